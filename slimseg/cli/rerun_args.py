"""``--rerun FILE.rrd`` (``dynamic``, ``predict --track``, ``slam-eval``): a Rerun recording of
the run beside its usual outputs (the ``slimseg[viz]`` extra; docs/viewers.md)."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from slimseg.errors import SlimsegError
from slimseg.utils.text import printable

if TYPE_CHECKING:
    from slimseg.sequence.rerun_frames import RerunFrames


def add_rerun_arg(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument(
        "--rerun",
        metavar="FILE.rrd",
        type=Path,
        help=f"also write a Rerun recording of {what} (needs slimseg[viz]; open it with "
        "`rerun FILE.rrd`)",
    )


def rerun_path(args: argparse.Namespace, out: Path, inputs: dict) -> Path | None:
    """``--rerun`` checked before any work (None: not given): a ``.rrd`` name, not an input,
    not inside a folder ``--out`` (which a run replaces whole), not a file of another kind;
    ``rerun-sdk`` installed."""
    if args.rerun is None:
        return None
    from slimseg.sequence.rerun_frames import check_rrd_path, plain_logs
    from slimseg.utils.outputs import refuse_inputs

    plain_logs()  # before rerun is first imported; the command's own process

    path = Path(args.rerun)
    refuse_inputs(path, "--rerun", inputs)
    target, folder = path.expanduser().resolve(), out.expanduser().resolve()
    if target == folder or folder in target.parents:
        raise SlimsegError(f"--rerun {path} lies in --out {out}: write it beside the folder")
    return check_rrd_path(path)


@contextmanager
def kept_recording(viz: RerunFrames | None) -> Iterator[Callable[[], None]]:
    """The block writes the Rerun recording ``viz`` (None: no ``--rerun``) and gets a
    ``seal()`` to call as its last step, inside any staged output, so the recording is
    finished into its stage before that output is published. Discarded when the block
    raises (or it cannot be finished), else renamed into place and named on one printed
    line."""
    seal = viz.seal if viz is not None else (lambda: None)
    try:
        yield seal
        if viz is not None:
            path = viz.finish()  # sealed already when the block called seal()
    except BaseException:
        if viz is not None:
            viz.discard()
        raise
    if viz is not None:
        print(f"Rerun recording of {viz.frames} frames: {printable(path)}")
