"""How a masked frame reaches a feature-based SLAM engine that has no mask input (ORB-SLAM3).

The dynamic region is removed from what the engine sees: its colour is filled by OpenCV's
Telea inpainting (a flat fill would create corners at the mask edge, exactly where features
must not appear) and its depth is zeroed (ORB-SLAM3's RGB-D tracking ignores keypoints
without depth). ``slimseg slam-eval`` feeds ORB-SLAM3 this way, and so does the runtime loop
of docs/runtime_api.md.
"""

from __future__ import annotations

import cv2
import numpy as np

INPAINT_RADIUS_PX = 3


def remove_dynamic(
    rgb: np.ndarray, depth: np.ndarray | None, mask: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None]:
    """``(rgb uint8 [H, W, 3], depth [H, W] or None)`` with the region ``mask [H, W]``
    (nonzero = dynamic) inpainted and its depth set to 0; the inputs are left as they are
    (a frame without dynamic pixels comes back unchanged, not copied)."""
    region = np.asarray(mask) > 0
    if region.shape != rgb.shape[:2]:
        raise ValueError(
            f"mask {list(region.shape)} does not match the frame {list(rgb.shape[:2])}"
        )
    if not region.any():
        return rgb, depth
    out = cv2.inpaint(rgb, region.astype(np.uint8) * 255, INPAINT_RADIUS_PX, cv2.INPAINT_TELEA)
    if depth is not None:
        depth = np.where(region, np.zeros((), depth.dtype), depth)
    return out, depth
