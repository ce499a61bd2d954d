"""An experiment, not a lever: give back the mask pixels whose depth did not change.

Reads a ``slimseg dynamic`` output's masks for a TUM-layout sequence with depth and
intrinsics, and writes new masks: every mask pixel (on the stillness test's grid) whose depth,
moved into each of the ``--gaps`` earlier frames by the PnP camera pose, agrees within the
stillness test's tolerance with what that frame saw there is given back; what is left is
opened (5 px) and dilated again by ``--dilation`` inside the old mask. Prints ORB-keypoint
precision and recall before and after against ``dynamic/``. Track the result with
``slimseg slam-eval --masks OUT``. docs/calibrate.md (round 4) reports what it did on six
held-out sequences with four models: the standing person came back, the sitting ones went too.

    python tools/per_pixel_stillness.py SEQ runs/dyn runs/dyn_pixels --gaps 10,20
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from slimseg.data.images import decode_file
from slimseg.data.tum import TumSequence, mask_name
from slimseg.dynamic.epipolar import OrbFeatures, PreviousFrame, orb_features
from slimseg.dynamic.modes import KEYPOINTS
from slimseg.dynamic.occupancy import STRIDE, TAU_M, camera_pose, warp_grid
from slimseg.dynamic.stillness import depth_span
from slimseg.utils.atomic import write_png


def unchanged(
    depth_m: np.ndarray,
    mask: np.ndarray,
    current: OrbFeatures,
    earlier: list[PreviousFrame],
    camera: tuple[float, float, float, float],
) -> np.ndarray | None:
    """``bool [H, W]``: the pixels of ``mask bool [H, W]`` whose depth agrees (within TAU_M of
    the span seen around where they land) with every one of the ``earlier`` frames; None
    when a frame has no pose to ``current``."""
    grid = None
    for frame in earlier:
        pose = camera_pose(frame, current)
        if pose is None or frame.depth_m is None:
            return None
        ys, xs, u, v, z = warp_grid(depth_m, camera, pose, mask)
        lo, hi = depth_span(frame.depth_m)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(lo[v, u]) & (z >= lo[v, u] - TAU_M) & (z <= hi[v, u] + TAU_M)
        here = np.zeros(mask[::STRIDE, ::STRIDE].shape, bool)
        here[ys[ok], xs[ok]] = True
        grid = here if grid is None else grid & here
    full = np.repeat(np.repeat(grid, STRIDE, 0), STRIDE, 1)
    return full[: mask.shape[0], : mask.shape[1]]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("sequence", type=Path, help="TUM-layout folder with depth and dynamic/")
    p.add_argument("masks", type=Path, help="slimseg dynamic --out folder (or its masks/)")
    p.add_argument("out", type=Path, help="new folder for the masks (must not exist)")
    p.add_argument("--gaps", default="10,20", help="earlier frames compared, comma list")
    p.add_argument("--dilation", type=int, default=5, help="px of dilation after the opening")
    args = p.parse_args(argv)
    if args.out.exists():
        print(f"error: {args.out} exists; give a new folder", file=sys.stderr)
        return 2
    seq = TumSequence(args.sequence)
    src = args.masks / "masks" if (args.masks / "masks").is_dir() else args.masks
    gaps = [int(g) for g in args.gaps.split(",")]
    camera = seq.camera.pinhole
    (args.out / "masks").mkdir(parents=True)
    history: list[PreviousFrame] = []
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * args.dilation + 1,) * 2)
    counts = np.zeros((2, 3), np.int64)  # before / after: TP, FP, FN
    for i in range(len(seq)):
        rgb, depth, stamp = seq.load(i)
        depth_m = np.asarray(depth, np.float32)
        feats = orb_features(rgb, KEYPOINTS)
        old = decode_file(src / mask_name(stamp), cv2.IMREAD_GRAYSCALE)
        if old is None:
            print(f"error: no mask {src / mask_name(stamp)}", file=sys.stderr)
            return 2
        old = old > 0
        new = old
        if all(i >= g for g in gaps):
            still = unchanged(depth_m, old, feats, [history[i - g] for g in gaps], camera)
            if still is not None:
                keep = cv2.morphologyEx((old & ~still).astype(np.uint8), cv2.MORPH_OPEN,
                                        np.ones((5, 5), np.uint8))  # fmt: skip
                new = (cv2.dilate(keep, disk) > 0) & old
        write_png(args.out / "masks" / mask_name(stamp), new.astype(np.uint8) * 255)
        history.append(PreviousFrame(feats, depth_m, camera))
        truth = decode_file(seq.root / "dynamic" / mask_name(stamp), cv2.IMREAD_GRAYSCALE)
        if truth is not None:
            kp = np.round(feats.keypoints).astype(int)
            gt = truth[kp[:, 1], kp[:, 0]] > 0
            for row, m in enumerate((old, new)):
                flag = m[kp[:, 1], kp[:, 0]]
                counts[row] += ((gt & flag).sum(), (~gt & flag).sum(), (gt & ~flag).sum())
    for name, (tp, fp, fn) in zip(("before", "after"), counts, strict=True):
        print(f"{name}: keypoint precision {tp / max(tp + fp, 1):.1%}, recall "
              f"{tp / max(tp + fn, 1):.1%}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
