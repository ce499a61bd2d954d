"""The GSConv channel shuffle: a fixed interleave permutation that never mixes the batch."""

from __future__ import annotations

import torch

from slimseg.layers.gsconv import GSConv, channel_interleave


def test_interleave_is_the_documented_permutation() -> None:
    x = torch.arange(8).float().view(1, 8, 1, 1)
    assert channel_interleave(x).flatten().tolist() == [0, 4, 1, 5, 2, 6, 3, 7]


def test_interleave_is_a_permutation_and_keeps_batch_order() -> None:
    x = torch.randn(5, 12, 3, 4)
    y = channel_interleave(x)
    for b in range(5):  # each sample's output is a channel permutation of the same sample
        assert sorted(y[b].flatten().tolist()) == sorted(x[b].flatten().tolist())
    assert torch.equal(y[:, 0::2], x[:, :6]) and torch.equal(y[:, 1::2], x[:, 6:])


def test_gsconv_batch_independence() -> None:
    m = GSConv(4, 8, 3, 2).eval()
    x = torch.randn(3, 4, 16, 16)
    with torch.no_grad():
        full = m(x)
        singles = torch.cat([m(x[i : i + 1]) for i in range(3)])
    torch.testing.assert_close(full, singles)
    assert full.shape == (3, 8, 8, 8)
