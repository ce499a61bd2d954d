"""Training precision: the ``--precision`` choices and the Lightning setting they select."""

from __future__ import annotations

from slimseg.errors import SlimsegError

#: ``auto`` follows the recipe's ``amp`` (16-mixed on a GPU, else full precision).
PRECISIONS = ("auto", "32-true", "16-mixed", "bf16-mixed")


def resolve_precision(requested: str, amp: bool, use_gpu: bool) -> str:
    """The Lightning ``precision`` for a run: ``requested`` is one of :data:`PRECISIONS`;
    ``amp`` is the recipe's switch, ``use_gpu`` whether the run trains on CUDA devices.

    float16 autocast needs a GPU (its loss scaling is CUDA-only): asked for on the CPU it is
    an error, not a silent fallback; ``bf16-mixed`` runs on both."""
    if requested not in PRECISIONS:
        raise SlimsegError(f"precision={requested!r} is not one of {list(PRECISIONS)}")
    if requested == "auto":
        return "16-mixed" if (amp and use_gpu) else "32-true"
    if requested == "16-mixed" and not use_gpu:
        raise SlimsegError(
            "precision=16-mixed needs a CUDA device (--accelerator gpu); on the CPU use "
            "bf16-mixed or 32-true"
        )
    return requested
