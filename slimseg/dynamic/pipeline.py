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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from slimseg.dynamic.epipolar import EpipolarResult, OrbFeatures, PreviousFrame, check_motion
from slimseg.dynamic.fusion import box_masks, dilate, fuse_seg_box
from slimseg.dynamic.threshold import adaptive_threshold, is_dynamic_frame, keypoint_mobility

MODES = ("seg", "box", "fusion", "box+depth-ransac", "semantic+epipolar", "fusion+epipolar")
EPIPOLAR_MODES = {"semantic+epipolar": "seg", "fusion+epipolar": "fusion"}


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

    @property
    def counts(self) -> dict[str, int]:
        n = len(self.dynamic)
        d = int(self.dynamic.sum())
        return {"keypoints": n, "dynamic": d, "static": n - d}


def orb_keypoints(rgb: np.ndarray, count: int = 1000) -> np.ndarray:
    """ORB keypoints of an RGB frame as ``float32 [N, 2]`` (x, y) px (OpenCV, ``count`` max)."""
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    kps = cv2.ORB_create(nfeatures=count).detect(gray, None)
    return np.array([k.pt for k in kps], np.float32).reshape(-1, 2)


def process_frame(
    keypoints: np.ndarray,
    boxes: np.ndarray,
    classes: np.ndarray,
    masks: np.ndarray | None,
    class_mobility: np.ndarray,
    hw: tuple[int, int],
    mode: str = "fusion",
    depth_m: np.ndarray | None = None,
    min_static: int = 100,
    dilation_px: int = 0,
    dynamic_mobility: float = 0.25,
    rng: np.random.Generator | None = None,
    descriptors: np.ndarray | None = None,
    previous: PreviousFrame | None = None,
) -> FrameResult:
    """Classify ``keypoints [N, 2]`` of one ``hw`` frame given detections in frame pixels:
    ``boxes [M, 4]`` xyxy, ``classes [M]``, ``masks bool [M, H, W]`` (None: detector only),
    ``class_mobility [K]`` priors; ``depth_m [H, W]`` metres for depth-RANSAC.

    Epipolar modes: ``descriptors uint8 [N, 32]`` are the ORB descriptors of ``keypoints`` (see
    ``epipolar.orb_features``) and ``previous`` the previous frame's features (None on the
    first frame: no check, the mode behaves like its base mode)."""
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; valid: {list(MODES)}")
    mob = np.asarray(class_mobility, np.float32)[np.asarray(classes, int)]
    boxes = np.asarray(boxes, np.float32).reshape(-1, 4)
    if mode in ("seg", "fusion", *EPIPOLAR_MODES) and masks is None:
        raise ValueError(f"mode {mode!r} needs instance masks (a segmentation model)")
    epi, checked = None, []
    if mode in EPIPOLAR_MODES:
        mob, epi, checked = _epipolar_priors(
            keypoints, descriptors, previous, masks, mob, dynamic_mobility
        )
        mode = EPIPOLAR_MODES[mode]
    used_seg: list[bool] = []
    if mode == "box+depth-ransac":
        from slimseg.dynamic.depth_ransac import screen_box_keypoints

        if depth_m is None:
            raise ValueError("mode 'box+depth-ransac' needs a depth image")
        movers = boxes[mob > dynamic_mobility]
        dynamic = screen_box_keypoints(keypoints, depth_m, movers, rng=rng)
        region = box_masks(movers, hw).any(0) if len(movers) else np.zeros(hw, bool)
        flag = bool(dynamic.mean() > 0) if len(dynamic) else False
        return FrameResult(dynamic, _mask(region, dilation_px), None, flag)
    regions = box_masks(boxes, hw) if mode == "box" else masks.astype(bool)
    if dilation_px > 0:  # points near a mask edge belong to the object (ORB patches straddle it)
        regions = np.stack([dilate(r, dilation_px) for r in regions]) if len(regions) else regions
    point_mob = keypoint_mobility(keypoints, regions, mob)
    # Eq. 3 counts points inside the detection boxes: a frame whose masks came out too thin is
    # exactly the one that needs the box fallback of Eq. 4
    dynamic_frame = is_dynamic_frame(keypoint_mobility(keypoints, box_masks(boxes, hw), mob))
    if mode == "fusion" and dynamic_frame and len(boxes):
        regions, used = fuse_seg_box(regions, boxes)
        used_seg = used.tolist()
        point_mob = keypoint_mobility(keypoints, regions, mob)
    result = adaptive_threshold(point_mob, min_static)
    if result.m_th is None:
        region = np.zeros(hw, bool)
    else:
        region = regions[mob > result.m_th].any(0) if len(regions) else np.zeros(hw, bool)
    return FrameResult(
        result.dynamic, _mask(region, 0), result.m_th, dynamic_frame, used_seg, epi, checked
    )


def _epipolar_priors(
    keypoints: np.ndarray,
    descriptors: np.ndarray | None,
    previous: PreviousFrame | None,
    masks: np.ndarray,
    mob: np.ndarray,
    dynamic_mobility: float,
) -> tuple[np.ndarray, EpipolarResult | None, list[int]]:
    """Mobility priors with the detections the epipolar check finds static set to 0."""
    candidates = np.flatnonzero(mob > dynamic_mobility)
    if previous is None or len(candidates) == 0:
        return mob, None, []
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
        depth_m=previous.depth_m,
        camera=previous.camera,
    )
    mob = mob.copy()
    mob[candidates[result.decided & ~result.moving]] = 0.0
    return mob, result, candidates.tolist()


def _mask(region: np.ndarray, dilation_px: int) -> np.ndarray:
    return dilate(region.astype(np.uint8), dilation_px) * 255
