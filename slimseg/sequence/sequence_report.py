"""What a sequence run reports and draws: keypoint scores per mode, the report, the overlay
panels, the CSV rows (used by :mod:`slimseg.sequence.sequence_run` and the sweeps' cache)."""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from slimseg.dynamic.threshold import inside
from slimseg.objects import Objects
from slimseg.sequence.precision_loss import PrecisionLoss
from slimseg.sequence.recall_loss import DROPOUT_COVER, RecallLoss

#: Keypoints a ground-truth dynamic region needs in a frame to count as a walker there (fewer:
#: a sliver at the frame's edge or behind an occluder, whose miss a SLAM engine barely sees).
WALKER_MIN_KEYPOINTS = 8


def truth_regions(truth_mask: np.ndarray, kps: np.ndarray) -> np.ndarray:
    """The connected region (8-connected) of ``truth_mask bool [H, W]`` each of ``kps [N, 2]``
    lies on → ``int32 [N]`` (0: static). Regions stand in for walkers where a sequence has
    ground-truth masks but no instances (two walkers that touch are one region)."""
    _, labels = cv2.connectedComponents(np.asarray(truth_mask, np.uint8), connectivity=8)
    return at_keypoints(labels, kps).astype(np.int32)


@dataclass
class ModeScore:
    """Keypoint-level confusion counts of one mode against ground-truth dynamic masks, and
    walker-frames: ground-truth regions with at least :data:`WALKER_MIN_KEYPOINTS` keypoints
    in a frame, ``walkers_missed`` of them with under :data:`DROPOUT_COVER` of their
    keypoints flagged (a walker lost in that frame, whose points all enter the map)."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0
    walkers: int = 0
    walkers_missed: int = 0

    def add(self, dynamic: np.ndarray, truth: np.ndarray) -> None:
        """Count one frame: predicted ``dynamic [N]`` vs ground-truth ``truth [N]`` (bool)."""
        self.tp += int((dynamic & truth).sum())
        self.fp += int((dynamic & ~truth).sum())
        self.fn += int((~dynamic & truth).sum())
        self.tn += int((~dynamic & ~truth).sum())

    def add_walkers(self, dynamic: np.ndarray, regions: np.ndarray) -> None:
        """Count one frame's walker-frames: predicted ``dynamic bool [N]`` against the
        ground-truth region of each keypoint ``regions int [N]`` (:func:`truth_regions`)."""
        ids, counts = np.unique(regions[regions > 0], return_counts=True)
        for rid in ids[counts >= WALKER_MIN_KEYPOINTS]:
            on = regions == rid
            self.walkers += 1
            self.walkers_missed += int(dynamic[on].mean() < DROPOUT_COVER)

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else float("nan")

    @property
    def recall(self) -> float:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else float("nan")

    @property
    def walker_recall(self) -> float:
        """Share of walker-frames not missed (NaN: none counted)."""
        return 1 - self.walkers_missed / self.walkers if self.walkers else float("nan")


@dataclass
class SequenceReport:
    frames: int = 0
    skipped: list[str] = field(default_factory=list)
    scores: dict[str, ModeScore] = field(default_factory=dict)
    ms_per_frame: dict[str, float] = field(default_factory=dict)
    epipolar: dict[str, int] = field(default_factory=dict)
    """GT instances only: ``"<truth> as <decision>"`` counts, truth moving/static, decision
    moving/static/undecided, over every instance the epipolar check looked at."""
    recall_loss: RecallLoss | None = None
    """the chosen mode's missed keypoints split by dropout vs partial cover, ghosts
    (sequences with ``annotations.json`` and ``dynamic/``)"""
    precision_loss: PrecisionLoss | None = None
    """the chosen mode's false dynamic keypoints by what they lie on: a static instance's
    class or the background (the same sequences)"""
    model_frames: int = 0
    """frames the model ran on (``--rate N``: about frames / N)"""
    coasted: int = 0
    """predicted masks the track stage emitted (coasted or carried)"""
    latency_ms: list[float] = field(default_factory=list)
    """per frame: from when the loop takes it up (at its arrival in a real-time replay, or
    later when the loop is behind) to its mask being ready (the chosen mode; before the
    writing and the scoring): what a SLAM front end waits per frame"""
    late_ms: list[float] = field(default_factory=list)
    """real-time replay: per frame, how long after its arrival the loop took it up (the
    replay's own reading, scoring and writing count here; a runtime has none of them)"""
    model_lags: list[int] = field(default_factory=list)
    """per model result used: frames between the frame it was computed on and the one it fed"""
    model_ms_per_run: float = 0.0
    """mean wall time of one model run (on whichever thread)"""
    stage_parts_ms: dict[str, float] = field(default_factory=dict)
    """the track stage's time per frame by part (``slimseg.dynamic.track.STAGE_PARTS``)"""
    rate: str = ""
    """how the model's rate was set (``ModelFeed.describe``)"""
    gave_up: int = 0
    """frames the chosen mode's rule masked nothing while objects were candidates (Eq. 1
    giving up the frame)"""
    dropped: int = 0
    """candidate objects the rule left out of the mask, over the sequence"""
    dropped_confident_frames: int = 0
    """frames in which the rule left out a candidate scoring at least ``keep_score``"""


def coasted_only(objects: Objects) -> np.ndarray | None:
    """``bool [H, W]``: pixels only predicted masks (coasted or carried) cover, no detection's
    (None: no predicted mask, or a box-only model)."""
    masks, predicted = objects.masks, objects.predicted
    if masks is None or not predicted.any():
        return None
    det = masks[~predicted].any(0) if (~predicted).any() else np.zeros(objects.hw, bool)
    return masks[predicted].any(0) & ~det


def track_rows(stamp: float, objects: Objects) -> list[dict]:
    """``tracks.csv`` rows of one frame: every object the track stage emitted, with the
    mobility the masking rules used."""
    return [
        {
            "timestamp": f"{stamp:.6f}",
            "track_id": int(objects.track_ids[k]),
            "class": int(objects.classes[k]),
            "source": objects.source[k],
            "misses": int(objects.misses[k]),
            "mobility": round(float(objects.mobility[k]), 4),
            "score": round(float(objects.scores[k]), 4),
            "box": " ".join(f"{v:.1f}" for v in objects.boxes[k]),
        }
        for k in range(len(objects))
    ]


def at_keypoints(mask: np.ndarray, kps: np.ndarray) -> np.ndarray:
    """``mask [H, W]`` sampled at ``kps [N, 2]`` (x, y) px, rounded and clipped → ``[N]``."""
    return inside(kps, np.asarray(mask)[None])[0]


def overlay(
    rgb: np.ndarray,
    mask: np.ndarray,
    kps: np.ndarray,
    dyn: np.ndarray,
    coasted: np.ndarray | None = None,
) -> np.ndarray:
    """Red: the dynamic mask; yellow: its part that only coasted masks cover."""
    out = rgb.copy()
    sel = mask > 0
    out[sel] = (0.5 * out[sel] + 0.5 * np.array([255, 0, 0])).astype(np.uint8)
    if coasted is not None:
        c = coasted & sel
        out[c] = (0.4 * rgb[c] + 0.6 * np.array([255, 220, 0])).astype(np.uint8)
    for (x, y), d in zip(kps.astype(int), dyn, strict=True):
        cv2.circle(out, (int(x), int(y)), 2, (255, 0, 0) if d else (0, 255, 0), -1)
    return out


def write_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        return
    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, path)
