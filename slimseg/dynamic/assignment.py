"""Minimum-cost assignment of the rows of a cost matrix to its columns (the Hungarian method).

The track stage's association (:mod:`slimseg.dynamic.track`) matches a frame's detections to
its tracks, a few dozen at most, so the core install solves it here instead of depending on
scipy (143 MB of the 400 MB the core install may take, for one function).

The method: shortest augmenting paths with row and column potentials (Kuhn–Munkres in the
Jonker–Volgenant form), ``O(n² m)`` for ``n ≤ m``; each row in turn is added and the
cheapest alternating path to a free column, in reduced costs, is augmented. Any optimal
assignment is returned; where several are optimal (equal costs) the choice can differ from
``scipy.optimize.linear_sum_assignment``'s, never the total cost.
"""

from __future__ import annotations

import numpy as np


def linear_assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``int64 [K]`` (increasing) and columns ``int64 [K]`` of a minimum-cost assignment
    of ``cost float [n, m]`` (finite values), ``K = min(n, m)``: what
    ``scipy.optimize.linear_sum_assignment`` returns, up to ties."""
    cost = np.asarray(cost, np.float64)
    if cost.ndim != 2:
        raise ValueError(f"expected a cost matrix [n, m], got shape {cost.shape}")
    if not np.isfinite(cost).all():
        raise ValueError("the cost matrix holds a NaN or an infinite value")
    if cost.size == 0:
        empty = np.zeros(0, np.int64)
        return empty, empty
    transposed = cost.shape[0] > cost.shape[1]
    c = cost.T if transposed else cost
    n, m = c.shape
    # 1-based columns; column 0 is the virtual start of each search
    u, v = np.zeros(n + 1), np.zeros(m + 1)
    owner = np.zeros(m + 1, np.int64)  # row (1-based) holding each column, 0: free
    way = np.zeros(m + 1, np.int64)
    for row in range(1, n + 1):
        owner[0], col = row, 0
        best = np.full(m + 1, np.inf)
        used = np.zeros(m + 1, bool)
        while True:
            used[col] = True
            r = owner[col]
            free = ~used[1:]
            reduced = c[r - 1] - u[r] - v[1:]
            better = free & (reduced < best[1:])
            best[1:][better] = reduced[better]
            way[1:][better] = col
            candidates = np.where(free, best[1:], np.inf)
            delta = candidates.min()
            ties = np.flatnonzero(candidates == delta) + 1
            unowned = ties[owner[ties] == 0]  # on a tie, a free column ends the search
            nxt = int(unowned[0] if len(unowned) else ties[0])
            u[owner[used]] += delta
            v[used] -= delta
            best[1:][free] -= delta
            col = nxt
            if owner[col] == 0:
                break
        while col:  # augment along the path back to the start
            prev = way[col]
            owner[col] = owner[prev]
            col = prev
    cols = np.flatnonzero(owner[1:])
    rows = owner[1:][cols] - 1
    if transposed:
        rows, cols = cols, rows
    order = np.argsort(rows, kind="stable")
    return rows[order].astype(np.int64), cols[order].astype(np.int64)
