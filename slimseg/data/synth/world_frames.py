"""Training and validation frames rendered from the sequence world (what SLAM is judged on).

The still images of :func:`~slimseg.data.synth.scene.render_image` are square collages with
objects at a 5x scale range; the sequences that ``slimseg dynamic`` and ``slimseg
slam-eval`` mask are 640x480 rooms with two or three people walking close to the camera,
drawn by :mod:`slimseg.data.synth.sequence`. A model trained only on the former has never
seen the latter. This module renders training splits from the latter: ``worlds`` short
sequences per split, presets mixed (:data:`WORLD_PRESETS`, cycled), every ``step``-th of
``frames`` frames written in TUM layout with ``annotations.json`` (what a ``data.yaml``
split's ``sequences`` reads, :mod:`slimseg.data.sequence_split`).

Seeds: world ``k`` of a split is sequence index ``FIRST_INDEX[split] + k`` of the dataset's
seed, and every evaluation sequence (``slimseg data synth --sequences N``, the demo's
sequence) is index ``0 .. N - 1`` of its seed: their random streams are disjoint for any
seeds while ``N`` stays below :data:`MAX_EVAL_SEQUENCES`
(:func:`~slimseg.data.synth.scene.frame_rng` keys a sequence by ``seed * 1_000_003 + index``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from slimseg.data.synth.sequence import write_sequence
from slimseg.errors import SlimsegError

#: The presets cycled over a split's worlds (None: the default small-motion sequences).
WORLD_PRESETS: tuple[str | None, ...] = (
    "walking_xyz",
    "walking_halfsphere",
    "walking_rpy",
    "sitting_static",
    "walking_static",
    None,
)
#: First sequence index of each split's worlds, and of the sequences ``slimseg calibrate``
#: chooses masking settings on; evaluation sequences use indices below
#: :data:`MAX_EVAL_SEQUENCES`, so no training world or calibration sequence is ever an
#: evaluation sequence, and no calibration sequence a training world.
FIRST_INDEX = {"train": 10_000, "val": 20_000, "calibrate": 30_000}
MAX_EVAL_SEQUENCES = 10_000
#: Folder of a split's worlds inside the dataset folder.
FOLDER = {"train": "train_sequences", "val": "val_sequences"}


@dataclass(frozen=True)
class WorldSplits:
    """Sequence-world splits of a synthetic dataset: ``train``/``val`` worlds (short
    sequences), each rendered over ``frames`` frames of which every ``step``-th is written."""

    train: int = 0
    val: int = 0
    frames: int = 96
    step: int = 6

    @property
    def per_world(self) -> int:
        """Frames written per world."""
        return len(range(0, self.frames, self.step))

    def check(self) -> None:
        """SlimsegError (naming the ``slimseg data synth`` option) on bad values."""
        if self.train < 0 or self.val < 0 or (self.train == 0) != (self.val == 0):
            raise SlimsegError(
                f"--seq-train {self.train} / --seq-val {self.val}: give both at least 1 "
                "world, or both 0"
            )
        if self.train + self.val and (self.frames < 1 or self.step < 1):
            raise SlimsegError(
                f"--seq-frames {self.frames} / --seq-step {self.step}: both must be at least 1"
            )
        if max(self.train, self.val) > FIRST_INDEX["val"] - FIRST_INDEX["train"]:
            raise SlimsegError(f"--seq-train/--seq-val: at most {MAX_EVAL_SEQUENCES} worlds")


def world_name(k: int, preset: str | None) -> str:
    """Folder name of world ``k`` (``003_walking_rpy``; ``_default`` without a preset)."""
    return f"{k:03d}_{preset or 'default'}"


def write_world_split(
    out: Path,
    split: str,
    splits: WorldSplits,
    seed: int,
    size: tuple[int, int],
    on_frame: Callable[[], None] | None = None,
) -> tuple[list[str], int]:
    """Render the ``split`` worlds into ``out / FOLDER[split]``; returns their folders
    (relative to ``out``, in order) and the instances written."""
    names, instances = [], 0
    count = splits.train if split == "train" else splits.val
    for k in range(count):
        preset = WORLD_PRESETS[k % len(WORLD_PRESETS)]
        rel = f"{FOLDER[split]}/{world_name(k, preset)}"
        counts = write_sequence(
            out / rel,
            seed,
            FIRST_INDEX[split] + k,
            splits.frames,
            size,
            on_frame,
            preset,
            step=splits.step,
        )
        names.append(rel)
        instances += counts["instances"]
    return names, instances


#: No sequence-world splits (the default of :func:`~slimseg.data.synth.generate`).
NO_WORLDS = WorldSplits()
