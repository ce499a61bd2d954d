"""``results.csv``, ``runs.csv``, ``results.md`` and ``trajectories.png`` of a slam-eval run."""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slimseg.data.tum import read_trajectory
from slimseg.eval.paper import TABLE3_ATE, YOLO_SLAM_WALKING_XYZ_ATE
from slimseg.slam.condition_runs import ConditionResult
from slimseg.utils.atomic import atomic_path, write_text
from slimseg.utils.table import format_table

FLOOR_NAME = "still (floor)"
COLUMNS = (
    "condition", "status", "runs", "scored_runs", "frames", "ate_rmse", "ate_min", "ate_max",
    "ate_std", "rpe_trans_frame", "rpe_rot_frame", "rpe_trans_s", "rpe_rot_s", "lost_median",
    "lost_max", "reinitialised", "tracking_ms", "late_max", "masking_ms", "note",
)  # fmt: skip


@dataclass(frozen=True)
class RunInfo:
    """What every row of one table shares (a table never mixes these)."""

    sequence: Path
    frames: int
    engine: str
    vocabulary: str
    intrinsics: str
    synthetic: bool
    runs: int
    groundtruth: np.ndarray | None = None
    """the true poses ``[K, 8]`` scored against; None: ``sequence``'s ``groundtruth.txt``"""


def summary_rows(results: list[ConditionResult], floor: float, frames: int) -> list[dict]:
    """One dict per condition (:data:`COLUMNS`), then the standing-still floor."""
    rows = [r.summary() for r in results]
    floor_row = dict.fromkeys(COLUMNS)
    floor_row.update(
        condition=FLOOR_NAME, status="computed", frames=frames, ate_rmse=floor,
        note="ATE of a camera that never moves (best-aligned): below it, a difference is noise",
    )  # fmt: skip
    return [*rows, floor_row]


def csv_text(rows: list[dict], columns: tuple[str, ...] | list[str]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(columns), extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


def run_rows(results: list[ConditionResult]) -> list[dict]:
    """Every individual run: condition, run, ATE, RPE, lost, trajectory file or error."""
    out = []
    for res in results:
        for r in res.runs:
            s = r.score.as_dict() if r.score else {}
            out.append(
                {"condition": res.condition.name, "run": r.index, **s, "lost": r.lost,
                 "reinitialised": r.reinitialised, "frames": r.frames,
                 "tracking_ms": round(r.tracking_ms, 2), "late": r.late,
                 "trajectory": r.trajectory.name if r.trajectory else "", "error": r.error or ""}
            )  # fmt: skip
    return out


def _m(v: object, digits: int = 4) -> str:
    return "-" if v is None else f"{float(v):.{digits}f}"


def table_lines(rows: list[dict], markdown: bool) -> str:
    """The human table: condition × ATE (median, spread, std), RPE, losses, masking time."""
    headers = ["condition", "ATE RMSE m", "min–max", "ATE std", "RPE m/s", "RPE deg/s",
               "lost (median/max of frames)", "reinit", "mask ms/frame", "status"]  # fmt: skip
    body = []
    for r in rows:
        spread = "-" if r["ate_min"] is None else f"{r['ate_min']:.4f}–{r['ate_max']:.4f}"
        lost = (
            "-"
            if r["lost_median"] is None
            else (f"{int(r['lost_median'])}/{int(r['lost_max'])} of {r['frames']}")
        )
        body.append([r["condition"], _m(r["ate_rmse"]), spread, _m(r["ate_std"]),
                     _m(r["rpe_trans_s"]), _m(r["rpe_rot_s"], 3), lost,
                     "-" if r["reinitialised"] is None else str(r["reinitialised"]),
                     _m(r["masking_ms"], 1), r["status"]])  # fmt: skip
    return format_table(headers, body, markdown=markdown)


def write_report(out: Path, info: RunInfo, results: list[ConditionResult], floor: float) -> list:
    """Write the four files under ``out``; returns the summary rows (for ``--json``)."""
    rows = summary_rows(results, floor, info.frames)
    write_text(out / "results.csv", csv_text(rows, COLUMNS))
    runs = run_rows(results)
    if runs:
        write_text(out / "runs.csv", csv_text(runs, list(runs[0])))
    official = info.vocabulary.startswith("official")
    lines = [
        f"# slam-eval: {info.sequence.name}",
        "",
        f"- sequence: `{info.sequence}` ({info.frames} frames"
        f"{', synthetic' if info.synthetic else ''})",
        f"- engine: {info.engine}" + (f", {info.runs} runs per condition (median, min–max)"
                                      if info.engine == "orbslam3" else ", deterministic: 1 run"),
        f"- vocabulary: {info.vocabulary}"
        + ("" if official or info.engine != "orbslam3" else
           " — **NON-OFFICIAL VOCABULARY**: not comparable with results made with ORBvoc.txt"),
        f"- intrinsics: {info.intrinsics}",
        "- ATE: evo APE, translation, SE(3) Umeyama alignment without scale, poses associated "
        "to ground truth within 0.02 s; RPE: evo RPE RMSE over all pairs 1 s apart "
        "(round(fps) frames), translation m/s and rotation deg/s",
        "- masked conditions: dynamic region (dilated) inpainted (Telea) and its depth zeroed "
        "before ORB-SLAM3 sees the frame; restored / oracle: whole replacement frames",
        "",
        table_lines(rows, markdown=True),
        "",
        *paper_lines(info.synthetic),
        "",
    ]  # fmt: skip
    write_text(out / "results.md", "\n".join(lines))
    plot_trajectories(out / "trajectories.png", info, results)
    return rows


def plot_trajectories(path: Path, info: RunInfo, results: list[ConditionResult]) -> None:
    """Top view (x–z, metres) of the ground truth and each condition's median-ATE run, each
    SE(3)-aligned to the ground truth as for the ATE."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    from slimseg.slam.metrics import aligned_positions

    gt = info.groundtruth
    if gt is None:
        gt = read_trajectory(info.sequence / "groundtruth.txt")
    fig = Figure(figsize=(7, 6), dpi=110)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(gt[:, 1], gt[:, 3], "k--", lw=1.5, label="ground truth", zorder=10)
    for res in results:
        run = res.median_run()
        if run is None or run.trajectory is None:
            continue
        xyz = aligned_positions(gt, read_trajectory(run.trajectory))
        label = f"{res.condition.name} ({run.score.ate_rmse:.3f} m)"
        ax.plot(xyz[:, 0], xyz[:, 2], lw=1.2, label=label)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_title(f"{info.sequence.name}: top view, {info.engine}")
    ax.axis("equal")
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp)


def as_json_rows(rows: list[dict]) -> list[dict]:
    """Rows with NaN replaced by None (strict JSON)."""
    return [
        {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in r.items()}
        for r in rows
    ]


def paper_lines(synthetic: bool) -> list[str]:
    """Markdown lines with both published tables, labelled for the sequence at hand."""
    where = (
        "**different dataset** (real TUM RGB-D recordings, official ORBvoc.txt; this table's "
        "sequence is synthetic): for orientation, not comparison"
        if synthetic
        else "real TUM RGB-D recordings with the official ORBvoc.txt"
    )
    lines = [
        "## Published numbers",
        "",
        f"Substation paper, Table III, ATE RMSE / std (m) — {where}.",
        "",
        "| sequence | ORB-SLAM3 | the paper's method |",
        "|---|---:|---:|",
    ]
    for seq, (a, b, c, d) in TABLE3_ATE.items():
        lines.append(f"| {seq} | {a:.4f} / {b:.4f} | {c:.4f} / {d:.4f} |")
    lines += ["", "YOLO-SLAM, fr3/walking_xyz, ATE RMSE (m):", "", "| configuration | ATE |",
              "|---|---:|"]  # fmt: skip
    lines += [f"| {k} | {v:.4f} |" for k, v in YOLO_SLAM_WALKING_XYZ_ATE.items()]
    return lines
