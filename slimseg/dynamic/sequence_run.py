"""Run the reference masking logic over a TUM RGB-D sequence, optionally scoring it.

Per frame: model → detections in frame pixels → ORB keypoints → ``process_modes`` for the
chosen mode → ``masks/<rgb timestamp>.png`` (uint8, 255 = dynamic; the offline mask-cache
convention of DynaSLAM-style runtimes) and a CSV row. When the sequence has ground-truth
``dynamic/`` masks (the synthetic generator writes them), every mode is scored on the same
detections and keypoints: precision and recall of dynamic keypoints.

The epipolar modes get the previous frame's ORB features (``PreviousFrame``); the first frame
has none and behaves like the base mode. ``predictor`` may also be an
:class:`~slimseg.dynamic.annotations.AnnotationInstances` (ground-truth instances of a synthetic
sequence): then the report also counts how the epipolar check classified every checked
instance against its ground-truth ``moving`` flag.
"""

from __future__ import annotations

import csv
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from slimseg.data.tum import TumSequence, mask_name
from slimseg.data.visualize import tile
from slimseg.dynamic.annotations import AnnotationInstances
from slimseg.dynamic.epipolar import PreviousFrame, orb_features
from slimseg.dynamic.masking_settings import DEFAULT, MaskingSettings
from slimseg.dynamic.pipeline import (
    EPIPOLAR_MODES,
    MODES,
    FrameInputs,
    FrameResult,
    FrameRules,
    process_modes,
)
from slimseg.dynamic.semantic import instances_of
from slimseg.utils.atomic import write_png

BOX_MODES = ("box", "box+depth-ransac")  # modes that work without instance masks


@dataclass
class ModeScore:
    """Keypoint-level confusion counts of one mode against ground-truth dynamic masks."""

    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0

    def add(self, dynamic: np.ndarray, truth: np.ndarray) -> None:
        """Count one frame: predicted ``dynamic [N]`` vs ground-truth ``truth [N]`` (bool)."""
        self.tp += int((dynamic & truth).sum())
        self.fp += int((dynamic & ~truth).sum())
        self.fn += int((~dynamic & truth).sum())
        self.tn += int((~dynamic & ~truth).sum())

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else float("nan")

    @property
    def recall(self) -> float:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else float("nan")


@dataclass
class SequenceReport:
    frames: int = 0
    skipped: list[str] = field(default_factory=list)
    scores: dict[str, ModeScore] = field(default_factory=dict)
    ms_per_frame: dict[str, float] = field(default_factory=dict)
    epipolar: dict[str, int] = field(default_factory=dict)
    """GT instances only: ``"<truth> as <decision>"`` counts, truth moving/static, decision
    moving/static/undecided, over every instance the epipolar check looked at."""


def run_sequence(
    predictor: object,
    sequence: Path | TumSequence,
    out: Path,
    mode: str = "fusion",
    masking: MaskingSettings = DEFAULT,
    keypoints: int = 1000,
    progress: bool = True,
    epipolar_depth: bool = False,
) -> SequenceReport:
    """Process every associated frame of ``sequence`` with ``predictor`` (a slimseg
    ``Predictor`` or ``AnnotationInstances``) under the ``masking`` settings (score threshold,
    dilation, Eq. 1/3/4); write masks, ``frames.csv`` and ``overlay.png`` under ``out``.
    ``epipolar_depth``: give the epipolar check the previous depth and the intrinsics
    (depth-aided residual, see ``epipolar``). ``sequence``: the folder, or it opened."""
    seq = sequence if isinstance(sequence, TumSequence) else TumSequence(sequence)
    gt_dir = seq.root / "dynamic"
    mobility = np.asarray(predictor.mobility, np.float32)
    (out / "masks").mkdir(parents=True, exist_ok=True)
    report = SequenceReport(scores={m: ModeScore() for m in MODES} if gt_dir.is_dir() else {})
    rows, panels = [], []
    t_model = t_logic = 0.0
    rng = np.random.default_rng(0)
    step = max(len(seq.frames) // 6, 1)
    gt_instances = isinstance(predictor, AnnotationInstances)
    previous: PreviousFrame | None = None
    settings = FrameRules.from_masking(mobility, mode, masking)
    conf = masking.conf
    for i in tqdm(range(len(seq.frames)), desc="dynamic", disable=not progress):
        rgb, depth, stamp = seq.load(i)
        t0 = time.perf_counter()
        pred = predictor.for_stamp(stamp) if gt_instances else predictor.predict(rgb, conf=conf)
        t1 = time.perf_counter()
        feats = orb_features(rgb, keypoints)  # same keypoints as orb_keypoints, + descriptors
        kps = feats.keypoints
        hw = rgb.shape[:2]
        boxes, classes, masks = instances_of(pred)  # semantic maps: one object per component
        t_prep = time.perf_counter() - t1
        inputs = FrameInputs(kps, boxes, classes, masks, hw, depth, feats.descriptors, previous)
        modes = [mode]
        if report.scores:  # every mode on the same detections and keypoints
            modes += [m for m in MODES if m != mode and (masks is not None or m in BOX_MODES)]
        count_epi = gt_instances and previous is not None and pred.masks is not None
        if count_epi and mode not in EPIPOLAR_MODES and "semantic+epipolar" not in modes:
            modes.append("semantic+epipolar")
        results = process_modes(inputs=inputs, settings=settings, modes=modes, rng=rng)
        result = results[mode]
        t_logic += t_prep + result.seconds  # the chosen mode only, not the scoring of the rest
        t_model += t1 - t0
        name = mask_name(stamp)
        write_png(out / "masks" / name, result.mask)
        rows.append(
            {
                "timestamp": f"{stamp:.6f}",
                **result.counts,
                "m_th": result.m_th,
                "dynamic_frame": result.dynamic_frame,
                "used_seg": result.used_seg,
                "detections": len(boxes),
                "model_ms": round(1000 * (t1 - t0), 2),
            }
        )
        if report.scores:
            gt = cv2.imread(str(gt_dir / name), cv2.IMREAD_GRAYSCALE)
            if gt is None:
                report.skipped.append(str(gt_dir / name))
            else:
                truth = at_keypoints(gt > 0, kps)
                for m, res in results.items():
                    report.scores[m].add(res.dynamic, truth)
        if count_epi:
            epi_mode = mode if mode in EPIPOLAR_MODES else "semantic+epipolar"
            _count_epipolar(report, predictor, stamp, results[epi_mode])
        if epipolar_depth:
            cam = (seq.camera.fx, seq.camera.fy, seq.camera.cx, seq.camera.cy)
            previous = PreviousFrame(feats, depth, cam)
        else:
            previous = PreviousFrame(feats)
        if i % step == 0 and len(panels) < 6:
            panels.append(_overlay(rgb, result.mask, kps, result.dynamic))
        report.frames += 1
    _write_csv(out / "frames.csv", rows)
    if panels:
        write_png(out / "overlay.png", tile(panels, 3))
    n = max(report.frames, 1)
    report.ms_per_frame = {"model": 1000 * t_model / n, "masking_logic": 1000 * t_logic / n}
    return report


def _count_epipolar(
    report: SequenceReport, instances: AnnotationInstances, stamp: float, result: FrameResult
) -> None:
    """Tally an epipolar mode's decisions on this frame's instances against their ``moving``
    flag (``result``: that mode's outcome, with the check it ran)."""
    epi = result.epipolar
    if epi is None:
        return
    truth = instances.moving(stamp)[result.checked]
    for t, dec, mov in zip(truth, epi.decided, epi.moving, strict=True):
        decision = "moving" if mov else ("static" if dec else "undecided")
        key = f"{'moving' if t else 'static'} as {decision}"
        report.epipolar[key] = report.epipolar.get(key, 0) + 1


def at_keypoints(mask: np.ndarray, kps: np.ndarray) -> np.ndarray:
    """``mask [H, W]`` sampled at ``kps [N, 2]`` (x, y) px, rounded and clipped → ``[N]``."""
    h, w = mask.shape
    x = np.clip(np.round(kps[:, 0]).astype(int), 0, w - 1)
    y = np.clip(np.round(kps[:, 1]).astype(int), 0, h - 1)
    return mask[y, x]


def _overlay(rgb: np.ndarray, mask: np.ndarray, kps: np.ndarray, dyn: np.ndarray) -> np.ndarray:
    out = rgb.copy()
    sel = mask > 0
    out[sel] = (0.5 * out[sel] + 0.5 * np.array([255, 0, 0])).astype(np.uint8)
    for (x, y), d in zip(kps.astype(int), dyn, strict=True):
        cv2.circle(out, (int(x), int(y)), 2, (255, 0, 0) if d else (0, 255, 0), -1)
    return out


def _write_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        return
    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, path)
