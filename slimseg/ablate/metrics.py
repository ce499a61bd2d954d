"""Per-row accuracy metrics of a sweep: named functions of a finished run folder.

A sweep's ``metrics:`` field lists names from :data:`ROW_METRICS` (default ``[coco]``); the
row builder calls each on the run's folder, the arm's spec (class count set to the data's)
and the sweep's data config, and merges the returned columns into the row. The report
averages every column a metric declares over the seeds of an arm (``summary.csv``).

To add one, write a :class:`RowMetric` (``name``, ``columns``, ``__call__``) and put it in
:data:`ROW_METRICS`. It scores the run's best weights (``weights/best.pt``) on the val split;
:func:`run_weights` and :func:`val_dataset` load both the way the training run saw them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from torch import nn

from slimseg.data.coco import CocoDataset
from slimseg.data.config import DataConfig
from slimseg.data.dataset import ZooDataset
from slimseg.errors import ConfigError, SlimsegError
from slimseg.eval.mask_quality import PERSON
from slimseg.eval.validation import validate_dataset, validate_mask_quality
from slimseg.models.checkpoint import WeightsInfo, load_weights
from slimseg.models.specs import ModelSpec


class RowMetric(Protocol):
    """``name``: the key in ``metrics:``; ``columns``: the row columns it returns, exactly
    these keys on every call: fractions in ``[0, 1]`` (``results.md`` prints them in %),
    NaN where undefined."""

    name: str
    columns: tuple[str, ...]

    def __call__(self, run_dir: Path, spec: ModelSpec, data_cfg: DataConfig) -> dict[str, float]:
        """Score the finished run in ``run_dir`` (``weights/best.pt``) on ``data_cfg``'s val."""
        ...


def run_weights(run_dir: Path) -> tuple[nn.Module, WeightsInfo]:
    """The run's best EMA weights (unfused, eval mode) and their stored info."""
    return load_weights(Path(run_dir) / "weights" / "best.pt")


def val_dataset(info: WeightsInfo, data_cfg: DataConfig) -> ZooDataset:
    """The val split letterboxed to the run's training imgsz (as its validation saw it)."""
    return ZooDataset(CocoDataset.from_config(data_cfg, "val"), int(info.train_config["imgsz"]))


@dataclass(frozen=True)
class CocoMetric:
    """COCO box and mask mAP50-95 / mAP50 (pycocotools) of the best weights on the val split:
    the scores the training run's own validation stored in ``best.pt``; weights stored without
    one are evaluated here with the run's batch, ``conf`` and ``iou``. Mask columns are NaN
    for detection-only models."""

    name: str = "coco"
    columns: tuple[str, ...] = ("box_map50_95", "seg_map50_95", "box_map50", "seg_map50")

    def __call__(self, run_dir: Path, spec: ModelSpec, data_cfg: DataConfig) -> dict[str, float]:
        model, info = run_weights(run_dir)
        metrics = info.metrics
        if "box" not in metrics:  # weights written without a validation: score them now
            t = info.train_config
            metrics, _ = validate_dataset(
                model.fuse(),
                val_dataset(info, data_cfg),
                int(t["batch"]),
                conf=float(t["conf"]),
                iou=float(t["iou"]),
                progress=False,
            )
        box, mask = metrics["box"], metrics.get("mask") or {}
        return {
            "box_map50_95": float(box["map50_95"]),
            "seg_map50_95": float(mask.get("map50_95", math.nan)),
            "box_map50": float(box["map50"]),
            "seg_map50": float(mask.get("map50", math.nan)),
        }


def _number(value: float | None) -> float:
    return math.nan if value is None else float(value)


@dataclass(frozen=True)
class MaskQualityMetric:
    """Person masks beyond mAP (``docs/mask_quality.md``): the person class's mask AP,
    AP50, AP75 and Boundary AP at the 1 px, 2 px and default bands, and the recall of the
    person ground truth's skeleton (all of it, and its thin parts), scored on the val split
    with the run's fused best weights at the evaluation thresholds."""

    name: str = "mask_quality"
    columns: tuple[str, ...] = (
        "person_mask_ap",
        "person_mask_ap50",
        "person_mask_ap75",
        "person_bap_1px",
        "person_bap_2px",
        "person_bap_default",
        "all_mask_ap",
        "skeleton_recall",
        "thin_skeleton_recall",
    )

    def __call__(self, run_dir: Path, spec: ModelSpec, data_cfg: DataConfig) -> dict[str, float]:
        model, info = run_weights(run_dir)
        t = info.train_config
        q = validate_mask_quality(
            model.fuse(),
            val_dataset(info, data_cfg),
            int(t["batch"]),
            conf=float(t["conf"]),
            iou=float(t["iou"]),
        )
        person = PERSON if PERSON in q["classes"] else None
        skeleton = q["skeleton"] or {}

        def ap(table: dict, key: str) -> float:
            value = table.get(person, {}) if person else {}
            return _number((value or {}).get(key))

        return {
            "person_mask_ap": ap(q["mask"], "ap"),
            "person_mask_ap50": ap(q["mask"], "ap50"),
            "person_mask_ap75": ap(q["mask"], "ap75"),
            "person_bap_1px": ap(q["boundary"]["1px"], "ap"),
            "person_bap_2px": ap(q["boundary"]["2px"], "ap"),
            "person_bap_default": ap(q["boundary"]["default"], "ap"),
            "all_mask_ap": _number(q["mask"]["all"]["ap"]),
            "skeleton_recall": _number(skeleton.get("recall")),
            "thin_skeleton_recall": _number(skeleton.get("thin_recall")),
        }


ROW_METRICS: dict[str, RowMetric] = {m.name: m for m in (CocoMetric(), MaskQualityMetric())}
DEFAULT_METRICS = ("coco",)
BASE_METRIC = "coco"  # its mAP columns are the report's tables: every sweep computes it


def resolve_metrics(names: Sequence[str], where: str) -> list[RowMetric]:
    """The metrics named in a sweep's ``metrics:`` (``where``: the config file)."""
    unknown = [n for n in names if n not in ROW_METRICS]
    if unknown:
        raise ConfigError(f"{where}: metrics {unknown} unknown; known: {', '.join(ROW_METRICS)}")
    if BASE_METRIC not in names or len(set(names)) != len(names):
        raise ConfigError(
            f"{where}: metrics must list '{BASE_METRIC}' (the mAP columns) and no name twice"
        )
    return [ROW_METRICS[n] for n in names]


def metric_columns(names: Sequence[str]) -> list[str]:
    """Row columns of the named metrics, in order."""
    return [c for n in names for c in ROW_METRICS[n].columns]


def score_run(
    metrics: Sequence[RowMetric], run_dir: Path, spec: ModelSpec, data_cfg: DataConfig
) -> dict[str, float]:
    """Every metric's columns for one finished run; a metric returning other keys than it
    declares is a bug in that metric (SlimsegError naming it)."""
    row: dict[str, float] = {}
    for metric in metrics:
        values = metric(run_dir, spec, data_cfg)
        if sorted(values) != sorted(metric.columns):
            raise SlimsegError(
                f"row metric {metric.name!r} returned {sorted(values)}, "
                f"declared {list(metric.columns)}"
            )
        row |= {k: float(values[k]) for k in metric.columns}
    return row
