"""Restore every frame of a TUM sequence and, with a true background, score the restoration.

Writes ``restored/rgb/<rgb timestamp>.png`` (8-bit colour) and ``restored/depth/<rgb
timestamp>.png`` (uint16, the sequence's depth scale, 5000 per metre on TUM) under ``out``;
both are written to a temporary file and moved into place (``os.replace``).

When the sequence has ``background/rgb`` (synthetic sequences), every frame with a removed
region is scored inside that region against the true static background, for our PatchMatch
restoration and for OpenCV's Telea inpainting (``cv2.inpaint``, radius 3) on the same region:
PSNR (dB, RGB), SSIM (mean of the 11 × 11 Gaussian SSIM map of the gray images over the
region), depth MAE (m, over pixels valid in both) and the number of ORB features (1000 per
frame, OpenCV defaults) that fall inside the region. The masked-out frame has 0 features there
by construction (SLAM drops them), so the count is also the gain.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from slimseg.data.frame_source import FrameSource
from slimseg.data.images import decode_file
from slimseg.data.sequence_source import opens_sequence
from slimseg.data.tum import depth_metres, mask_name
from slimseg.dynamic.modes import KEYPOINTS
from slimseg.dynamic.restore import (
    MAX_REFS,
    STRIDE,
    WINDOW,
    FrameData,
    removed_region,
    restore_frame,
    select_references,
)
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import write_png

MaskSource = Callable[[int, float], np.ndarray]


@dataclass
class MethodScore:
    """Sums over scored frames of one method (``orb`` counts features in the regions)."""

    psnr: list[float] = field(default_factory=list)
    ssim: list[float] = field(default_factory=list)
    depth_mae: list[float] = field(default_factory=list)
    orb: int = 0
    seconds: float = 0.0


@dataclass
class RestoreReport:
    frames: int = 0
    restored: int = 0  # frames with a non-empty removed region
    references: int = 0  # total references used
    coverage: list[float] = field(default_factory=list)
    scored: int = 0
    truth_orb: int = 0
    methods: dict[str, MethodScore] = field(default_factory=dict)


def psnr(a: np.ndarray, b: np.ndarray, region: np.ndarray) -> float:
    """PSNR (dB, peak 255) of ``uint8 [H, W, C]`` images over ``region bool [H, W]``."""
    d = a[region].astype(np.float64) - b[region].astype(np.float64)
    mse = float((d**2).mean()) if d.size else 0.0
    return float("inf") if mse == 0 else 10 * math.log10(255.0**2 / mse)


def ssim_in(a: np.ndarray, b: np.ndarray, region: np.ndarray) -> float:
    """Mean SSIM (Wang et al. 2004, Gaussian σ 1.5, 11 × 11) of the gray versions of two RGB
    ``uint8`` images over ``region``."""
    x = cv2.cvtColor(a, cv2.COLOR_RGB2GRAY).astype(np.float64)
    y = cv2.cvtColor(b, cv2.COLOR_RGB2GRAY).astype(np.float64)
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2

    def blur(z: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(z, (11, 11), 1.5)

    mx, my = blur(x), blur(y)
    vx, vy, cxy = blur(x * x) - mx**2, blur(y * y) - my**2, blur(x * y) - mx * my
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx**2 + my**2 + c1) * (vx + vy + c2))
    return float(s[region].mean())


def orb_in(rgb: np.ndarray, region: np.ndarray, count: int = KEYPOINTS) -> int:
    """ORB features of the whole frame whose keypoint falls inside ``region``."""
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    kps = cv2.ORB_create(nfeatures=count).detect(gray, None)
    h, w = region.shape
    return sum(region[min(int(k.pt[1]), h - 1), min(int(k.pt[0]), w - 1)] for k in kps)


@opens_sequence
def restore_sequence(
    sequence: Path | FrameSource,
    masks: MaskSource,
    out: Path,
    dilation_px: int = 2,
    window: int = WINDOW,
    stride: int = STRIDE,
    max_refs: int = MAX_REFS,
    keypoints: int = KEYPOINTS,
    progress: bool = True,
) -> RestoreReport:
    """Restore every associated frame of ``sequence``; ``masks(i, rgb_timestamp)`` gives frame
    ``i``'s dynamic mask (``[H, W]``, nonzero = removed); ``sequence``: the folder, or it
    opened (a bag too). See the module docstring."""
    seq = sequence  # a path was opened by @opens_sequence
    scale = seq.camera.depth_scale
    (out / "restored" / "rgb").mkdir(parents=True, exist_ok=True)
    (out / "restored" / "depth").mkdir(parents=True, exist_ok=True)
    bg_dir = seq.root / "background"
    report = RestoreReport()
    if (bg_dir / "rgb").is_dir():
        report.methods = {"PatchMatch (ours)": MethodScore(), "cv2.inpaint Telea": MethodScore()}
    cache: dict[int, tuple[FrameData, float]] = {}

    def get(j: int) -> tuple[FrameData, float]:
        if j not in cache:
            rgb, depth, stamp = seq.load(j)
            m = np.asarray(masks(j, stamp))
            if m.shape != rgb.shape[:2]:
                raise SlimsegError(
                    f"dynamic mask {mask_name(stamp)} of frame {j} is {m.shape[::-1]} (w, h) "
                    f"but the frame is {rgb.shape[1::-1]}; masks must match the RGB size"
                )
            cache[j] = (
                FrameData.build(rgb, depth, removed_region(m, dilation_px), keypoints),
                stamp,
            )
        return cache[j]

    n = len(seq)
    for i in tqdm(range(n), desc="restore", disable=not progress):
        for k in [k for k in cache if k < i - window]:
            del cache[k]
        target, stamp = get(i)
        t0 = time.perf_counter()
        cands = {}
        if target.removed.any():
            for j in range(i - window, i + window + 1, 1):
                if j != i and 0 <= j < n and (j - i) % stride == 0:
                    cands[j] = get(j)[0]
        refs = select_references(target, cands, max_refs=max_refs)
        restored = restore_frame(target, [(cands[r.index], r) for r in refs])
        t_ours = time.perf_counter() - t0
        name = mask_name(stamp)
        write_png(out / "restored" / "rgb" / name, restored.rgb)
        raw = np.clip(np.round(restored.depth * scale), 0, 65535).astype(np.uint16)
        write_png(out / "restored" / "depth" / name, raw)
        report.frames += 1
        if target.removed.any():
            report.restored += 1
            report.references += len(refs)
            report.coverage.append(restored.coverage)
            if report.methods:
                _score(report, seq, i, bg_dir, name, target, restored.rgb, restored.depth, t_ours)
    return report


def _score(
    report: RestoreReport,
    seq: FrameSource,
    i: int,
    bg_dir: Path,
    name: str,
    target: FrameData,
    rgb: np.ndarray,
    depth: np.ndarray,
    t_ours: float,
) -> None:
    truth_bgr = decode_file(bg_dir / "rgb" / name, cv2.IMREAD_COLOR)
    if truth_bgr is None:
        return
    truth = cv2.cvtColor(truth_bgr, cv2.COLOR_BGR2RGB)
    depth_name = Path(seq.frames[i][1][1]).name
    raw = decode_file(bg_dir / "depth" / depth_name, cv2.IMREAD_UNCHANGED)
    truth_d = None if raw is None else depth_metres(raw, seq.camera.depth_scale)
    region = target.removed
    t0 = time.perf_counter()
    m8 = region.astype(np.uint8)
    telea = cv2.inpaint(target.rgb, m8, 3, cv2.INPAINT_TELEA)
    telea_d = cv2.inpaint(
        np.where(region, 0, target.depth).astype(np.float32), m8, 3, cv2.INPAINT_TELEA
    )
    t_telea = time.perf_counter() - t0
    report.scored += 1
    report.truth_orb += orb_in(truth, region)
    for key, img, dep, secs in (
        ("PatchMatch (ours)", rgb, depth, t_ours),
        ("cv2.inpaint Telea", telea, telea_d, t_telea),
    ):
        s = report.methods[key]
        s.psnr.append(psnr(img, truth, region))
        s.ssim.append(ssim_in(img, truth, region))
        s.orb += orb_in(img, region)
        s.seconds += secs
        if truth_d is not None:
            ok = region & (truth_d > 0) & (dep > 0)
            if ok.any():
                s.depth_mae.append(float(np.abs(dep[ok] - truth_d[ok]).mean()))


def report_rows(report: RestoreReport) -> list[list[object]]:
    """Table rows (numbers as text, "-" where not applicable): method, PSNR dB, SSIM, depth MAE
    m (means over scored frames), ORB features in the regions (total, per frame), ms per
    frame."""

    def mean(v: list[float], digits: int) -> str:
        finite = [x for x in v if math.isfinite(x)]
        return f"{float(np.mean(finite)):.{digits}f}" if finite else "-"

    n = max(report.scored, 1)
    rows: list[list[object]] = [["masked-out frame", "-", "-", "-", 0, "0.0", "-"]]
    for key, s in report.methods.items():
        rows.append(
            [
                key,
                mean(s.psnr, 2),
                mean(s.ssim, 3),
                mean(s.depth_mae, 3),
                s.orb,
                f"{s.orb / n:.1f}",
                f"{1000 * s.seconds / n:.0f}",
            ]
        )
    rows.append(
        ["true background", "-", "-", "-", report.truth_orb, f"{report.truth_orb / n:.1f}", "-"]
    )
    return rows


REPORT_HEADERS = [
    "method",
    "PSNR dB",
    "SSIM",
    "depth MAE m",
    "ORB in regions",
    "ORB / frame",
    "ms / frame",
]
