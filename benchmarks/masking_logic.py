"""Per-frame cost of the SLAM-side masking logic without the network (640×480, 1000 points).

    python benchmarks/masking_logic.py

Five detections (two persons, a dog, a chair, a tv) with instance masks, 1000 keypoints, a
depth image with people at 2 m before a wall at 4 m; median of 50 calls per mode, then
``fusion`` under each masking preset (the ``slimseg`` preset's degrading rule with its static
support, the FAST corners of ORB-SLAM3's pyramid, counted in), then the ``slimseg`` preset
with a previous frame and the frames 10 and 20 back (their depth and ORB features: the motion
layers' camera pose and moved-in pixels, the stillness test's two poses and depth comparisons)
against the same without the motion layers (``motion_layer_px`` 0), without the stillness test
(``still_frames`` 0) and without both, plus ORB detection of 1000 features on a textured frame
for scale. One run, one process.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import replace

import cv2
import numpy as np

from slimseg.dynamic.degrade import support_points
from slimseg.dynamic.epipolar import PreviousFrame, orb_features
from slimseg.dynamic.frame_inputs import FrameInputs
from slimseg.dynamic.masking_settings import DEFAULT, PRESETS
from slimseg.dynamic.pipeline import (
    MODES,
    FrameRules,
    orb_keypoints,
    process_frame,
)
from slimseg.dynamic.stillness import find_still
from slimseg.objects import Objects

H, W = 480, 640


def scene(rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    boxes = np.array(
        [
            [50, 80, 170, 460],
            [400, 100, 500, 470],
            [220, 300, 380, 460],
            [520, 250, 630, 420],
            [250, 40, 390, 150],
        ],
        np.float32,
    )
    classes = np.array([0, 0, 1, 2, 3])
    masks = np.zeros((5, H, W), bool)
    for k, (x1, y1, x2, y2) in enumerate(boxes.astype(int)):
        masks[k, y1:y2, x1 + (x2 - x1) // 5 : x2 - (x2 - x1) // 5] = True
    depth = np.full((H, W), 4.0, np.float32)
    depth[masks[:3].any(0)] = 2.0
    keypoints = rng.uniform([0, 0], [W, H], (1000, 2)).astype(np.float32)
    return keypoints, boxes, classes, masks, depth


def main() -> None:
    rng = np.random.default_rng(0)
    kps, boxes, classes, masks, depth = scene(rng)
    mobility = np.array([1.0, 0.75, 0.25, 0.0], np.float32)
    ones = np.ones(len(boxes), np.float32)
    print(f"masking logic per frame, {W}x{H}, {len(kps)} keypoints, {len(boxes)} detections")
    base = None
    for mode in MODES:
        times = []
        for _ in range(50):
            t = time.perf_counter()
            process_frame(
                inputs=FrameInputs(
                    kps, Objects(boxes, ones, classes, masks, (H, W)), depth_m=depth
                ),
                settings=FrameRules(mobility, mode),
                rng=np.random.default_rng(1),
            )
            times.append(time.perf_counter() - t)
        ms = 1000 * statistics.median(times)
        base = base or ms
        print(f"  {mode:18s} {ms:7.2f} ms  ({ms / base:.2f} of seg)")
    frame = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    # a textured frame with a rendered frame's corner count (pure noise has 80k: a worst case)
    textured = cv2.GaussianBlur(frame, (0, 0), 1.5)
    print(f"fusion per masking preset (the degrading rule's support corners included: "
          f"{len(support_points(textured))} on a blurred-noise frame):")  # fmt: skip
    scores = np.array([0.9, 0.8, 0.3, 0.2, 0.15], np.float32)
    ref = None
    for name, preset in PRESETS.items():
        rules = FrameRules(mobility, "fusion", preset)
        times = []
        for _ in range(30):
            t = time.perf_counter()
            corners = support_points(textured) if preset.rule == "degrade" else None
            objects = Objects(boxes, scores, classes, masks, (H, W))
            inputs = FrameInputs(kps, objects, depth_m=depth, support=corners)
            process_frame(inputs=inputs, settings=rules)
            times.append(time.perf_counter() - t)
        ms = 1000 * statistics.median(times)
        ref = ref or ms
        print(f"  {name:18s} {ms:7.2f} ms  ({ms / ref:.2f} of papers): {preset.describe()}")
    motion_layers(textured, masks, boxes, classes, scores, depth, mobility)
    times = []
    for _ in range(20):
        t = time.perf_counter()
        orb_keypoints(frame, 1000)
        times.append(time.perf_counter() - t)
    print(f"  ORB detection (1000 features, for scale): {1000 * statistics.median(times):.2f} ms")


def motion_layers(
    textured: np.ndarray,
    masks: np.ndarray,
    boxes: np.ndarray,
    classes: np.ndarray,
    scores: np.ndarray,
    depth: np.ndarray,
    mobility: np.ndarray,
) -> None:
    """The slimseg preset given the previous frame (people 8 px to the left in its depth) and
    the frames 10 and 20 back (80 and 160 px), with and without the motion layers and the
    stillness test, calls alternating."""
    feats = orb_features(textured, 1000, corners=True)
    camera = (525.0, 525.0, 319.5, 239.5)
    previous, ten, twenty = (PreviousFrame(feats, np.roll(depth, -px, axis=1), camera)
                             for px in (8, 80, 160))  # fmt: skip
    objects = Objects(boxes, scores, classes, masks, (H, W))
    inputs = FrameInputs(
        feats.keypoints, objects, depth_m=depth, descriptors=feats.descriptors,
        previous=previous, support=feats.corners,
    )  # fmt: skip
    off = "both off"
    arms = {
        "both on (slimseg)": DEFAULT,
        "motion layers off": DEFAULT.with_values(motion_layer_px=0),
        "stillness off": DEFAULT.with_values(still_frames=0),
        off: DEFAULT.with_values(motion_layer_px=0, still_frames=0),
    }
    times: dict[str, list[float]] = {k: [] for k in arms}
    for _ in range(30):
        for name, settings in arms.items():
            t = time.perf_counter()
            frame = inputs
            if settings.still_frames:  # what the chain does with the frames 10 and 20 back
                prior = objects.priors(mobility)
                frame = replace(inputs, still=find_still(inputs, (ten, twenty), prior))
            process_frame(inputs=frame, settings=FrameRules(mobility, "fusion", settings))
            times[name].append(time.perf_counter() - t)
    med = {k: 1000 * statistics.median(v) for k, v in times.items()}
    print("slimseg preset with the previous frame and the frames 10 and 20 back:")
    for name, ms in med.items():
        print(f"  {name:24s} {ms:7.2f} ms  ({ms / med[off]:.2f} of both off)")


if __name__ == "__main__":
    main()
