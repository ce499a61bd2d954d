"""Ground-truth instances of a synthetic sequence as detections (detector-independent tests).

``slimseg data synth --sequences`` writes ``annotations.json`` (COCO, one image per colour
frame, categories with a ``mobility`` prior, annotations with ``track_id`` and ``moving``).
:class:`AnnotationInstances` serves them in the shape of a model's ``Prediction`` so the masking
modes, the epipolar check and restoration can be evaluated without a detector's errors.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slimseg.detections import Prediction
from slimseg.errors import SlimsegError


@dataclass(frozen=True)
class Dropout:
    """Detector misses simulated on ground-truth instances: each instance track loses
    ``rate`` of the frames it appears in, in bursts of ``burst`` consecutive appearances at
    random places (``seed``); what a memory across frames should win back (docs/tracking.md)."""

    rate: float
    burst: int
    seed: int = 0

    def __post_init__(self) -> None:
        if not (0 <= self.rate < 1 and self.burst >= 1):
            raise SlimsegError(
                f"ground-truth dropout {self.rate}:{self.burst}: expected RATE in [0, 1) and "
                "BURST >= 1 frames (e.g. 0.1:3)"
            )

    @classmethod
    def parse(cls, text: str) -> Dropout:
        """``RATE:BURST[:SEED]``, e.g. ``0.1:3`` (10 % of each track's frames, bursts of 3)."""
        parts = text.split(":")
        try:
            if len(parts) not in (2, 3):
                raise ValueError
            return cls(float(parts[0]), int(parts[1]), int(parts[2]) if len(parts) == 3 else 0)
        except ValueError:
            raise SlimsegError(
                f"--gt-dropout {text!r}: expected RATE:BURST[:SEED], e.g. 0.1:3"
            ) from None

    def dropped(self, track: int, n: int) -> np.ndarray:
        """``bool [n]``: which of a track's ``n`` appearances are dropped."""
        out = np.zeros(n, bool)
        bursts = round(self.rate * n / self.burst)
        if bursts == 0 or n == 0:
            return out
        rng = np.random.default_rng([self.seed, track])
        # bursts separated by at least one kept appearance: place them in the slack
        slack = n - bursts * self.burst - (bursts - 1)
        if slack < 0:
            bursts = max((n + 1) // (self.burst + 1), 0)
            slack = n - bursts * self.burst - (bursts - 1)
        gaps = np.sort(rng.integers(0, slack + 1, bursts)) if bursts else []
        start = 0
        prev = 0
        for g in gaps:
            start += int(g) - prev
            prev = int(g)
            out[start : start + self.burst] = True
            start += self.burst + 1
        return out


class AnnotationInstances:
    """Instances of ``<sequence>/annotations.json`` keyed by colour timestamp.

    ``names`` / ``mobility``: per class (class index = COCO category id - 1, as the synth
    categories are numbered 1..K). :meth:`for_stamp` gives one frame's ``Prediction`` (score 1)
    and :meth:`moving` the ``moving`` flag of each of its instances.
    """

    def __init__(self, sequence: str | Path, dropout: Dropout | None = None) -> None:
        path = Path(sequence) / "annotations.json"
        if not path.is_file():
            raise SlimsegError(
                f"{path} not found: ground-truth instances need a synthetic sequence "
                "('slimseg data synth --sequences N')"
            )
        self.path = path
        self._by_stamp: dict[str, tuple[dict, list[dict]]] = {}
        try:  # every field read here: a malformed file is one error naming it, never a traceback
            coco = json.loads(path.read_text(encoding="utf-8"))
            cats = sorted(coco["categories"], key=lambda c: c["id"])
            images = {im["id"]: im for im in coco["images"]}
            if [c["id"] for c in cats] != list(range(1, len(cats) + 1)):
                raise SlimsegError(f"{path}: category ids must be 1..K")
            self.names = [str(c["name"]) for c in cats]
            self.mobility = [float(c.get("mobility", 1.0)) for c in cats]
            if not all(0.0 <= m <= 1.0 for m in self.mobility):
                raise SlimsegError(f"{path}: category mobility must lie in [0, 1]")
            for im in images.values():
                self._by_stamp[f"{float(im['timestamp']):.6f}"] = (im, [])
            for a in coco["annotations"]:
                im = images.get(a["image_id"])
                if im is not None:
                    self._by_stamp[f"{float(im['timestamp']):.6f}"][1].append(a)
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise SlimsegError(f"cannot read {path}: {type(e).__name__} {e}") from None
        self.dropout = dropout
        self.dropped = 0
        if dropout is not None and dropout.rate > 0:
            self._drop(dropout)

    def _drop(self, dropout: Dropout) -> None:
        """Remove the scheduled appearances of every instance track (frames in time order)."""
        keys = sorted(self._by_stamp, key=float)
        seen: dict[int, list[tuple[str, int]]] = {}
        for key in keys:
            for j, a in enumerate(self._by_stamp[key][1]):
                seen.setdefault(int(a.get("track_id", -1)), []).append((key, j))
        drop: set[tuple[str, int]] = set()
        for tid, where in seen.items():
            if tid < 0:
                continue
            flags = dropout.dropped(tid, len(where))
            drop |= {w for w, f in zip(where, flags, strict=True) if f}
        for key in keys:
            im, anns = self._by_stamp[key]
            kept = [a for j, a in enumerate(anns) if (key, j) not in drop]
            self.dropped += len(anns) - len(kept)
            self._by_stamp[key] = (im, kept)

    def _frame(self, stamp: float) -> tuple[dict, list[dict]]:
        key = f"{float(stamp):.6f}"
        if key not in self._by_stamp:
            raise SlimsegError(f"{self.path}: no image with timestamp {key}")
        return self._by_stamp[key]

    def for_stamp(self, stamp: float) -> Prediction:
        """The frame's instances: boxes xyxy, classes, ``masks bool [N, H, W]``."""
        # here, not at the top: slimseg.Masker imports this module and needs neither
        from pycocotools import mask as mask_utils

        from slimseg.data.coco_rle import segm_to_rle

        im, anns = self._frame(stamp)
        h, w = int(im["height"]), int(im["width"])
        masks = np.zeros((len(anns), h, w), bool)
        boxes = np.zeros((len(anns), 4), np.float32)
        classes = np.array([a["category_id"] - 1 for a in anns], np.int64)
        for k, a in enumerate(anns):
            masks[k] = mask_utils.decode(segm_to_rle(a["segmentation"], h, w)) > 0
            x, y, bw, bh = a["bbox"]
            boxes[k] = (x, y, x + bw, y + bh)
        return Prediction(
            boxes=boxes,
            scores=np.ones(len(anns), np.float32),
            classes=classes,
            names=[self.names[c] for c in classes],
            mobility=[self.mobility[c] for c in classes],
            masks=masks,
            image_hw=(h, w),
        )

    def track_ids(self, stamp: float) -> np.ndarray:
        """``int64 [N]``: the ``track_id`` of each instance of the frame (-1 when absent)."""
        return np.array([int(a.get("track_id", -1)) for a in self._frame(stamp)[1]], np.int64)

    def moving(self, stamp: float) -> np.ndarray:
        """``bool [N]``: the ground-truth ``moving`` flag of each instance of the frame."""
        return np.array([bool(a.get("moving", False)) for a in self._frame(stamp)[1]], bool)
