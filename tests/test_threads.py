"""Scoped torch thread counts (Predictor and bench must not leave theirs behind)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from slimseg.deploy.runners import TorchRunner
from slimseg.utils.threads import torch_threads


def test_torch_threads_restores_the_previous_count() -> None:
    before = torch.get_num_threads()
    other = 1 if before != 1 else 2
    with torch_threads(other):
        assert torch.get_num_threads() == other
    assert torch.get_num_threads() == before
    with pytest.raises(RuntimeError), torch_threads(other):
        raise RuntimeError("boom")
    assert torch.get_num_threads() == before
    with torch_threads(None):
        assert torch.get_num_threads() == before


def test_torch_runner_sets_threads_only_during_a_call() -> None:
    before = torch.get_num_threads()
    other = 1 if before != 1 else 2
    seen = []

    class Probe(torch.nn.Module):
        def forward(self, x: torch.Tensor) -> torch.Tensor:
            seen.append(torch.get_num_threads())
            return x

    TorchRunner(Probe(), threads=other)(np.zeros((1, 3, 4, 4), np.float32))
    assert seen == [other] and torch.get_num_threads() == before
