"""Calibration frames for INT8: real images of the user's data, letterboxed exactly as the
predictor letterboxes them (:func:`~slimseg.deploy.preprocess.preprocess_frame`).

A source is a data YAML (its ``val`` split's images, in json order) or a folder of images
(sorted by name, not recursive). Frames are read again on every pass rather than held in
memory (300 frames at 640 px are 1.5 GB of float32).
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slimseg.data.coco import CocoDataset, ImageProblem, read_image_rgb8
from slimseg.data.config import DataConfig, load_data_config
from slimseg.data.frame_files import IMAGE_SUFFIXES
from slimseg.deploy.preprocess import preprocess_frame
from slimseg.errors import SlimsegError

log = logging.getLogger(__name__)

DEFAULT_CALIB_IMAGES = 300


@dataclass
class CalibrationSet:
    """The frames a calibration uses. ``paths``: readable images, at most the number asked;
    ``data``: the data config when the source is a YAML (its val split gates the accuracy);
    ``skipped``: unreadable files passed over; ``digest``: sha256 (16 hex digits) over the
    used files' names and bytes, recorded in the export's metadata."""

    source: Path
    paths: list[Path]
    data: DataConfig | None
    skipped: int
    digest: str

    def frames(self) -> Iterator[np.ndarray]:
        """RGB ``uint8 [h, w, 3]`` frames, in order."""
        for path in self.paths:
            yield read_image_rgb8(path)[0]

    def inputs(self, imgsz: tuple[int, int]) -> Iterator[np.ndarray]:
        """Network inputs ``float32 [1, 3, H, W]``, letterboxed as the predictor does."""
        for frame in self.frames():
            yield preprocess_frame(frame, imgsz)[0]


def _candidates(source: Path) -> tuple[list[Path], DataConfig | None]:
    if source.is_dir():
        files = sorted(p for p in source.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        return files, None
    if source.suffix.lower() in (".yaml", ".yml") and source.is_file():
        data = load_data_config(source)
        val = CocoDataset.from_config(data, "val")
        return [val.image_path(i) for i in range(len(val))], data
    raise SlimsegError(
        f"--calib {source}: not a data YAML or a folder of images; pass DATA.yaml (its val "
        "split is used) or a folder of frames from the deployment domain"
    )


def load_calibration_set(source: str | Path, images: int | None = None) -> CalibrationSet:
    """The first ``images`` readable frames of ``source`` (default: up to
    :data:`DEFAULT_CALIB_IMAGES`, all if fewer). An explicit ``images`` larger than what the
    source holds is an error that says how many there are; no readable image at all too."""
    source = Path(source)
    if images is not None and images < 1:
        raise SlimsegError(f"--calib-images {images}: need at least 1")
    wanted = images or DEFAULT_CALIB_IMAGES
    paths: list[Path] = []
    skipped = 0
    digest = hashlib.sha256()
    candidates, data = _candidates(source)
    for path in candidates:
        if len(paths) == wanted:
            break
        try:
            read_image_rgb8(path)
        except ImageProblem as exc:
            log.warning("calibration: skipping %s", exc)
            skipped += 1
            continue
        paths.append(path)
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    if not paths:
        raise SlimsegError(
            f"--calib {source}: no readable images ({skipped} unreadable of "
            f"{len(candidates)} files); point it at a folder of .jpg/.png frames or a data YAML"
        )
    if images is not None and len(paths) < images:
        raise SlimsegError(
            f"--calib {source}: only {len(paths)} readable images, {images} asked; pass "
            f"--calib-images {len(paths)} (or add frames)"
        )
    if len(paths) < wanted:
        log.warning("calibration: %s has %d readable images; using all of them", source, len(paths))
    return CalibrationSet(source, paths, data, skipped, digest.hexdigest()[:16])
