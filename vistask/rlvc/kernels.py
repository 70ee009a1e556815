"""Loops of the stage loop compiled by numba: the split search's cells and value iteration.

They add up in the order of the same sums written as torch scatter-adds (``index_add_``), so
their results equal those to the last bit. numba is imported on first use
(``split.candidate_moments``, ``solver.value_iteration``): acting never needs it, and it
takes about 50 MB and 0.3 s to import; the first call compiles (numba caches the code).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def passing_cells(row_group, starts, features, w0, w1, w2, room, n_features, min_count, room_for):
    """The cells of ``split.candidate_moments``, group by group: each group's rows in their
    order (a counting sort), their features' counts, sums and sums of squares added in
    F-sized accumulators; room for ``room_for`` cells to start with, doubled as they come."""
    n_groups = len(room)
    size = np.zeros(n_groups + 1, dtype=np.int64)
    for g in row_group:
        size[g] += 1
    first = np.zeros(n_groups + 2, dtype=np.int64)
    first[1:] = np.cumsum(size)
    order, at = np.empty(len(row_group), dtype=np.int64), first[:-1].copy()
    for r in range(len(row_group)):
        order[at[row_group[r]]] = r
        at[row_group[r]] += 1
    count, s1, s2 = np.zeros(n_features), np.zeros(n_features), np.zeros(n_features)
    seen, touched = np.zeros(n_features, dtype=np.bool_), np.empty(n_features, dtype=np.int64)
    cells = np.empty(room_for, np.int64)
    n, a, b = np.empty(room_for), np.empty(room_for), np.empty(room_for)
    k = 0
    for g in range(n_groups):  # the last group (n_groups) cannot split
        t = 0
        for i in range(first[g], first[g + 1]):
            r = order[i]
            for j in range(starts[r], starts[r + 1]):
                f = features[j]
                if not seen[f]:
                    seen[f] = True
                    touched[t] = f
                    t += 1
                count[f] += w0[r]
                s1[f] += w1[r]
                s2[f] += w2[r]
        touched[:t].sort()  # the cells ascend
        for f in touched[:t]:
            if min_count <= count[f] <= room[g]:
                if k == len(cells):
                    cells, n, a, b = doubled(cells), doubled(n), doubled(a), doubled(b)
                cells[k], n[k], a[k], b[k] = g * n_features + f, count[f], s1[f], s2[f]
                k += 1
            count[f], s1[f], s2[f], seen[f] = 0.0, 0.0, 0.0, False
    return cells[:k], n[:k], a[:k], b[:k]


@numba.njit(cache=True)
def doubled(array):
    """A copy of ``array`` with twice the room."""
    grown = np.empty(2 * len(array), array.dtype)
    grown[: len(array)] = array
    return grown


@numba.njit(cache=True)
def value_iteration(sa, successor, p, r, visited, gamma, tol, max_iters, n_actions):
    """Q (S * A,) of ``solver.value_iteration`` from the transitions' (s, a) row ``sa``,
    successor and probability (nnz,), the rewards and visited flags (S * A,): the expected
    successor values added transition by transition in their order."""
    v = np.zeros(len(r) // n_actions)
    q, expected = np.empty(len(r)), np.empty(len(r))
    for _ in range(max_iters):
        expected[:] = 0.0
        for k in range(len(sa)):
            expected[sa[k]] += p[k] * v[successor[k]]
        q[:] = r + gamma * expected
        change = 0.0
        for s in range(len(v)):
            best = -np.inf
            for i in range(s * n_actions, (s + 1) * n_actions):
                if visited[i] and q[i] > best:
                    best = q[i]
            best = best if np.isfinite(best) else 0.0  # no visited action: V = 0
            change = max(change, abs(best - v[s]))
            v[s] = best
        if change < tol:
            break
    return q
