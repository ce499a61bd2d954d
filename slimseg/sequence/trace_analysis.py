"""What a sequence run's report makes of the frames the chain produced (its trace).

The chain (:class:`~slimseg.dynamic.frame_masker.FrameMasker`) runs one mode and scores
nothing. :class:`TraceAnalysis` observes each :class:`~slimseg.dynamic.frame_masker.
MaskedFrame` it returned: it runs every other mode on the inputs the chain's rules saw (the
same objects, keypoints, depth and previous frame), scores each against the ground-truth
``dynamic/`` masks, splits where recall is lost, tallies the epipolar check against
ground-truth instances and draws the overlay panels. Inline for inline model rates; for a
real-time run (the model on its own thread) it keeps the trace (masks as crops, depth read
again later) and analyses it after the run, so the analysis takes no CPU from the model's
thread.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from slimseg.data.frame_source import FrameSource
from slimseg.data.images import decode_file
from slimseg.data.tum import mask_name
from slimseg.data.visualize import tile
from slimseg.dynamic.annotations import AnnotationInstances
from slimseg.dynamic.mask_patch import Patch, pack_masks, unpack_masks
from slimseg.dynamic.masked_frame import MaskedFrame
from slimseg.dynamic.modes import BOX_MODES, EPIPOLAR_MODES, Mode
from slimseg.dynamic.occupancy import MotionLayers
from slimseg.dynamic.pipeline import FrameResult, FrameRules, apply_rules
from slimseg.objects import Objects
from slimseg.sequence.precision_loss import PrecisionLoss
from slimseg.sequence.recall_loss import FrameInstances, RecallLoss
from slimseg.sequence.sequence_report import SequenceReport, at_keypoints, coasted_only, overlay
from slimseg.utils.atomic import write_png

PANELS = 6  # overlay panels, spread over the sequence


class TraceAnalysis:
    """The analysis of one run over ``seq`` whose chain used ``rules``; ``score``: the modes
    to score (the chain's own among them or not); ``gt_instances``: the ground-truth
    instances the run masked with (None: a model); ``deferred``: keep the trace and analyse
    it in :meth:`finish` (a real-time run)."""

    def __init__(
        self,
        seq: FrameSource,
        gt_instances: AnnotationInstances | None,
        report: SequenceReport,
        rules: FrameRules,
        score: tuple[str, ...],
        deferred: bool = False,
    ) -> None:
        self.seq, self.report, self.gt_instances, self.rules = seq, report, gt_instances, rules
        self.score = tuple(m for m in score if m != rules.mode)
        self.deferred = deferred
        self.gt_dir = seq.root / "dynamic"
        ann = (seq.root / "annotations.json").is_file()
        self.losses = RecallLoss() if self.gt_dir.is_dir() and ann else None
        self.false = PrecisionLoss() if self.losses is not None else None
        self.instances = _instances(gt_instances, seq.root) if self.losses is not None else None
        self.every = max(len(seq.frames) // PANELS, 1)
        self.panels: list[np.ndarray] = []
        self.stamps: list[float] = []
        self.kept: list[tuple[MaskedFrame, list[Patch] | None]] = []
        self._rng = np.random.default_rng(0)  # depth-RANSAC's sampling, as the chain's

    def observe(self, f: MaskedFrame, rgb: np.ndarray) -> None:
        """One frame of the run, with its colour image ``rgb uint8 [H, W, 3]``."""
        if self.deferred:
            self.kept.append(_packed(f))
        else:
            self._frame(f, rgb)

    def finish(self, out: Path, use_depth: bool = True) -> None:
        """Analyse a kept trace (its frames read again), then write ``overlay.png``."""
        depth_before = None
        for i, (kept, crops) in enumerate(self.kept):
            rgb, depth, _ = self.seq.load(i)
            depth = depth if use_depth else None
            self._frame(_unpacked(kept, crops, depth, depth_before), rgb)
            depth_before = depth
        self.kept = []
        if self.losses is not None:
            self.report.recall_loss = self.losses.finish()
            self.report.precision_loss = self.false
        if self.panels:
            write_png(out / "overlay.png", tile(self.panels, 3))

    def _frame(self, f: MaskedFrame, rgb: np.ndarray) -> None:
        report, result, kps, stamp = self.report, f.result, f.keypoints, f.stamp
        results = {self.rules.mode: result, **self._others(f)}
        only = coasted_only(f.objects)
        if report.scores:
            gt = decode_file(self.gt_dir / mask_name(stamp), cv2.IMREAD_GRAYSCALE)
            if gt is None:
                report.skipped.append(str(self.gt_dir / mask_name(stamp)))
            else:
                truth = at_keypoints(gt > 0, kps)
                for m, res in results.items():
                    report.scores[m].add(res.dynamic, truth)
                if self.losses is not None:  # the frame's instances decoded once for both
                    frame = FrameInstances.of(self.instances, stamp)
                    self.losses.add(frame, kps, result.dynamic, truth, result.mask > 0, only)
                    self.false.add(frame, kps, result.dynamic, truth)
        self.stamps.append(stamp)
        self._tally(f, results)
        if f.index % self.every == 0 and len(self.panels) < PANELS:
            self.panels.append(overlay(rgb, result.mask, kps, result.dynamic, only))

    def _others(self, f: MaskedFrame) -> dict[str, FrameResult]:
        """The other modes on the frame's inputs: those it allows (instance masks for all
        but the box modes, depth for depth-RANSAC), each deciding its objects' mobility its
        own way (without the chain's tracks: they cannot be replayed); the motion layers and
        the epipolar verdict are computed once for all of them."""
        inputs = f.inputs
        modes = [
            m for m in self.score
            if (inputs.objects.masks is not None or m in BOX_MODES)
            and (m != Mode.BOX_DEPTH_RANSAC or inputs.depth_m is not None)
        ]  # fmt: skip
        moved = MotionLayers.of(inputs, self.rules.masking) if modes else None
        verdict = None  # the epipolar check, shared by both epipolar modes
        out = {}
        for mode in map(Mode, modes):
            t0 = time.perf_counter()
            if mode in EPIPOLAR_MODES:
                verdict = verdict or self.rules.decide(inputs, mode)
                decision = verdict
            else:
                decision = self.rules.decide(inputs, mode)
            res = apply_rules(inputs, decision, self.rules, mode=mode, rng=self._rng,
                              moved=moved)  # fmt: skip
            out[mode.value] = replace(res, seconds=time.perf_counter() - t0)
        return out

    def _tally(self, f: MaskedFrame, results: dict[str, FrameResult]) -> None:
        """The epipolar check's decisions of frame ``f`` against ground-truth instances (a
        late result's detections belong to an older frame)."""
        mode = self.rules.mode
        epi_mode = mode if mode in EPIPOLAR_MODES else Mode.SEMANTIC_EPIPOLAR
        if self.gt_instances is None or f.index == 0 or epi_mode not in results:
            return
        seen = self.stamps[f.index - f.lag] if f.model_ran else f.stamp
        _count_epipolar(self.report, self.gt_instances, seen, results[epi_mode], f.objects)


def _packed(f: MaskedFrame) -> tuple[MaskedFrame, list[Patch] | None]:
    """``f`` as a long trace keeps it: its objects' masks as crops, no depth images."""
    inputs = f.inputs
    previous = inputs.previous
    if previous is not None:
        previous = replace(previous, depth_m=None)
    objects = replace(inputs.objects, masks=None)
    inputs = replace(inputs, objects=objects, depth_m=None, previous=previous)
    return replace(f, inputs=inputs), pack_masks(f.objects.masks)


def _unpacked(
    f: MaskedFrame,
    crops: list[Patch] | None,
    depth_m: np.ndarray | None,
    depth_before: np.ndarray | None,
) -> MaskedFrame:
    """:func:`_packed`'s inverse, with the frame's depth and the previous frame's read again."""
    inputs = f.inputs
    previous = inputs.previous
    if previous is not None and previous.camera is not None:
        previous = replace(previous, depth_m=depth_before)
    objects: Objects = inputs.objects
    if crops is not None:
        objects = replace(objects, masks=unpack_masks(crops, objects.hw))
    inputs = replace(inputs, objects=objects, depth_m=depth_m, previous=previous)
    return replace(f, inputs=inputs)


def _instances(gt: AnnotationInstances | None, root: Path) -> AnnotationInstances:
    """The sequence's complete ground-truth instances (never a dropout-injected copy)."""
    if gt is not None and gt.dropout is None:
        return gt
    return AnnotationInstances(root)


def _count_epipolar(
    report: SequenceReport,
    instances: AnnotationInstances,
    stamp: float,
    result: FrameResult,
    objects: Objects,
) -> None:
    """Tally an epipolar mode's decisions on this frame's instances against their ``moving``
    flag (``result``: that mode's outcome, with the check it ran; the ``objects`` it judged:
    the track stage's predicted masks are not instances and are left out)."""
    epi = result.epipolar
    if epi is None:
        return
    checked = objects.det_index[np.asarray(result.checked, int)]
    keep = checked >= 0
    truth = instances.moving(stamp)[checked[keep]]
    for t, dec, mov in zip(truth, epi.decided[keep], epi.moving[keep], strict=True):
        decision = "moving" if mov else ("static" if dec else "undecided")
        key = f"{'moving' if t else 'static'} as {decision}"
        report.epipolar[key] = report.epipolar.get(key, 0) + 1
