"""Float32 regions inside mixed-precision code: decoding, mask assembly and validation.

Under ``torch.autocast`` (Lightning's ``16-mixed``/``bf16-mixed`` wrap the training *and*
the validation step in it) matmuls and convolutions run in float16/bfloat16 even on float32
inputs. Box decoding, mask probabilities and the validation that picks ``best.pt`` must not:
they run inside :func:`full_precision`, so their numbers do not depend on the training
precision (``slimseg val``, export and the predictor run in float32).
"""

from __future__ import annotations

from contextlib import AbstractContextManager

import torch


def full_precision(device: torch.device | str) -> AbstractContextManager:
    """A context in which autocast is off for ``device``'s type (``"cuda"``, ``"cpu"``, ...):
    operations run in their inputs' dtype. Restores the caller's autocast state on exit."""
    device_type = torch.device(device).type
    return torch.autocast(device_type, enabled=False)
