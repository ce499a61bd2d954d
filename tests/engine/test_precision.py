"""--precision: the Lightning setting chosen for a run, and the refused combinations."""

from __future__ import annotations

import pytest

from slimseg.engine.precision import resolve_precision
from slimseg.errors import SlimsegError


@pytest.mark.parametrize(
    ("requested", "amp", "gpu", "expected"),
    [
        ("auto", True, True, "16-mixed"),
        ("auto", True, False, "32-true"),
        ("auto", False, True, "32-true"),
        ("bf16-mixed", False, False, "bf16-mixed"),
        ("16-mixed", False, True, "16-mixed"),
        ("32-true", True, True, "32-true"),
    ],
)
def test_resolved_precision(requested: str, amp: bool, gpu: bool, expected: str) -> None:
    assert resolve_precision(requested, amp, gpu) == expected


def test_float16_on_cpu_and_unknown_values_are_refused() -> None:
    with pytest.raises(SlimsegError, match="needs a CUDA device"):
        resolve_precision("16-mixed", True, False)
    with pytest.raises(SlimsegError, match="not one of"):
        resolve_precision("fp8", True, True)
