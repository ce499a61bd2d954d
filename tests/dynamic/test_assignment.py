"""The track stage's own Hungarian assignment against scipy's (a dev dependency only)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from slimseg.dynamic.assignment import linear_assignment


@pytest.mark.parametrize("seed", range(4))
def test_same_total_cost_as_scipy_and_same_pairs_without_ties(seed) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(200):
        n, m = rng.integers(1, 10, 2)
        iou = rng.random((n, m)) * (rng.random((n, m)) < 0.4)  # mostly no overlap, as tracks
        cost = 1.0 - iou
        rows, cols = linear_assignment(cost)
        ref_rows, ref_cols = linear_sum_assignment(cost)
        assert len(rows) == min(n, m) and len(set(cols.tolist())) == len(cols)
        assert (np.diff(rows) > 0).all()
        assert cost[rows, cols].sum() == pytest.approx(cost[ref_rows, ref_cols].sum(), abs=1e-12)
        # the pairs the tracker keeps (overlapping ones) are scipy's: continuous IoUs, no ties
        kept = {(r, c) for r, c in zip(rows, cols, strict=True) if iou[r, c] > 0}
        ref = {(r, c) for r, c in zip(ref_rows, ref_cols, strict=True) if iou[r, c] > 0}
        assert kept == ref


def test_edges() -> None:
    rows, cols = linear_assignment(np.zeros((0, 3)))
    assert rows.shape == cols.shape == (0,)
    rows, cols = linear_assignment(np.array([[3.0], [1.0], [2.0]]))  # tall: the best row
    assert rows.tolist() == [1] and cols.tolist() == [0]
    with pytest.raises(ValueError, match="NaN"):
        linear_assignment(np.array([[np.nan]]))
