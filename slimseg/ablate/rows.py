"""A sweep run's row, in two parts that may be measured on different machines and times.

- the *scores* (``scores.json``): what training decided (metrics, best epoch) and what the
  arm costs (params, GFLOPs), plus the run's identity; the same wherever the run trained;
- the *timing*: onnxruntime latency at the bench sizes and training images/s, which depend
  on the machine and on what else runs on it.

The local backend measures both right after each run (runs go one at a time); the ray
backend writes ``scores.json`` from the parallel runs and measures the timing in a serial
phase on one machine. ``row.json`` (present = run done) is the two joined, keys in the
order of the first sweeps.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from slimseg.ablate.latency import latency_columns

# 2: arms (``model``), seeds, row metrics, per-size latency; a version-1 row is measured
# again from its run's weights (nothing retrains).
ROW_VERSION = 2

# ``train_img_s_from``: how the training throughput was measured.
FROM_EPOCHS = "epochs"  # the run's own training epochs (validation excluded)
FROM_STEPS = "steps"  # a timed burst of training steps in the serial phase

# The scores end here; the timing columns follow in the row.
_TIMING_AFTER = "fused_params"


def timing_keys(sizes: tuple[int, ...], masks: bool) -> list[str]:
    """The row's machine-dependent columns, in row order."""
    return ["latency_ms", "latency_imgsz", *latency_columns(sizes, masks), "train_img_s"]


def join_row(scores: dict, timing: dict) -> dict:
    """``scores`` with ``timing`` inserted after the cost columns (the row's key order)."""
    row: dict = {}
    for key, value in scores.items():
        if key == "train_img_s_from":
            continue
        row[key] = value
        if key == _TIMING_AFTER:
            row |= {k: v for k, v in timing.items() if k != "train_img_s_from"}
    if "train_img_s_from" in timing:
        row["train_img_s_from"] = timing["train_img_s_from"]
    return row


def provisional_row(scores: dict, sizes: tuple[int, ...], masks: bool) -> dict:
    """A scored run whose timing is not measured yet: the timing columns are NaN
    (``latency_imgsz`` excepted), so the reports can show its mAP already."""
    timing = {k: math.nan for k in timing_keys(sizes, masks)}
    return join_row(scores, timing | {"latency_imgsz": sizes[0]})


def _read(path: Path, config_hash: str) -> dict | None:
    if not path.is_file():
        return None
    row = json.loads(path.read_text())
    if row.get("config_hash") != config_hash or row.get("row_version") != ROW_VERSION:
        return None
    return row


def read_row(run_dir: Path, config_hash: str) -> dict | None:
    """The finished row of a run folder, if it belongs to this config."""
    return _read(Path(run_dir) / "row.json", config_hash)


def read_scores(run_dir: Path, config_hash: str) -> dict | None:
    """The scores of a trained and scored run (ray backend), if of this config."""
    return _read(Path(run_dir) / "scores.json", config_hash)


def rows_on_disk(
    run_dirs: list[Path], config_hash: str, sizes: tuple[int, ...], masks: bool
) -> list[dict]:
    """The rows of the runs that have one, in the order of ``run_dirs`` (the plan's):
    ``row.json``, else a provisional row from ``scores.json``; runs with neither are left
    out. What the reports are rebuilt from, so they never depend on the order in which the
    runs finished or on which process finished them."""
    rows = []
    for run_dir in run_dirs:
        row = read_row(run_dir, config_hash)
        if row is None and (scores := read_scores(run_dir, config_hash)) is not None:
            row = provisional_row(scores, sizes, masks)
        if row is not None:
            rows.append(row)
    return rows
