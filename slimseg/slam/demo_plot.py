"""``slam.png`` of ``slimseg demo``: trajectories against the ground truth, and the ATE bars.

Left, a top view (world x and z, metres) of every scored run of every condition, each run
already aligned to the ground truth as its ATE was computed (SE(3) Umeyama, no scale): the
run with the median ATE drawn bold, the others thin. Right, one bar per condition at the
median ATE RMSE of its runs, a whisker from the smallest to the largest, every run as a dot
and the median written above; the dotted line (in the legend) is the ATE of a camera that
never moves (best-aligned), the error of giving up on tracking altogether.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slimseg.utils.atomic import atomic_path

COLORS = ("tab:red", "tab:blue", "tab:green", "tab:purple", "tab:orange")


@dataclass(frozen=True)
class PlotCondition:
    """One condition: its ``label``, the aligned positions ``[K, 3]`` (m) and ATE (m) of each
    scored run, and how many runs were tracked (``runs`` ≥ scored ones)."""

    label: str
    xyz: list[np.ndarray]
    ates: list[float]
    runs: int

    def median_index(self) -> int | None:
        """Index of the run with the median ATE (the lower middle one for an even count)."""
        if not self.ates:
            return None
        order = np.argsort(self.ates, kind="stable")
        return int(order[(len(order) - 1) // 2])


def _median(values: list[float]) -> float:
    """The median of the runs as slam-eval's table gives it (mean of the two middle runs for an
    even count; the bold line is then the lower of them, slam-eval's median run)."""
    return float(np.median(values))


def plot_demo_slam(
    path: str | Path,
    gt_xyz: np.ndarray,
    conditions: list[PlotCondition],
    title: str,
    floor: float | None = None,
) -> Path:
    """Write the two-panel figure to ``path`` (PNG, atomically) and return the path.
    ``gt_xyz [G, 3]``: ground-truth positions (m); ``floor``: still-camera ATE (m) or None."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    fig = Figure(figsize=(13, 5.8), dpi=110)
    top, bars = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.25, 1]})
    gt_xyz = np.asarray(gt_xyz, np.float64)
    top.plot(gt_xyz[:, 0], gt_xyz[:, 2], color="k", ls="--", lw=1.8, zorder=10)
    top.plot(gt_xyz[:1, 0], gt_xyz[:1, 2], "ko", ms=5, zorder=11)
    handles = [Line2D([], [], color="k", ls="--", lw=1.8, marker="o", ms=4,
                      label="ground truth (● start)")]  # fmt: skip
    for c, color in zip(conditions, COLORS, strict=False):
        mid = c.median_index()
        for i, xyz in enumerate(c.xyz):
            bold = i == mid
            top.plot(xyz[:, 0], xyz[:, 2], color=color, lw=1.8 if bold else 0.8,
                     alpha=0.95 if bold else 0.35, zorder=5 if bold else 2)  # fmt: skip
        if mid is None:
            text = f"{c.label}: not scored (0/{c.runs} runs)"
        else:
            text = (f"{c.label}: median ATE {_median(c.ates):.3f} m "
                    f"({len(c.ates)}/{c.runs} runs scored)")  # fmt: skip
        handles.append(Line2D([], [], color=color, lw=1.8, label=text))
    top.set_xlabel("x (m)")
    top.set_ylabel("z (m)")
    top.set_title("top view: bold = median-ATE run, thin = the other runs;\n"
                  "each run aligned to the ground truth as for its ATE", fontsize=9)  # fmt: skip
    top.set_aspect("equal", adjustable="datalim")
    top.grid(alpha=0.3)
    top.legend(handles=handles, fontsize=8, loc="best")

    x = np.arange(len(conditions))
    for i, (c, color) in enumerate(zip(conditions, COLORS, strict=False)):
        if not c.ates:
            bars.text(i, 0, "not scored", ha="center", va="bottom", fontsize=9)
            continue
        med, lo, hi = _median(c.ates), min(c.ates), max(c.ates)
        bars.bar(i, med, width=0.6, color=color, alpha=0.55)
        bars.errorbar(i, med, yerr=[[med - lo], [hi - med]], color="k", capsize=6, lw=1.2)
        jitter = np.linspace(-0.12, 0.12, len(c.ates)) if len(c.ates) > 1 else [0.0]
        bars.plot(i + np.asarray(jitter), c.ates, "o", color="k", ms=3.5, zorder=5)
        bars.annotate(f"{med:.3f} m", (i, hi), textcoords="offset points", xytext=(0, 6),
                      ha="center", fontsize=9, fontweight="bold")  # fmt: skip
    if floor is not None and np.isfinite(floor):
        bars.axhline(floor, color="0.4", ls=":", lw=1.2,
                     label=f"a camera that never moves: {floor:.3f} m")  # fmt: skip
        bars.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.08), frameon=False)
    bars.set_xticks(x, [c.label for c in conditions])
    bars.set_xlim(-0.6, len(conditions) - 0.4)
    tops = [max(c.ates) for c in conditions if c.ates] + [floor or 0.0]
    top_m = max([t for t in tops if np.isfinite(t)], default=0.0)
    bars.set_ylim(0, 1.15 * top_m if top_m > 0 else 1.0)
    bars.set_ylabel("ATE RMSE (m), lower is better")
    bars.set_title("ATE: bar = median, whisker = min–max, dots = individual runs", fontsize=9)
    bars.grid(axis="y", alpha=0.3)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp)
    return Path(path)
