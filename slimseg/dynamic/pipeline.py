"""The masking rules of one frame: objects + their decided mobility + keypoints (+ depth) →
dynamic points and the mask.

Modes (YOLO-SLAM's and the substation paper's ablations):
- ``box``: every keypoint inside a box of a dynamic class is dynamic;
- ``seg``: instance masks with the Eq. 1 adaptive mobility threshold;
- ``fusion``: Eq. 4 (a seg mask covering ≤ t_o of its box is replaced by the box) on dynamic
  keyframes (Eq. 3), plain seg masks otherwise; then Eq. 1;
- ``box+depth-ransac``: inside boxes of dynamic classes, YOLO-SLAM's depth-RANSAC keeps the
  largest depth-consistent set as dynamic; the rest of each box stays static;
- ``semantic+epipolar`` / ``fusion+epipolar`` (VTD-SLAM's multi-view check): ``seg`` /
  ``fusion`` with the epipolar check's verdict in the mobilities.

Each object's mobility comes decided (:func:`slimseg.dynamic.mobility.decide_mobility`:
prior or track, stillness, the check's evidence); :func:`apply_rules` only applies it: the
regions, the depth cut with its motion layers, the dilation, Eq. 3, Eq. 4 and the shortfall
rule. With the track stage ``misses`` > 0 marks the coasted masks (Eq. 4 leaves them as they
are: a prediction turned into its box would only grow the error).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from slimseg.dynamic.degrade import degrade
from slimseg.dynamic.depth_cut import behind_pixels, cut_behind, reference_depths
from slimseg.dynamic.epipolar import EpipolarResult
from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.masking_settings import PAPERS, MaskingSettings
from slimseg.dynamic.mobility import Decision, MotionBelief, decide_mobility
from slimseg.dynamic.modes import BOX_MODES, EPIPOLAR_MODES, KEYPOINTS, Mode, mode_of
from slimseg.dynamic.occupancy import MotionLayers
from slimseg.dynamic.seg_box import (
    T_O,
    box_keypoint_mobility,
    box_masks,
    dilate,
    dilate_masks,
    fuse_seg_box,
)
from slimseg.dynamic.threshold import adaptive_threshold, is_dynamic_frame, keypoint_mobility


@dataclass(frozen=True)
class FrameResult:
    """``dynamic [N]`` per keypoint, ``mask uint8 [H, W]`` (255 = dynamic region), ``m_th`` used
    (None: gave up), Eq. 3 flag, Eq. 4 decisions per detection, and counts."""

    dynamic: np.ndarray
    mask: np.ndarray
    m_th: float | None
    dynamic_frame: bool
    used_seg: list[bool] = field(default_factory=list)
    epipolar: EpipolarResult | None = None
    """epipolar modes: the check's outcome for the detections listed in ``checked``"""
    checked: list[int] = field(default_factory=list)
    seconds: float = 0.0
    """time the mode's rules took (the harness adds its own decision's)"""
    dropped: list[int] = field(default_factory=list)
    """objects above Eq. 1's starting threshold left out of the mask (``eq1``: those under
    the threshold it settled on, all of them when it gave up; ``degrade``: those it gave up)"""
    support: int | None = None
    """``degrade``: support points left outside the mask (None: Eq. 1, which counts
    keypoints)"""

    @property
    def counts(self) -> dict[str, int]:
        n = len(self.dynamic)
        d = int(self.dynamic.sum())
        return {"keypoints": n, "dynamic": d, "static": n - d}


def orb_keypoints(rgb: np.ndarray, count: int = KEYPOINTS) -> np.ndarray:
    """ORB keypoints of an RGB frame as ``float32 [N, 2]`` (x, y) px (OpenCV, ``count`` max)."""
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    kps = cv2.ORB_create(nfeatures=count).detect(gray, None)
    return np.array([k.pt for k in kps], np.float32).reshape(-1, 2)


@dataclass(frozen=True)
class FrameRules:
    """How to classify: ``class_mobility [K]`` priors per class, the ``mode`` and the
    ``masking`` settings (Eq. 1's ``min_static`` / ``m_th_start`` / ``m_th_step``, the
    dilation, Eq. 3's ``frame_ratio``, Eq. 4's ``t_o``, the shortfall ``rule`` and its
    ``keep_score``, the depth cut, ``motion_odds``; their ``conf`` acts on the detector, not
    here; default: the ``papers`` preset, the equations as printed)."""

    class_mobility: np.ndarray
    mode: Mode = Mode.FUSION
    masking: MaskingSettings = PAPERS

    @property
    def mover_prior(self) -> float:
        """The mobility above which an object counts as dynamic (depth-RANSAC's boxes, the
        epipolar modes' candidates): Eq. 1's starting threshold."""
        return self.masking.m_th_start

    def decide(self, inputs: FrameInputs, mode: Mode | None = None,
               belief: MotionBelief | None = None) -> Decision:  # fmt: skip
        """:func:`~slimseg.dynamic.mobility.decide_mobility` under these rules (``mode``:
        another than the rules' own)."""
        base = inputs.objects.priors(self.class_mobility)
        return decide_mobility(inputs, mode or self.mode, base, mover_prior=self.mover_prior,
                               motion_odds=self.masking.motion_odds, belief=belief)  # fmt: skip


def process_frame(
    *, inputs: FrameInputs, settings: FrameRules, rng: np.random.Generator | None = None
) -> FrameResult:
    """One frame judged alone in ``settings.mode``: the mobility decided
    (:meth:`FrameRules.decide`), then the rules applied; ``rng`` drives depth-RANSAC's
    sampling."""
    decision = settings.decide(inputs)
    moved = MotionLayers.of(inputs, settings.masking)
    return apply_rules(inputs, decision, settings, rng=rng, moved=moved)


def apply_rules(
    inputs: FrameInputs,
    decision: Decision,
    settings: FrameRules,
    *,
    mode: Mode | None = None,
    rng: np.random.Generator | None = None,
    moved: MotionLayers | None = None,
) -> FrameResult:
    """The rules of ``mode`` (default ``settings.mode``) on ``inputs`` with the objects'
    decided mobility; ``moved``: the frame's motion layers (None: none). Timed."""
    mode = mode_of(mode or settings.mode)
    t0 = time.perf_counter()
    if mode not in BOX_MODES and inputs.objects.masks is None:
        raise ValueError(f"mode {mode!r} needs instance masks (a segmentation model)")
    res = _one_mode(inputs, settings, EPIPOLAR_MODES.get(mode, mode), decision.mobility, rng,
                    moved)  # fmt: skip
    epi, checked = decision.verdict if mode in EPIPOLAR_MODES else (None, [])
    return replace(res, epipolar=epi, checked=checked, seconds=time.perf_counter() - t0)


def _one_mode(
    inputs: FrameInputs,
    settings: FrameRules,
    mode: str,
    mob: np.ndarray,
    rng: np.random.Generator | None,
    moved: MotionLayers | None = None,
) -> FrameResult:
    keypoints, hw, objects = inputs.keypoints, inputs.hw, inputs.objects
    boxes, masks, s = objects.boxes, objects.masks, settings.masking
    used_seg: list[bool] = []
    if mode == Mode.BOX_DEPTH_RANSAC:
        from slimseg.dynamic.depth_ransac import screen_box_keypoints

        if inputs.depth_m is None:
            raise ValueError("mode 'box+depth-ransac' needs a depth image")
        movers = boxes[mob > settings.mover_prior]
        dynamic = screen_box_keypoints(keypoints, inputs.depth_m, movers, rng=rng)
        region = box_masks(movers, hw).any(0) if len(movers) else np.zeros(hw, bool)
        flag = bool(dynamic.mean() > 0) if len(dynamic) else False
        return FrameResult(dynamic, _mask(region, s.dilation_px), None, flag)
    regions = box_masks(boxes, hw) if mode == Mode.BOX else np.asarray(masks, bool)
    depth = inputs.depth_m if s.cut_behind_m > 0 and mode != Mode.BOX else None
    reference = layers = None
    if depth is not None:  # masks that stay on their object (seg masks, before dilation)
        reference = reference_depths(regions, boxes, depth)
        if moved is not None:  # what moved in behind the near layer stays
            behind = behind_pixels(boxes, depth, reference, s.cut_behind_m)
            layers = moved.layers(behind, boxes, reference, s.cut_behind_m)
        regions = cut_behind(regions.copy(), boxes, depth, reference, s.cut_behind_m, layers)
    # points near a mask edge belong to the object (ORB patches)
    regions = dilate_masks(regions, s.dilation_px)
    point_mob = keypoint_mobility(keypoints, regions, mob)
    # Eq. 3 counts points inside the detection boxes: a frame whose masks came out too thin is
    # exactly the one that needs the box fallback of Eq. 4
    box_mob = box_keypoint_mobility(keypoints, boxes, hw, mob)
    dynamic_frame = is_dynamic_frame(box_mob, s.frame_ratio)
    if mode == Mode.FUSION and dynamic_frame and len(boxes):
        fused, used = fuse_seg_box(regions, boxes, eq4_thresholds(settings, reference, len(boxes)))
        keep = objects.misses > 0  # Eq. 4 acts on detection masks only
        if keep.any():
            fused[keep] = regions[keep]
            used = used | keep
        if depth is not None and not used.all():  # the boxes put in place of thin masks
            box = ~used
            lay = None if layers is None else layers[box]
            fused[box] = cut_behind(fused[box], boxes[box], depth, reference[box],
                                    s.cut_behind_m, lay)  # fmt: skip
        regions, used_seg = fused, used.tolist()
        point_mob = keypoint_mobility(keypoints, regions, mob)
    if s.rule == "degrade":
        out = degrade(
            regions=regions, mobility=mob, scores=objects.scores, keypoints=keypoints,
            support=keypoints if inputs.support is None else inputs.support,
            min_static=s.min_static, m_th_start=s.m_th_start,
            keep_score=s.keep_score,
        )  # fmt: skip
        region = regions[out.masked].any(0) if out.masked.any() else np.zeros(hw, bool)
        m_th = round(s.m_th_start, 4)
        return FrameResult(out.dynamic, _mask(region, 0), m_th, dynamic_frame, used_seg,
                           dropped=out.dropped, support=out.support)  # fmt: skip
    result = adaptive_threshold(point_mob, s.min_static, s.m_th_start, s.m_th_step)
    if result.m_th is None:
        region, kept = np.zeros(hw, bool), np.zeros(len(mob), bool)
    else:
        kept = mob > result.m_th
        region = regions[kept].any(0) if len(regions) else np.zeros(hw, bool)
    candidates = mob > s.m_th_start + 1e-9  # those above Eq. 1's first threshold
    dropped = np.flatnonzero(candidates & ~kept).tolist()
    return FrameResult(result.dynamic, _mask(region, 0), result.m_th, dynamic_frame, used_seg,
                       dropped=dropped)  # fmt: skip


def eq4_thresholds(settings: FrameRules, reference: np.ndarray | None, n: int) -> np.ndarray:
    """Eq. 4's ``t_o`` per object ``[n]``: the setting's; but where the depth cut is asked for
    and cannot act on an object (no depth image: an RGB-only stream; or no valid depth under
    its mask, ``reference`` NaN), at most the papers' :data:`~slimseg.dynamic.seg_box.T_O`: a
    box nothing trims is the room behind the object, so only a seg mask too thin to trust is
    replaced by it."""
    s = settings.masking
    t_o = np.full(n, s.t_o)
    if s.cut_behind_m > 0:
        uncut = np.ones(n, bool) if reference is None else ~np.isfinite(reference)
        t_o[uncut] = min(s.t_o, T_O)
    return t_o


def _mask(region: np.ndarray, dilation_px: int) -> np.ndarray:
    return dilate(region.astype(np.uint8), dilation_px) * 255
