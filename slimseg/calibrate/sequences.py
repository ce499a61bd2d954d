"""The sequences a calibration chooses on: rendered from indices no training world and no
evaluation sequence uses, or the user's own (TUM layout with ground-truth ``dynamic/`` masks).

Rendered ones are sequence index ``FIRST_INDEX["calibrate"] + k`` of :data:`CALIBRATION_SEED`
(:mod:`slimseg.data.synth.world_frames`: training worlds start at 10,000 and 20,000, evaluation
sequences stay below 10,000), so a model is never calibrated on a frame it trained on or on a
sequence it is judged on, whatever seeds its training and its evaluation used.
"""

from __future__ import annotations

import logging
import multiprocessing
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slimseg.data.frame_source import Frame
from slimseg.data.synth.sequence import write_sequence
from slimseg.data.synth.world_frames import FIRST_INDEX
from slimseg.data.tum import TumSequence
from slimseg.errors import SlimsegError

log = logging.getLogger(__name__)

#: The seed of the rendered calibration sequences (their indices keep them apart from any
#: training world and evaluation sequence of any seed).
CALIBRATION_SEED = 0
#: Presets rendered, in order: a camera that moves along with walkers (what costs most when
#: a mask misses), one that circles, one that stands (where masks must not eat the static
#: scene), one that rotates in place (where the model scores walkers lowest: settings chosen
#: without it lost their recall there, docs/calibrate.md).
CALIBRATION_PRESETS: tuple[str, ...] = (
    "walking_xyz",
    "walking_halfsphere",
    "walking_static",
    "walking_rpy",
)
#: Frames per rendered sequence (30 Hz) and their size (TUM's).
CALIBRATION_FRAMES = 60
CALIBRATION_SIZE = (640, 480)


@dataclass(frozen=True)
class CalibrationSet:
    """Where the calibration sequences came from: ``rendered`` (preset, index) pairs of
    ``frames`` frames of ``size`` (W, H), or the user's folders."""

    folders: tuple[Path, ...]
    rendered: tuple[tuple[str, int], ...] = ()
    frames: int = CALIBRATION_FRAMES
    size: tuple[int, int] = CALIBRATION_SIZE

    def describe(self) -> dict[str, object]:
        """What the calibration was chosen on (for the metadata and the report)."""
        if self.rendered:
            return {
                "rendered": [
                    {"preset": p, "seed": CALIBRATION_SEED, "index": i} for p, i in self.rendered
                ],
                "frames": self.frames,
                "size": list(self.size),
            }
        return {"sequences": [f.name for f in self.folders]}


def render_calibration_set(
    root: Path,
    count: int,
    frames: int = CALIBRATION_FRAMES,
    size: tuple[int, int] = CALIBRATION_SIZE,
    workers: int = 1,
) -> CalibrationSet:
    """Render ``count`` calibration sequences (presets cycled) under ``root / <preset>``,
    ``workers`` at a time (processes from a fork server: rendering is pure Python and NumPy,
    one core each)."""
    if count < 1:
        raise SlimsegError("a calibration needs at least one sequence")
    presets = [CALIBRATION_PRESETS[k % len(CALIBRATION_PRESETS)] for k in range(count)]
    rendered = [(p, FIRST_INDEX["calibrate"] + k) for k, p in enumerate(presets)]
    folders = [root / f"{k:02d}_{p}" for k, p in enumerate(presets)]
    jobs = [
        (f, CALIBRATION_SEED, i, frames, size, p)
        for f, (p, i) in zip(folders, rendered, strict=True)
    ]
    if workers > 1 and count > 1:
        ctx = multiprocessing.get_context("forkserver")
        with ctx.Pool(min(workers, count)) as pool:
            pool.starmap(_render, jobs)
    else:
        for job in jobs:
            _render(*job)
    log.info("rendered %d calibration sequences of %d frames", count, frames)
    return CalibrationSet(tuple(folders), tuple(rendered), frames, size)


def _render(
    folder: Path, seed: int, index: int, frames: int, size: tuple[int, int], preset: str
) -> None:
    write_sequence(folder, seed, index, frames, size, preset=preset)


def user_calibration_set(folders: list[Path]) -> CalibrationSet:
    """The user's sequences, checked: each a TUM folder with ground-truth ``dynamic/`` masks
    (the keypoint objective needs them) and ``groundtruth.txt`` (the ATE confirmation)."""
    for f in folders:
        if not (f / "dynamic").is_dir():
            raise SlimsegError(
                f"--sequence {f}: no dynamic/ folder of ground-truth masks "
                "(calibration scores keypoints against them)"
            )
        if not (f / "groundtruth.txt").is_file():
            raise SlimsegError(
                f"--sequence {f}: no groundtruth.txt (the ATE confirmation "
                "needs the camera's trajectory)"
            )
    return CalibrationSet(tuple(folders))


class PreloadedSequence(TumSequence):
    """A :class:`TumSequence` whose frames are decoded once and kept: a calibration masks the
    same frames under every candidate, and decoding would cost more than the masking."""

    def __init__(self, root: str | Path) -> None:
        super().__init__(root)
        load = super().load
        self._cached: list[Frame] = [load(i) for i in range(len(self))]

    def load(self, i: int) -> Frame:
        """Frame ``i`` as :meth:`TumSequence.load` returns it (the arrays are shared: the
        chain only reads them)."""
        return self._cached[self.frame_index(i)]

    @property
    def nbytes(self) -> int:
        """Memory the decoded frames take."""
        return sum(int(np.asarray(a).nbytes) for f in self._cached for a in f[:2])
