"""One frame of the SLAM-facing reference: detections + keypoints (+ depth) → dynamic points.

Modes (YOLO-SLAM's and the substation paper's ablations):
- ``box``: every keypoint inside a box of a dynamic class is dynamic;
- ``seg``: instance masks with the Eq. 1 adaptive mobility threshold;
- ``fusion``: Eq. 4 (a seg mask covering ≤ t_o of its box is replaced by the box) on dynamic
  keyframes (Eq. 3), plain seg masks otherwise; then Eq. 1;
- ``box+depth-ransac``: inside boxes of dynamic classes, YOLO-SLAM's depth-RANSAC keeps the
  largest depth-consistent set as dynamic; the rest of each box stays static;
- ``semantic+epipolar`` / ``fusion+epipolar`` (VTD-SLAM's multi-view check): like ``seg`` /
  ``fusion``, but every detection of a dynamic class (prior > ``dynamic_mobility``) is first
  checked against the previous frame (``epipolar.check_motion`` on its instance mask); one the
  check finds *static* gets mobility 0, so its points stay static (a standing person). Objects
  with too few matched points, and every object of the first frame (no ``previous``), keep
  their prior: undecided means dynamic. Eq. 3 then counts with the corrected priors.

Objects the stillness test found still (``FrameInputs.still``; the chain runs
:mod:`slimseg.dynamic.stillness` with ``still_frames`` on) get mobility 0 before any mode
runs: a person standing still is static structure.

With the track stage (:mod:`slimseg.dynamic.track`), the objects' ``mobility`` column carries
each one's mobility (its track's moving probability, decayed per missed frame) instead of the
class prior, ``misses`` > 0 marks the coasted masks (Eq. 4 leaves them as they are: a
prediction turned into its box would only grow the error), and the epipolar check has
already run (``FrameInputs.evidence``): its outcome is in the mobilities, not applied again.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from slimseg.dynamic.degrade import degrade
from slimseg.dynamic.depth_cut import behind_pixels, cut_behind, reference_depths
from slimseg.dynamic.epipolar import EpipolarResult, OrbFeatures, check_motion
from slimseg.dynamic.frame_inputs import FrameInputs, MotionEvidence
from slimseg.dynamic.masking_settings import PAPERS, MaskingSettings
from slimseg.dynamic.modes import BOX_MODES, EPIPOLAR_MODES, KEYPOINTS, MODES, WEIGHED_MODES, Mode
from slimseg.dynamic.motion_evidence import uncertain, weigh_motion
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


@dataclass
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
    """time this mode took (the shared epipolar check counts for the first mode needing it)"""
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
    """How to classify: ``class_mobility [K]`` priors per class, the ``mode``, the ``masking``
    settings (Eq. 1's ``min_static`` / ``m_th_start`` / ``m_th_step``, the dilation, Eq. 3's
    ``frame_ratio``, Eq. 4's ``t_o``, the shortfall ``rule`` and its ``keep_score``, the depth
    cut, ``motion_odds``; their ``conf`` acts on the detector, not here; default: the
    ``papers`` preset, the equations as printed), and ``dynamic_mobility``: the prior above
    which a class counts as dynamic (boxes of depth-RANSAC, epipolar candidates),
    ``masking.m_th_start`` if None."""

    class_mobility: np.ndarray
    mode: Mode = Mode.FUSION
    masking: MaskingSettings = PAPERS
    dynamic_mobility: float | None = None

    @property
    def mover_prior(self) -> float:
        """The prior above which a class counts as dynamic (``dynamic_mobility``)."""
        if self.dynamic_mobility is None:
            return self.masking.m_th_start
        return self.dynamic_mobility


def process_frame(
    *, inputs: FrameInputs, settings: FrameRules, rng: np.random.Generator | None = None
) -> FrameResult:
    """Classify the keypoints of one frame with ``settings.mode``; ``rng`` drives
    depth-RANSAC's sampling. Epipolar modes: see the module docstring."""
    return process_modes(inputs=inputs, settings=settings, modes=(settings.mode,), rng=rng)[
        settings.mode
    ]


def process_modes(
    *,
    inputs: FrameInputs,
    settings: FrameRules,
    modes: Sequence[str],
    rng: np.random.Generator | None = None,
) -> dict[str, FrameResult]:
    """:func:`process_frame` for several ``modes`` of the same frame (``settings.mode`` is
    ignored), in the given order; the epipolar check runs once and serves both epipolar
    modes (its time counts for the first of them). Returns ``{mode: FrameResult}``."""
    bad = [m for m in modes if m not in MODES]
    if bad:
        raise ValueError(f"unknown mode {bad[0]!r}; valid: {list(MODES)}")
    mob = inputs.objects.priors(settings.class_mobility)
    if inputs.still is not None and inputs.still.any():  # standing still: static structure
        mob = np.where(inputs.still, np.float32(0.0), mob).astype(mob.dtype)
    check = weighed = None
    moved = MotionLayers.of(inputs, settings.masking)
    if inputs.evidence is not None and not inputs.evidence.weighed:
        check = mob, inputs.evidence.result, inputs.evidence.checked
    out = {}
    for mode in modes:
        t0 = time.perf_counter()
        if mode not in BOX_MODES and inputs.objects.masks is None:
            raise ValueError(f"mode {mode!r} needs instance masks (a segmentation model)")
        if mode in EPIPOLAR_MODES:
            if check is None:
                check = epipolar_priors(inputs, mob, settings.mover_prior)
            priors, epi, checked = check
            res = _one_mode(inputs, settings, EPIPOLAR_MODES[mode], priors, rng, moved)
            res.epipolar, res.checked = epi, list(checked)
        elif mode in WEIGHED_MODES and settings.masking.motion_odds > 1 and inputs.evidence is None:
            if weighed is None:
                weighed = weighed_mobility(inputs, mob, settings.masking.motion_odds)
            res = _one_mode(inputs, settings, mode, weighed, rng, moved)
        else:
            res = _one_mode(inputs, settings, mode, mob, rng, moved)
        res.seconds = time.perf_counter() - t0
        out[mode] = res
    return out


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


def weighed_mobility(inputs: FrameInputs, mob: np.ndarray, odds: float) -> np.ndarray:
    """``mob [M]`` with the epipolar check's decisions on the objects whose mobility is
    uncertain (0 < p < 1) weighed in at ``odds`` (:mod:`slimseg.dynamic.motion_evidence`);
    unchanged without a previous frame or such an object."""
    if inputs.previous is None or inputs.objects.masks is None or not uncertain(mob).any():
        return mob
    ev = epipolar_evidence(inputs, np.where(uncertain(mob), mob, 0.0), 0.0)
    if ev.result is None:
        return mob
    return weigh_motion(mob, ev.checked, ev.result.decided, ev.result.moving, odds)


def epipolar_priors(
    inputs: FrameInputs, mob: np.ndarray, dynamic_mobility: float
) -> tuple[np.ndarray, EpipolarResult | None, list[int]]:
    """Mobility priors with the detections the epipolar check finds static set to 0."""
    ev = epipolar_evidence(inputs, mob, dynamic_mobility)
    if ev.result is None:
        return mob, None, []
    mob = mob.copy()
    checked = np.asarray(ev.checked, int)
    mob[checked[ev.result.decided & ~ev.result.moving]] = 0.0
    return mob, ev.result, ev.checked


def epipolar_evidence(
    inputs: FrameInputs, mob: np.ndarray, dynamic_mobility: float, pairs: np.ndarray | None = None
) -> MotionEvidence:
    """Run the epipolar check on the objects whose mobility ``mob [M]`` exceeds
    ``dynamic_mobility`` (``pairs``: the frames' ORB matches, when already computed)."""
    keypoints, descriptors, previous, masks = (
        inputs.keypoints,
        inputs.descriptors,
        inputs.previous,
        inputs.objects.masks,
    )
    candidates = np.flatnonzero(mob > dynamic_mobility)
    if previous is None or len(candidates) == 0:
        return MotionEvidence(None, [])
    if descriptors is None:
        raise ValueError(
            "epipolar modes need the ORB descriptors of the keypoints: pass descriptors= "
            "(epipolar.orb_features gives keypoints and descriptors together)"
        )
    current = OrbFeatures(np.asarray(keypoints, np.float32).reshape(-1, 2), descriptors)
    result = check_motion(
        previous.features,
        current,
        np.asarray(masks, bool)[candidates],
        depth_m=previous.depth_m if previous.depth_residual else None,
        camera=previous.camera,
        pairs=pairs,
    )
    return MotionEvidence(result, candidates.tolist())


def _mask(region: np.ndarray, dilation_px: int) -> np.ndarray:
    return dilate(region.astype(np.uint8), dilation_px) * 255
