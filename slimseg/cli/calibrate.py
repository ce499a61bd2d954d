"""``slimseg calibrate``: choose the masking settings for one model on sequences it never trained
on, and write them into a copy of its export as the ``calibrated`` preset."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from slimseg.cli.arg_types import count
from slimseg.cli.commands import COMMAND_HELP
from slimseg.dynamic.modes import MODES, Mode
from slimseg.errors import SlimsegError
from slimseg.utils.extras import install_command

log = logging.getLogger(__name__)


def add_parser(sub: argparse._SubParsersAction) -> None:
    from slimseg.calibrate.confirm import CONFIRM_RUNS
    from slimseg.calibrate.objective import RECALL_FLOOR, RECALL_TARGET
    from slimseg.calibrate.run import DEFAULT_BUDGET_S, DEFAULT_MAX_TRIALS, DEFAULT_SEQUENCES
    from slimseg.calibrate.search import SEARCHED

    p = sub.add_parser(
        "calibrate",
        help=COMMAND_HELP["calibrate"],
        description="Run the model once over calibration sequences (rendered from sequence "
        "indices no training world and no evaluation sequence uses, or your own TUM folders "
        "with ground-truth dynamic/ masks and groundtruth.txt), then search the masking "
        f"knobs ({', '.join(k.key for k in SEARCHED)}) with Optuna's TPE sampler for the "
        f"best keypoint precision at a {100 * RECALL_FLOOR:.0f} % recall floor (the "
        f"{100 * RECALL_TARGET:.0f} % target plus a margin; keypoints and walker-frames), per "
        "frame and with the track stage; "
        "confirm the best candidates and the shipped preset with ORB-SLAM3's ATE beside the "
        "ground-truth masks; write the chosen settings into a copy of the export as its "
        "'calibrated' preset (what Masker, dynamic, slam-eval and the C++ consumer use by "
        "default), with a report (report.json, report.md, report.png). Needs "
        f"{install_command('calibrate')} (Optuna, MIT) and, for the confirmation, "
        f"{install_command('slam')} (GPL-3.0).",
    )
    p.add_argument("--model", type=Path, required=True, help="the slimseg export (.onnx)")
    p.add_argument("--out", type=Path, required=True, help="the calibrated copy to write (.onnx)")
    p.add_argument(
        "--report",
        type=Path,
        default=None,
        help="report folder (default: OUT's name + _calibration beside it)",
    )
    p.add_argument(
        "--sequence",
        type=Path,
        nargs="+",
        default=[],
        help="calibrate on these TUM folders (with dynamic/ and groundtruth.txt) "
        "instead of rendered ones",
    )
    p.add_argument(
        "--sequences",
        type=count(1),
        default=DEFAULT_SEQUENCES,
        help=f"rendered calibration sequences (default {DEFAULT_SEQUENCES})",
    )
    p.add_argument("--mode", default=Mode.FUSION.value, choices=MODES)
    p.add_argument(
        "--budget",
        type=float,
        default=DEFAULT_BUDGET_S,
        metavar="SECONDS",
        help=f"time bound of the whole calibration (default {DEFAULT_BUDGET_S:g})",
    )
    p.add_argument(
        "--trials",
        type=count(2),
        default=DEFAULT_MAX_TRIALS,
        help=f"at most this many candidates (default {DEFAULT_MAX_TRIALS})",
    )
    p.add_argument("--workers", type=count(1), default=2, help="candidates scored at a time")
    p.add_argument("--seed", type=int, default=0, help="the sampler's seed")
    p.add_argument(
        "--confirm-runs",
        type=count(0),
        default=CONFIRM_RUNS,
        help=f"ORB-SLAM3 runs per confirmed candidate (default {CONFIRM_RUNS}; 0: none)",
    )
    p.add_argument(
        "--vocab",
        type=Path,
        default=None,
        help="ORBvoc.txt for the confirmation (default: built from the frames)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=run)


def default_report(model_out: Path) -> Path:
    """The report folder beside a calibrated export: ``NAME_calibration`` for ``NAME.onnx``."""
    return model_out.with_name(model_out.stem + "_calibration")


def run(args: argparse.Namespace) -> int:
    from slimseg.calibrate.run import CalibrationPlan

    model, out = Path(args.model), Path(args.out)
    if not model.is_file():
        raise SlimsegError(f"--model {model}: no such file")
    if not args.budget > 0:
        raise SlimsegError(f"--budget {args.budget}: expected seconds > 0")
    report = args.report or default_report(out)
    plan = CalibrationPlan(
        model=model,
        sequences=tuple(args.sequence),
        rendered=args.sequences,
        mode=args.mode,
        budget_s=args.budget,
        max_trials=args.trials,
        workers=args.workers,
        seed=args.seed,
        confirm_runs=args.confirm_runs,
        vocab=args.vocab,
        progress=not args.quiet,
    )
    result = calibrate_model(plan, out, report, print)
    print(result)
    return 0


def calibrate_model(plan: object, out: Path, report: Path, say) -> str:
    """Calibrate, write the report folder and the calibrated export; returns the summary
    line (also what ``slimseg demo`` prints)."""
    from slimseg.calibrate.report import write_report
    from slimseg.calibrate.run import calibrate
    from slimseg.calibrate.sequences import user_calibration_set
    from slimseg.deploy.calibrated import (
        check_calibrated_out,
        read_model_metadata,
        write_calibrated,
    )
    from slimseg.utils.atomic import staged_dir
    from slimseg.utils.outputs import claim_folder

    _check_extras(plan.confirm_runs > 0)  # one-line errors before any work
    read_model_metadata(plan.model)
    check_calibrated_out(plan.model, out)
    claim_folder(report, "--report")
    user_calibration_set(list(plan.sequences))
    inputs = {"--model": plan.model, "--sequence": list(plan.sequences)}
    with staged_dir(report, "--report", "calibrate", inputs) as folder:
        result = calibrate(plan, folder, say)
        digest = write_report(result, plan.model, folder)
        share, static = result.chosen.evaluation.shares()
        provenance = {
            "on": result.calibration_set.describe(),
            "mode": plan.mode,
            "objective": "keypoint precision at a 95 % recall floor, per frame and tracked",
            "report": report.name,
            "report_digest": digest,
            "seconds": round(result.seconds.get("total", 0.0), 1),
            "expect": {"mask_share": round(share, 4), "static_share": round(static, 4)},
        }
        write_calibrated(plan.model, out, result.settings, provenance)
    ship, chosen = result.shipped.evaluation, result.chosen.evaluation
    (sp, sr), (cp, cr) = ship.pooled("track"), chosen.pooled("track")
    line = (
        f"calibrated {plan.model.name} in {result.seconds['total']:.0f} s "
        f"({len(result.trials)} candidates): tracked keypoint precision/recall "
        f"{100 * sp:.1f}/{100 * sr:.1f} % (shipped) -> {100 * cp:.1f}/{100 * cr:.1f} %"
    )
    if result.truth_ate is not None:
        a = result.ates[result.chosen.number].median
        s = result.ates[result.shipped.number].median
        line += (
            f"; ORB-SLAM3 ATE {s:.4f} -> {a:.4f} m (ground-truth masks "
            f"{result.truth_ate.median:.4f} m)"
        )
    return line + f"; wrote {out} and {report}/"


def _check_extras(slam: bool) -> None:
    import importlib.util

    if importlib.util.find_spec("optuna") is None:
        raise SlimsegError(f"slimseg calibrate needs Optuna: {install_command('calibrate')}")
    if slam and importlib.util.find_spec("pyorbslam3") is None:
        raise SlimsegError(
            "the ORB-SLAM3 confirmation needs "
            + install_command("slam")
            + " (GPL-3.0), or pass --confirm-runs 0"
        )
