"""``slimseg slam-eval --sweep``: option checks and output of a masking-settings sweep."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from contextlib import ExitStack

from slimseg.dynamic.annotations import Dropout
from slimseg.dynamic.chain_config import TRACK_OFF, TrackPlan
from slimseg.dynamic.masking_settings import MaskingSettings
from slimseg.dynamic.modes import MODES, Mode
from slimseg.errors import SlimsegError
from slimseg.utils.outputs import refuse_inputs

DEFAULT_SWEEP_MODE = Mode.FUSION.value


def sweep_mode(text: str | None) -> str:
    """The one mask mode of ``--modes`` (raw and gt may be named: they are always run)."""
    if text is None:
        return DEFAULT_SWEEP_MODE
    names = [t.strip() for t in text.split(",") if t.strip()]
    bad = [n for n in names if n not in (*MODES, "raw", "gt")]
    if bad:
        raise SlimsegError(f"--modes {','.join(bad)}: a sweep takes one mask mode of "
                           f"{', '.join(MODES)} (raw and gt are always run)")  # fmt: skip
    modes = [n for n in names if n in MODES]
    if len(modes) != 1:
        raise SlimsegError(f"--sweep needs exactly one mask mode in --modes, got {modes or 'none'}")
    return modes[0]


def run_sweep_command(
    args: argparse.Namespace,
    masking: MaskingSettings,
    say: Callable[[str], None],
    track: TrackPlan = TRACK_OFF,
    dropout: Dropout | None = None,
    notes: Sequence[str] = (),
) -> int:
    """Validate the sweep options, run it, print and write the tables (every setting under
    the ``track`` stage, on ground-truth instances with ``dropout`` if given); ``notes``
    printed on stderr once the sequences have opened."""
    from slimseg.data.bags.reader import is_bag
    from slimseg.data.tum import TumSequence
    from slimseg.slam.sweep import parse_sweep
    from slimseg.slam.sweep_report import table, write_sweep
    from slimseg.slam.sweep_run import SweepPlan, claim_sweep_out, run_sweep

    spec = parse_sweep(args.sweep)
    mode = sweep_mode(args.modes)
    if args.masks is not None:
        raise SlimsegError("--sweep recomputes the masks: give --model X.onnx or --gt-instances, "
                           "not --masks")  # fmt: skip
    if args.model is None and not args.gt_instances:
        raise SlimsegError("--sweep needs --model X.onnx or --gt-instances")
    if args.restore is not None:
        raise SlimsegError("--restore is not swept: run slam-eval --restore on the chosen setting")
    bags = [str(s) for s in args.sequence if is_bag(s)]
    if bags:
        raise SlimsegError(f"--sweep reads TUM folders, not bags ({', '.join(bags)}): convert "
                           "them first with slimseg data bag2tum")  # fmt: skip
    with ExitStack() as opened:  # every sequence closed when the sweep is done
        plan = SweepPlan(
            sequences=[opened.enter_context(TumSequence(s)) for s in args.sequence],
            mode=mode,
            spec=spec,
            how=args.sweep_mode,
            base=masking,
            model=args.model,
            gt_instances=args.gt_instances,
            engine=args.engine,
            runs=args.runs,
            vocab=args.vocab,
            keypoints=args.keypoints,
            features=args.features,
            realtime=not args.no_realtime,
            speed=args.speed,
            threads=args.threads,
            progress=not args.quiet,
            track=track,
            dropout=dropout,
        )
        inputs = {"--sequence": args.sequence, "--model": args.model, "--vocab": args.vocab}
        refuse_inputs(args.out, "--out", inputs, folder=True)
        claim_sweep_out(plan, args.out)  # a user's files in --out are never replaced
        for line in notes:
            print(line, file=sys.stderr)
        sweeps = run_sweep(plan, args.out, say)
    model = "ground-truth instances" if args.gt_instances else f"model {args.model}"
    rows = write_sweep(args.out, plan, sweeps, model)
    for sw in sweeps:
        say(f"{sw.label}:")
        say(table([r for r in rows if r["sequence"] == sw.label], list(spec), markdown=False))
    say(f"written: {args.out / 'sweep.md'}, sweep.csv, sweep.png")
    if args.json:
        from slimseg.slam.report import as_json_rows

        print(json.dumps(as_json_rows(rows), indent=1))
    if not any(r["scored_runs"] for r in rows if r["kind"] in ("point", "reference")):
        raise SlimsegError("no setting could be scored (see the status column)")
    return 0
