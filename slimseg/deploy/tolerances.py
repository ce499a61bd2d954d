"""The export contract's FP32 limits (export/CONTRACT.md), their one home: torch-free, so the
runtime checks an engine's precision against them (:mod:`slimseg.deploy.ov_session`) without
the training stack; :mod:`slimseg.deploy.parity` gates exports on them."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Tolerance:
    """``|onnx - torch| <= atol + rtol · |torch|`` elementwise (:func:`numpy.allclose`)."""

    atol: float
    rtol: float

    def __str__(self) -> str:
        return f"{self.atol:g} + {self.rtol:g}·|torch|"


# Measured (export/CONTRACT.md): realistic-magnitude graphs use at most ~20 % of these limits
# on an AVX-512 CPU and twice its float64 deviation at most ~40 %; every zeroed conv bias or
# swapped pair of output channels of yolov8n-seg and yolov8s-seg-gs-rep exceeds them (≥ 4.9×).
FP32_BOX_TOL = Tolerance(atol=0.25, rtol=1e-4)  # px: cx, cy, w, h (DFL decode: absolute)
FP32_SCORE_TOL = Tolerance(atol=2e-3, rtol=1e-4)  # class scores after sigmoid, in [0, 1]
FP32_MASK_TOL = Tolerance(atol=1e-2, rtol=1e-4)  # raw mask coefficients and prototypes
FP32_LOGIT_TOL = Tolerance(atol=1e-3, rtol=1e-4)  # semantic models: per-pixel class logits
FP32_TOLERANCES = {
    "box_px": FP32_BOX_TOL,
    "score": FP32_SCORE_TOL,
    "mask_terms": FP32_MASK_TOL,
    "logit": FP32_LOGIT_TOL,
}
