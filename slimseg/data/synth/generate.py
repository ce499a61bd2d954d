"""Write the whole embedded dataset: image-mode train/val splits, TUM sequences, data.yaml."""

from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from slimseg.data.synth.categories import CATEGORIES, MOBILITY, NAMES
from slimseg.data.synth.coco_writer import CocoBuilder, frame_annotations
from slimseg.data.synth.presets import PRESETS, default_exposure_ms
from slimseg.data.synth.scene import STREAM_TRAIN, STREAM_VAL, render_image
from slimseg.data.synth.sequence import write_sequence
from slimseg.data.synth.world import FPS
from slimseg.data.synth.world_frames import (
    FOLDER,
    MAX_EVAL_SEQUENCES,
    NO_WORLDS,
    WorldSplits,
    write_world_split,
)
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import write_manifest, write_png, write_text
from slimseg.utils.manifest import confined_name
from slimseg.utils.outputs import claim_folder, named_folder, read_manifest

_WRITES = ("train", "val", "sequences", *FOLDER.values(), "data.yaml")  # every entry it makes


@dataclass
class SynthReport:
    """What :func:`generate` wrote: images per split, image-mode instances per class,
    sequence counts, wall time and the data.yaml path."""

    data_yaml: Path
    images: dict[str, int] = field(default_factory=dict)
    instances: dict[str, int] = field(default_factory=dict)
    sequences: int = 0
    frames: int = 0
    sequence_instances: int = 0
    world_frames: dict[str, int] = field(default_factory=dict)
    world_instances: int = 0
    seconds: float = 0.0

    def summary(self) -> str:
        """One line for the terminal."""
        parts = []
        if self.images:
            imgs = " + ".join(f"{n} {s}" for s, n in self.images.items())
            per_class = ", ".join(f"{name} {self.instances.get(name, 0)}" for name in NAMES)
            parts.append(f"{imgs} images (instances: {per_class})")
        if self.world_frames:
            frames = " + ".join(f"{n} {s}" for s, n in self.world_frames.items())
            parts.append(f"{frames} sequence-world frames ({self.world_instances} instances)")
        if self.sequences:
            plural = "s" if self.sequences != 1 else ""
            parts.append(
                f"{self.sequences} sequence{plural} x {self.frames} frames "
                f"({self.sequence_instances} instances)"
            )
        return f"synth: {'; '.join(parts)}; {self.seconds:.1f} s; data: {self.data_yaml}"


def _check(
    out: Path,
    train: int,
    val: int,
    imgsz: int,
    seed: int,
    sequences: int,
    frames: int,
    seq_size: tuple[int, int],
    overwrite: bool,
    exposure_ms: float | None,
    worlds: WorldSplits,
) -> None:
    worlds.check()
    if train < 0 or val < 0 or (train == 0) != (val == 0):
        raise SlimsegError(
            f"--train {train} / --val {val}: give both splits at least 1 image, or both 0 "
            "with --sequences N (a sequences-only dataset)"
        )
    if train == val == sequences == worlds.train == 0:
        raise SlimsegError(
            "--train 0 --val 0 --sequences 0: nothing to generate; give --train N --val N, "
            "--seq-train N --seq-val N and/or --sequences N"
        )
    if sequences >= MAX_EVAL_SEQUENCES:
        raise SlimsegError(f"--sequences {sequences}: at most {MAX_EVAL_SEQUENCES - 1}")
    if seed < 0:
        raise SlimsegError(f"--seed {seed} must be 0 or more")
    if imgsz < 64 or imgsz % 32:
        raise SlimsegError(f"--imgsz {imgsz} must be a multiple of 32 and at least 64")
    if sequences < 0:
        raise SlimsegError(f"--sequences {sequences} must be 0 or more")
    if sequences and frames < 1:
        raise SlimsegError(f"--frames {frames} must be at least 1")
    if exposure_ms is not None and not 0.0 <= exposure_ms <= 1000.0 / FPS:
        raise SlimsegError(
            f"--exposure-ms {exposure_ms:g}: the shutter time must be 0 (no motion blur) to "
            f"{1000.0 / FPS:.1f} ms (one frame interval at {FPS:g} Hz)"
        )
    if min(seq_size) < 64:
        raise SlimsegError(f"--seq-size {seq_size[0]} {seq_size[1]}: both must be at least 64")
    named_folder(out, "--out")
    if out.exists() and not out.is_dir():
        raise SlimsegError(f"--out {out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise SlimsegError(f"--out {out} is not empty (pass --overwrite to replace the dataset)")
    if overwrite:  # only a folder data synth wrote (its manifest lists every entry)
        claim_folder(out, "--out", own=_WRITES)


def generate(
    out: Path,
    train: int,
    val: int,
    imgsz: int,
    seed: int,
    sequences: int = 0,
    frames: int = 60,
    *,
    seq_size: tuple[int, int] = (640, 480),
    overwrite: bool = False,
    progress: bool = True,
    preset: str | None = None,
    exposure_ms: float | None = None,
    worlds: WorldSplits = NO_WORLDS,
) -> SynthReport:
    """Render and write the dataset into ``out``; returns a :class:`SynthReport`.

    Layout: ``out/{train,val}/{images,depth}/NNNNNN.png`` (RGB PNG; uint16 TUM depth),
    ``out/{train,val}/annotations.json`` (COCO, RLE), ``out/sequences/seq_KKK/`` (TUM layout,
    see :mod:`slimseg.data.synth.sequence`) and ``out/data.yaml``, written last. Every file is
    written atomically, and a manifest (:data:`slimseg.utils.outputs.MANIFEST`) lists them.
    ``overwrite`` first deletes what that manifest lists, and refuses a folder holding anything
    else (a folder that was never a synthetic dataset is never deleted). ``preset``: the
    sequences' camera path and walkers (:mod:`slimseg.data.synth.presets`); ``exposure_ms``:
    the sequences' motion-blur shutter time (None: the preset's default; 0: none).
    ``train = val = 0`` with sequences writes a sequences-only dataset (no image splits in
    data.yaml). ``worlds``: training/validation frames rendered from the sequence world
    (:mod:`slimseg.data.synth.world_frames`, ``out/{train,val}_sequences/``), the splits'
    ``sequences`` in data.yaml, alone or beside the still images. Raises ``SlimsegError`` on
    bad input.
    """
    out = Path(out)
    if preset is not None and preset not in PRESETS:
        raise SlimsegError(f"--preset {preset!r}: valid presets are {sorted(PRESETS)}")
    _check(
        out, train, val, imgsz, seed, sequences, frames, seq_size, overwrite, exposure_ms, worlds
    )
    start = time.perf_counter()
    if overwrite and out.is_dir():  # claimed by _check: every entry is an earlier synth's
        for name in sorted(read_manifest(out) or ()):  # each confined and unchanged (_check)
            if not confined_name(name):
                continue
            p = out / name
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            elif os.path.lexists(p):
                p.unlink()
    out.mkdir(parents=True, exist_ok=True)
    write_manifest(out, "data synth", (), announced=_WRITES)  # an interrupted run: overwritable
    report = SynthReport(data_yaml=out / "data.yaml", sequences=sequences, frames=frames)
    total = train + val + sequences * frames + (worlds.train + worlds.val) * worlds.per_world
    world_folders: dict[str, list[str]] = {}
    with tqdm(total=total, desc="synth", unit="img", disable=not progress) as bar:
        for split, n, stream in (("train", train, STREAM_TRAIN), ("val", val, STREAM_VAL)):
            if n:
                _write_split(out / split, n, imgsz, seed, stream, report, bar)
                report.images[split] = n
            if worlds.train:
                names, inst = write_world_split(out, split, worlds, seed, seq_size, bar.update)
                world_folders[split] = names
                report.world_frames[split] = len(names) * worlds.per_world
                report.world_instances += inst
        for s in range(sequences):
            counts = write_sequence(
                out / "sequences" / f"seq_{s:03d}",
                seed,
                s,
                frames,
                seq_size,
                bar.update,
                preset,
                exposure_ms,
            )
            report.sequence_instances += counts["instances"]
    command = synth_command(
        train,
        val,
        imgsz,
        seed,
        sequences,
        frames,
        seq_size,
        preset,
        exposure_ms=exposure_ms,
        worlds=worlds,
    )
    _write_data_yaml(out, command, train > 0, sequences, world_folders)
    write_manifest(out, "data synth", _WRITES)  # what --overwrite may delete next time
    report.seconds = time.perf_counter() - start
    return report


def _write_split(
    root: Path, n: int, imgsz: int, seed: int, stream: int, report: SynthReport, bar: tqdm
) -> None:
    (root / "images").mkdir(parents=True, exist_ok=True)
    (root / "depth").mkdir(parents=True, exist_ok=True)
    coco = CocoBuilder(f"slimseg synthetic {root.name} split (seed {seed}, {imgsz} px)")
    for i in range(n):
        frame = render_image(seed, i, imgsz, stream)
        name = f"{i:06d}.png"
        write_png(root / "images" / name, frame.rgb)
        write_png(root / "depth" / name, frame.depth)
        image = {"id": i + 1, "file_name": name, "width": imgsz, "height": imgsz}
        anns = frame_annotations(frame, i + 1)
        coco.add(image | {"depth_file": name}, anns)
        for a in anns:
            cat = CATEGORIES[a["category_id"] - 1].name
            report.instances[cat] = report.instances.get(cat, 0) + 1
        bar.update()
    coco.write(root / "annotations.json")


def _yaml_list(values: list) -> str:
    return "[" + ", ".join(str(v) for v in values) + "]"


def synth_command(
    train: int,
    val: int,
    imgsz: int,
    seed: int,
    sequences: int = 0,
    frames: int = 60,
    seq_size: tuple[int, int] = (640, 480),
    preset: str | None = None,
    out: str = "<dir>",
    exposure_ms: float | None = None,
    worlds: WorldSplits = NO_WORLDS,
) -> str:
    """The ``slimseg data synth`` command that writes exactly this dataset into ``out``: every
    option that changes a file (sequence options only with sequences; ``--exposure-ms`` only
    when it is not the preset's default), none that does not (``--overwrite``, ``--quiet``)."""
    parts = [f"slimseg data synth --out {out} --train {train} --val {val}"]
    parts.append(f"--imgsz {imgsz} --seed {seed}")
    if worlds.train:
        parts.append(f"--seq-train {worlds.train} --seq-val {worlds.val}")
        parts.append(f"--seq-frames {worlds.frames} --seq-step {worlds.step}")
    if sequences or worlds.train:
        parts.append(f"--seq-size {seq_size[0]} {seq_size[1]}")
    if sequences:
        parts.append(f"--sequences {sequences} --frames {frames}")
        if preset is not None:
            parts.append(f"--preset {preset}")
        if exposure_ms is not None and exposure_ms != default_exposure_ms(preset):
            short = f"{exposure_ms:g}"  # repr when %g would round it
            parts.append(
                f"--exposure-ms {short if float(short) == exposure_ms else repr(exposure_ms)}"
            )
    return " ".join(parts)


def _write_data_yaml(
    out: Path, command: str, images: bool, sequences: int, worlds: dict[str, list[str]]
) -> None:
    """``data.yaml``: the splits when there are images or sequence-world frames (a
    sequences-only set has none: ``slimseg train`` then says so), names and mobility always,
    the sequence folders. A split with both lists its worlds beside the images (and no depth
    folder: depth goes with an images-only split)."""
    lines = [
        "# slimseg synthetic dataset; to regenerate it (<dir>: this folder):",
        f"# {command}",
        "path: .",
    ]
    for split in ("train", "val") if images or worlds else ():
        keys = []
        if images:
            keys.append(f"images: {split}/images, annotations: {split}/annotations.json")
            if not worlds:
                keys.append(f"depth: {split}/depth")
        if worlds:
            keys.append("sequences: " + _yaml_list(worlds[split]))
        lines.append(f"{split}: {{{', '.join(keys)}}}")
    lines.append("names: " + _yaml_list([f"'{n}'" if " " in n else n for n in NAMES]))
    lines.append("mobility: " + _yaml_list(list(MOBILITY)))
    if sequences:
        lines.append(
            "sequences: " + _yaml_list([f"sequences/seq_{s:03d}" for s in range(sequences)])
        )
    write_text(out / "data.yaml", "\n".join(lines) + "\n")
