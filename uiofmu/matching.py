"""The least-cost matching of the rows and columns of a square cost matrix (the assignment problem).

Used to pair the eigenvalues a card lists with the ones its matrices give, in any order
(:func:`uiofmu.consistency.spectrum`): numpy only, so re-checking a card loads no optimiser.
"""

from __future__ import annotations

import numpy as np


def least_cost_matching(cost) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns paired so that the sum of their costs is least.

    The shortest augmenting path method with dual potentials (Hungarian method, O(n^3)): each row in turn
    joins the matching along the cheapest path of reduced costs from it to a free column, and the potentials
    move so that every reduced cost stays non-negative and those of matched pairs zero.

    Parameters
    ----------
    cost : (n, n) array_like
        Finite costs.

    Returns
    -------
    rows, cols : (n,) int arrays
        ``rows`` is ``0, ..., n - 1`` and row ``rows[i]`` is paired with column ``cols[i]``.

    Raises
    ------
    ValueError
        For a matrix that is not square or has a cost that is not finite.

    Examples
    --------
    >>> rows, cols = least_cost_matching([[4.0, 1.0], [2.0, 8.0]])
    >>> cols.tolist()
    [1, 0]
    """
    cost = np.asarray(cost, dtype=float)
    if cost.ndim != 2 or cost.shape[0] != cost.shape[1]:
        raise ValueError(f"least_cost_matching: a square cost matrix, not one of shape {cost.shape}")
    if not np.all(np.isfinite(cost)):
        raise ValueError("least_cost_matching: every cost must be finite")
    n = cost.shape[0]
    # column 0 stands for "no column": the start of every path; row_of[j] is the row matched to column j (1..n)
    row_pot = np.zeros(n + 1)
    col_pot = np.zeros(n + 1)
    row_of = np.zeros(n + 1, dtype=int)
    for row in range(1, n + 1):
        row_of[0] = row
        reach = np.full(n + 1, np.inf)          # least reduced cost of a path to each column
        came_from = np.zeros(n + 1, dtype=int)
        done = np.zeros(n + 1, dtype=bool)
        col = 0
        while row_of[col] != 0:
            done[col] = True
            here = row_of[col]
            free = ~done
            free[0] = False
            reduced = cost[here - 1] - row_pot[here] - col_pot[1:]
            better = free[1:] & (reduced < reach[1:])
            reach[1:][better] = reduced[better]
            came_from[1:][better] = col
            candidates = np.flatnonzero(free)
            nxt = candidates[np.argmin(reach[candidates])]
            delta = reach[nxt]
            row_pot[row_of[done]] += delta
            col_pot[done] -= delta
            reach[free] -= delta
            col = nxt
        while col != 0:                          # flip the path: each column takes the row before it
            prev = came_from[col]
            row_of[col] = row_of[prev]
            col = prev
    cols = np.empty(n, dtype=int)
    cols[row_of[1:] - 1] = np.arange(n)
    return np.arange(n), cols


__all__ = ["least_cost_matching"]
