"""``slimseg info``: what this install holds (the core and each extra, installed or what is
missing, and what each enables), then params, gradients and GFLOPs of the model zoo when the
training stack is installed (:mod:`slimseg.cli.info_models`). Runs on the core install."""

from __future__ import annotations

import argparse
import platform

from slimseg.cli.arg_types import count, multiple_of
from slimseg.cli.commands import COMMAND_HELP
from slimseg.errors import SlimsegError
from slimseg.utils.extras import install_command, is_train_module, train_hint
from slimseg.utils.install_state import CORE, EXTRA_USES, install_state
from slimseg.utils.table import format_table
from slimseg.version import __version__


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "info",
        help=COMMAND_HELP["info"],
        description="Without --model: the installed extras and what each enables, then (with "
        "the training stack) every variant's size and cost. --model: report params, gradients "
        "(trainable params), GFLOPs in our convention (FlopCounterMode, eval, batch 1) and in "
        "the substation paper's (thop-style), and the fused model's params and GFLOPs; '--model "
        "all' prints the zoo and compares the s-scale segmenters with the paper's Table II. "
        f"The model report needs {install_command('train')}.",
    )
    p.add_argument("--model", default=None, help="variant name, spec YAML path, or 'all' (the zoo)")
    p.add_argument(
        "--nc", type=count(1), default=None, help="number of classes (default: the spec's)"
    )
    p.add_argument(
        "--imgsz", type=multiple_of(), default=640, help="square input size (multiple of 32)"
    )
    p.add_argument("--fused", action="store_true", help="build the model in fused (deploy) form")
    p.add_argument("--json", action="store_true", help="print the model report as JSON")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    if args.imgsz % 32:
        raise SlimsegError(f"--imgsz {args.imgsz} is not a multiple of 32 (the largest stride)")
    overview = args.model is None and not args.json
    if overview:
        print_install()
    try:
        from slimseg.cli.info_models import report_models
    except ModuleNotFoundError as exc:  # the core install: no training stack
        if not is_train_module(exc.name):
            raise
        if overview:
            print(f"\nmodel size and cost (--model): {train_hint('the model report')}")
            return 0
        raise SlimsegError(train_hint("the model report (--model)")) from None
    if args.model is None:
        args.model = "all"
        if overview:
            print()
    return report_models(args)


def print_install() -> None:
    """The version, Python, the core's distributions and each extra's state."""
    states = install_state()
    core = next(s for s in states if s.name == CORE)
    print(f"slimseg {__version__} (Python {platform.python_version()})")
    print("core: " + ", ".join(f"{d} {v}" for d, v in core.versions.items()))
    if core.missing:
        print(f"core: missing {', '.join(core.missing)}: pip install slimseg")
    rows = [[s.name, s.describe(), EXTRA_USES[s.name]] for s in states if s.name != CORE]
    print(f"extras ({install_command('NAME')} adds one):")
    print(format_table(["extra", "state", "enables"], rows))
