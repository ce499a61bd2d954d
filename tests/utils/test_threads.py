"""torch_threads: the thread count is scoped to the block, restored even on error."""

from __future__ import annotations

import pytest
import torch

from slimseg.utils.threads import torch_threads


def test_count_is_set_inside_and_restored_after_an_error() -> None:
    before = torch.get_num_threads()
    wanted = 1 if before != 1 else 2
    with pytest.raises(RuntimeError), torch_threads(wanted):
        assert torch.get_num_threads() == wanted
        raise RuntimeError("boom")
    assert torch.get_num_threads() == before


@pytest.mark.parametrize("n", [None, 0])
def test_none_and_zero_leave_the_count_alone(n: int | None) -> None:
    before = torch.get_num_threads()
    with torch_threads(n):
        assert torch.get_num_threads() == before
    assert torch.get_num_threads() == before


def test_torch_runner_sets_threads_only_during_a_call() -> None:
    import numpy as np

    from slimseg.deploy.runners import TorchRunner

    before = torch.get_num_threads()
    other = 1 if before != 1 else 2
    seen = []

    class Probe(torch.nn.Module):
        def forward(self, x: torch.Tensor) -> torch.Tensor:
            seen.append(torch.get_num_threads())
            return x

    TorchRunner(Probe(), threads=other)(np.zeros((1, 3, 4, 4), np.float32))
    assert seen == [other] and torch.get_num_threads() == before
