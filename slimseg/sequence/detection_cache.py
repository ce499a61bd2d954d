"""Detections of a whole sequence computed once, then masked under many settings.

A sweep over the masking settings (score threshold, dilation, Eq. 1/3/4) changes only the
post-processing of the detections, so the model runs once per frame, at the lowest score
threshold of the sweep, and every setting filters that cache (:meth:`CachedFrame.above`).

Filtering is exact: NMS is greedy in decreasing score, so a detection is only ever suppressed
by a higher-scoring one; the survivors scoring above ``c`` are therefore the same whether NMS
ran at ``c`` or at any lower threshold (the candidate cap and ``max_det`` keep the highest
scores, which a higher threshold keeps too). Each mask depends only on its own detection.

Masks are stored as their tight bounding crop (a mask is zero outside its box anyway), so a
sequence of 640×480 frames with a few dozen low-score detections per frame stays small.
"""

from __future__ import annotations

import hashlib
import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from slimseg.data.images import decode_file
from slimseg.data.tum import TumSequence, mask_name
from slimseg.dynamic.chain_config import TRACK_OFF, ChainConfig, TrackPlan
from slimseg.dynamic.epipolar import OrbFeatures, orb_features
from slimseg.dynamic.familiarity import frame_shares
from slimseg.dynamic.frame_masker import FrameMasker, segmenter_for
from slimseg.dynamic.mask_patch import Patch, pack_masks, unpack_masks
from slimseg.dynamic.masking_settings import MaskingSettings
from slimseg.dynamic.modes import KEYPOINTS, Mode
from slimseg.objects import Objects
from slimseg.sequence.sequence_report import ModeScore, truth_regions
from slimseg.sequence.sequence_run import sequence_config
from slimseg.utils.atomic import write_png

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CachedFrame:
    """One frame: colour ``stamp``, ORB ``features`` (keypoints + descriptors), the model's
    ``objects`` (decreasing score, masks left out) with their masks as tight ``crops`` (None:
    a box-only model), ground-truth dynamic flag per keypoint ``truth bool [N]`` (None: no
    ``dynamic/`` mask), the model and preparation (ORB + mask crops) times in ms, and the
    ground-truth region under each keypoint ``regions int32 [N]`` (0: static; None: no
    ``dynamic/`` mask)."""

    stamp: float
    features: OrbFeatures
    objects: Objects
    crops: list[Patch] | None
    truth: np.ndarray | None
    model_ms: float
    prep_ms: float
    regions: np.ndarray | None = None

    def above(self, conf: float) -> Objects:
        """The objects scoring above ``conf``, their masks restored, in the cached order."""
        keep = np.flatnonzero(self.objects.scores > conf)
        rows = self.objects[keep]
        if self.crops is None:
            return rows
        return replace(rows, masks=unpack_masks([self.crops[k] for k in keep], rows.hw))


@dataclass
class DetectionCache:
    """Every associated frame of ``sequence`` run through the model once at ``conf_floor``;
    ``mobility [K]``: the model's class priors; ``calls``: model invocations made."""

    sequence: TumSequence
    conf_floor: float
    mobility: np.ndarray
    frames: list[CachedFrame] = field(default_factory=list)
    calls: int = 0

    @property
    def model_ms(self) -> float:
        """Mean model time per frame (ms)."""
        return float(np.mean([f.model_ms for f in self.frames])) if self.frames else 0.0

    @property
    def prep_ms(self) -> float:
        """Mean ORB + instance extraction time per frame (ms)."""
        return float(np.mean([f.prep_ms for f in self.frames])) if self.frames else 0.0


def build_cache(
    predictor: object,
    sequence: TumSequence,
    conf_floor: float,
    keypoints: int = KEYPOINTS,
    progress: bool = True,
) -> DetectionCache:
    """Run ``predictor`` (a slimseg ``Predictor`` or ``AnnotationInstances``) once per frame of
    ``sequence`` at score threshold ``conf_floor`` and keep everything a setting needs."""
    gt_dir = sequence.root / "dynamic"
    cache = DetectionCache(sequence, conf_floor, np.asarray(predictor.mobility, np.float32))
    segment = segmenter_for(predictor)
    for i in tqdm(range(len(sequence)), desc="detections", disable=not progress):
        rgb, _, stamp = sequence.load(i)
        t0 = time.perf_counter()
        objects = segment(rgb, stamp, conf_floor)
        cache.calls += 1
        t1 = time.perf_counter()
        feats = orb_features(rgb, keypoints, corners=True)  # corners: any setting's rule
        crops = pack_masks(objects.masks)
        t2 = time.perf_counter()
        truth = regions = None
        gt = decode_file(gt_dir / mask_name(stamp), cv2.IMREAD_GRAYSCALE)
        if gt is not None:
            regions = truth_regions(gt > 0, feats.keypoints)
            truth = regions > 0
        kept = replace(objects, masks=None)
        ms = (1000 * (t1 - t0), 1000 * (t2 - t1))
        cache.frames.append(CachedFrame(stamp, feats, kept, crops, truth, *ms, regions))
    log.debug("%d frames cached at conf %.3f, %d model calls", len(cache.frames), conf_floor,
             cache.calls)  # fmt: skip
    return cache


@dataclass
class SettingMasks:
    """The masks of one setting: keypoint confusion ``score`` against ``dynamic/`` (None: no
    ground truth), the masking logic's mean time per frame (ms), the frames written and a
    ``digest`` of every mask (equal digests: identical masks)."""

    score: ModeScore | None
    logic_ms: float
    frames: int
    digest: str = ""
    model_share: float = 1.0
    """share of frames the model ran on (``--rate N``: 1/N)"""
    mask_share: float = 0.0
    """mean share of the frame masked"""
    static_share: float = 1.0
    """mean share of the frame's keypoints left static (the support a SLAM engine keeps)"""


def mask_with(
    cache: DetectionCache,
    mode: Mode | str,
    masking: MaskingSettings,
    out: Path | None,
    track: TrackPlan = TRACK_OFF,
) -> SettingMasks:
    """Apply ``mode`` under ``masking`` to every cached frame; write ``out/<rgb ts>.png``
    (uint8, 255 = dynamic; None: score only, write nothing), exactly what ``slimseg dynamic
    --mode mode`` writes for these
    settings: the same :class:`~slimseg.dynamic.frame_masker.FrameMasker` on the sequence's
    frames, its model and its ORB extractor answered from the cache. ``track``: the track
    stage (the cache must hold detections down to its ``low`` threshold) at a fixed rate
    (every N: the model's time counts once per N frames)."""
    if track.on and cache.conf_floor > track.floor(masking.conf) + 1e-9:
        raise ValueError(f"the cache holds detections from conf {cache.conf_floor}; the track "
                         f"stage needs them from {track.floor(masking.conf)}")  # fmt: skip
    if not track.rate.fixed:
        raise ValueError(f"a cached sweep replays a fixed model rate, not {track.rate.name}")
    seq = cache.sequence
    have_truth = all(f.truth is not None for f in cache.frames)
    score = ModeScore() if have_truth and cache.frames else None
    t_logic, masked, static = 0.0, 0.0, 0.0
    digest = hashlib.sha1()
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    frames = {f.stamp: f for f in cache.frames}
    config = sequence_config(seq, ChainConfig(mode=mode, masking=masking, track=track))
    masker = FrameMasker(
        lambda rgb, stamp, conf: frames[stamp].above(conf), cache.mobility, config,
        extractor=lambda rgb, stamp: frames[stamp].features,
    )  # fmt: skip
    with masker:
        for i, f in enumerate(cache.frames):
            rgb, depth, _ = seq.load(i)  # reading is not the logic's time
            res = masker.step(rgb, depth, f.stamp)
            t_logic += res.timing.masking / 1000
            if out is not None:
                write_png(out / mask_name(f.stamp), res.mask)
            digest.update(np.ascontiguousarray(res.mask).tobytes())
            share, kept = frame_shares(res.mask, res.dynamic)
            masked, static = masked + share, static + kept
            if score is not None:
                score.add(res.dynamic, f.truth)
                if f.regions is not None:
                    score.add_walkers(res.dynamic, f.regions)
    n = max(len(cache.frames), 1)
    logic_ms = 1000 * t_logic / n + cache.prep_ms
    return SettingMasks(score, logic_ms, len(cache.frames), digest.hexdigest(),
                        1.0 / track.rate.every, masked / n, static / n)  # fmt: skip
