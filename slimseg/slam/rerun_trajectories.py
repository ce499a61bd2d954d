"""``slimseg slam-eval --rerun FILE.rrd``: every condition's estimated trajectory beside the
ground truth in 3-D, in a Rerun recording (the ``slimseg[viz]`` extra).

Entities (all static, no timeline): ``world/ground_truth`` (``LineStrips3D``, black), one
``world/<condition>`` per condition (its median-ATE run, SE(3)-aligned to the ground truth as
for the ATE, labelled with that ATE; coloured as the class palette colours conditions), the
ATE of each as ``ate/<condition>`` (``Scalars``, metres) and the results table as a
``TextDocument`` at ``results``. Written under a temporary name and renamed into place.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slimseg.data.tum import read_trajectory
from slimseg.data.visualize import class_color
from slimseg.sequence.rerun_frames import RerunRecording
from slimseg.slam.condition_runs import ConditionResult
from slimseg.slam.metrics import aligned_positions


def _layout() -> object:
    """The trajectories in 3-D beside the results table; panels folded."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="trajectories (aligned as for the ATE)"),
            rrb.TextDocumentView(origin="results", name="ATE per condition"),
            column_shares=[2, 1],
        ),
        collapse_panels=True,
    )


def write_trajectories(
    path: Path, gt: np.ndarray, results: list[ConditionResult], table: str
) -> tuple[Path, int]:
    """Write the recording (see the module docstring); returns its path and the number of
    condition trajectories in it (a condition without a scored run has none)."""
    rec = RerunRecording(path, "slimseg slam-eval")
    rr = rec.rr
    try:
        rec.rec.log(
            "world/ground_truth",
            rr.LineStrips3D([gt[:, 1:4]], colors=[(0, 0, 0)], labels=["ground truth"]),
            static=True,
        )
        shown = 0
        for k, res in enumerate(results):
            run = res.median_run()
            if run is None or run.trajectory is None:
                continue
            xyz = aligned_positions(gt, read_trajectory(run.trajectory))
            name = res.condition.name
            ate = float(run.score.ate_rmse)
            rec.rec.log(f"world/{name}", rr.LineStrips3D(
                [xyz], colors=[class_color(k)], labels=[f"{name} ATE {ate:.4f} m"]
            ), static=True)  # fmt: skip
            rec.rec.log(f"ate/{name}", rr.Scalars(ate), static=True)
            shown += 1
        rec.rec.log("results", rr.TextDocument(table, media_type=rr.MediaType.MARKDOWN),
                    static=True)  # fmt: skip
        rec.rec.send_blueprint(_layout())
    except BaseException:
        rec.discard()
        raise
    return rec.finish(), shown
