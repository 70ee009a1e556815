"""Which visual classes compaction merges (paper section 2.5.2): classes whose optimal values
are close and whose greedy actions are interchangeable; and where a dropped feature may move
the percepts that show it.

Classes s1 and s2 are interchangeable within a tolerance t when

    |V(s1) - V(s2)| <= t,  Q(s2, a1) >= V(s2) - t  and  Q(s1, a2) >= V(s1) - t,

with a_i the greedy action of s_i. The relation is not transitive, so groups are built
greedily as cliques: every pair inside a group is interchangeable, and any member's greedy
action loses at most t in every other member.

A feature that compaction drops moves the few percepts that show it, not whole classes: a
percept of s1 may go to s2 when s2's greedy action loses at most t in s1 and the values differ
by at most ``DROP_VALUE_TOLERANCE`` t. A learner that makes compounds drops a feature only
where it moves percepts between interchangeable classes.

Once learning ends, the merged classes are grown again as one decision tree that puts every
seen percept in its class (``induced_splits``): the tests then serve the merged classes, not
the TD errors of the classes they were split from.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse
import torch
from sklearn.tree import DecisionTreeClassifier

from vistask.checks import checked
from vistask.rlvc.presence import PackedPresence, distinct_rows
from vistask.rlvc.solver import state_values

DROP_VALUE_TOLERANCE = 10.0  # in tolerances; see the module's docstring
# The noisy copies of ``induced_splits``. Place navigation, the classes of one BDD agent regrown,
# held-out error: 128 views a state, mean of 5 draws: 9.0% with no copies, 8.1% with 4 copies
# at 0.15, 7.7% with 8 at 0.2; 512 views a state (seed 0): 7.8% with none, 7.5% with 2 at
# 0.2, 6.9% with 4 at 0.15, 7.0% with 4 at 0.2, 7.5% with 8 at 0.2, which took three times as
# long as 4 (186 s).
NOISY_COPIES = 4
DROP_RATE = 0.15
ACCEPTABLE_BLOCK = 1024  # rows of ``acceptable`` compared at once
# ``induced_splits`` hands scikit-learn a sparse matrix where the dense one would take more
# bytes (it grows the same tree from either).
DENSE_TREE_BYTES = 2**30


@checked
def acceptable(q: torch.Tensor, tolerance: float, value_tolerance: float) -> torch.Tensor:
    """(S, A) Q -> (S, S) bool: class j's greedy action loses at most ``tolerance`` in class i,
    and their values differ by at most ``value_tolerance``.

    Actions a class never tried (Q = -inf) are never acceptable, and no class with no tried
    action is. Every class is acceptable to itself.

    Example:
        >>> q = torch.tensor([[1.0, 0.0], [0.7, 0.0], [0.0, 1.0]])
        >>> acceptable(q, 0.1, 0.5)
        tensor([[ True,  True, False],
                [ True,  True, False],
                [False, False,  True]])
    """
    if q.ndim != 2:
        raise ValueError(f"q must be (S, A), got shape {tuple(q.shape)}")
    if tolerance < 0 or value_tolerance < 0:
        raise ValueError(f"tolerances must be >= 0, got {tolerance} and {value_tolerance}")
    v, greedy = state_values(q), q.argmax(dim=1)
    tried = torch.isfinite(q).any(dim=1)
    # good[i, a]: action a loses at most ``tolerance`` in class i.
    good = (q >= v[:, None] - tolerance) & tried[:, None]
    out = torch.eye(len(q), dtype=torch.bool)
    # Blocks of classes in order of value, each compared with the classes whose values lie
    # within twice ``value_tolerance`` of its own (the others are never close): ``RLVC.fuse``
    # compares some 16,000 cells, whose (S, S) float64 differences took gigabytes and seconds.
    by_value = torch.argsort(v)
    sorted_v = v[by_value]
    for rows in by_value.split(ACCEPTABLE_BLOCK):
        low = torch.searchsorted(sorted_v, v[rows].min() - 2 * value_tolerance)
        high = torch.searchsorted(sorted_v, v[rows].max() + 2 * value_tolerance, right=True)
        columns = by_value[low:high]
        close = (v[rows, None] - v[None, columns]).abs() <= value_tolerance
        out[rows[:, None], columns] |= close & good[rows][:, greedy[columns]] & tried[columns]
    return out


@checked
def interchangeable(q: torch.Tensor, tolerance: float) -> torch.Tensor:
    """(S, A) Q -> (S, S) bool: classes i and j are interchangeable within ``tolerance``.

    Actions a class never tried (Q = -inf) never count as interchangeable, and neither does a
    class with no tried action at all.

    Example:
        >>> q = torch.tensor([[1.0, 0.0], [0.95, 0.0], [0.0, 1.0]])
        >>> interchangeable(q, 0.1)
        tensor([[ True,  True, False],
                [ True,  True, False],
                [False, False,  True]])
    """
    each_way = acceptable(q, tolerance, tolerance)
    return each_way & each_way.T


@checked
def merge_groups(q: torch.Tensor, tolerance: float) -> torch.Tensor:
    """(S, A) Q -> (S,) long group of every class, groups numbered 0..G-1.

    Classes are visited from the highest value down; each joins the first group all of whose
    members it is interchangeable with, or starts a new one.

    Example:
        >>> merge_groups(torch.tensor([[1.0, 0.0], [0.95, 0.0], [0.0, 1.0]]), 0.1)
        tensor([0, 0, 1])
    """
    pairs = interchangeable(q, tolerance).numpy()
    n = len(pairs)
    group = torch.full((n,), -1, dtype=torch.long)
    # fits_all[g, c]: class c is interchangeable with every member of group g so far.
    fits_all = pairs.copy()  # at most one group per class, started from that class's row
    n_groups = 0
    for c in torch.argsort(state_values(q), descending=True, stable=True).tolist():
        open_groups = fits_all[:n_groups, c].nonzero()[0]
        if len(open_groups):
            g = int(open_groups[0])
            fits_all[g] &= pairs[c]
        else:
            g = n_groups
            fits_all[g] = pairs[c]
            n_groups += 1
        group[c] = g
    return group


def induced_splits(
    presence: torch.Tensor | PackedPresence,
    classes: torch.Tensor,
    features: Sequence[int],
    seed: int = 0,
    counts: torch.Tensor | None = None,
) -> tuple[list[tuple[int, int]], list[int]]:
    """A decision tree over ``features`` that puts every percept in its class, as class splits.

    CART (scikit-learn, Gini impurity) grows the tree until every leaf holds percepts of one
    class. Unlike the splits that made the classes, each one chosen for the TD errors of a
    class on its own, the tree's tests are chosen for the merged classes over all percepts. It
    also learns from ``NOISY_COPIES`` copies of every percept, each present feature dropped
    with probability ``DROP_RATE``: unseen percepts lack some of the features of the seen ones
    of their state, and the copies make the tree route them by tests that do not hinge on one
    feature. The copies never move a percept: a leaf takes the class of the percepts in it,
    or where only copies reach it, the class of the percepts around it (``_node_classes``);
    a subtree whose leaves all take one class becomes one leaf.

    Returns the splits (class split, feature tested: the present side becomes the next class
    id) in the order in which ``ClassBDD.split`` numbers the classes they make, and the class
    of each of those ids, a leaf of the tree each.

    Args:
        presence: (N, F) bool presence of the percepts.
        classes: (N,) long class of each percept; percepts equal on ``features`` must share it.
        features: the features the tree may test.
        seed: draws the copies and breaks ties between equally good tests.
        counts: (N,) long, the times each percept was met, its weight (None: once each).

    Example:
        >>> presence = torch.tensor([[1, 0, 0], [0, 1, 0], [0, 0, 1]]).bool()
        >>> induced_splits(presence, torch.tensor([1, 0, 0]), [0, 1, 2])
        ([(0, 0)], [0, 1])
    """
    features = np.asarray(features, dtype=np.int64)
    labels = classes.cpu().numpy()
    classes_of, labels = np.unique(labels, return_inverse=True)  # the tree's class indices
    if len(classes_of) < 2 or len(features) == 0:
        return [], [int(classes_of[0]) if len(classes_of) else 0]
    # A percept seen many times is one row, weighted by its count.
    bits, first, inverse, weight = distinct_rows(presence, features, counts)
    if (labels[first][inverse] != labels).any():
        raise ValueError("percepts equal on the features are in different classes")
    labels, n = labels[first], len(first)
    rows, columns = np.unpackbits(bits, axis=1, count=len(features)).nonzero()
    rng = np.random.default_rng(seed)
    copies = 1 + NOISY_COPIES  # the percepts, then their noisy copies
    kept = [rng.random(len(rows)) >= DROP_RATE for _ in range(NOISY_COPIES)]
    rows = np.concatenate([rows, *(rows[k] + (i + 1) * n for i, k in enumerate(kept))])
    columns = np.concatenate([columns, *(columns[k] for k in kept)])
    shape = (n * copies, len(features))
    if np.prod(shape) * 4 <= DENSE_TREE_BYTES:
        # Dense and column-major: scikit-learn grew the same tree in 7-9 s, where it took 13 s
        # row-major and 12-19 s from a sparse matrix (the mountain car's classes fused from
        # 11 structures: 44,000 percepts, 639 features).
        x = np.zeros(shape, dtype=np.float32, order="F")
        x[rows, columns] = 1
    else:
        x = scipy.sparse.csc_matrix((np.ones(len(rows), np.float32), (rows, columns)), shape)
    tree = DecisionTreeClassifier(criterion="gini", random_state=seed)
    tree = tree.fit(x, np.tile(labels, copies), sample_weight=np.tile(weight, copies)).tree_
    leaf_of = tree.apply(x[:n].tocsr() if scipy.sparse.issparse(x) else x[:n])
    node_class = _node_classes(tree, leaf_of, labels, weight, len(classes_of))
    # Breadth first, the absent child keeps its parent's class id and the present child
    # takes the next one, as ``ClassBDD.split`` numbers them.
    splits, id_class, frontier = [], {}, [(0, 0)]
    n_ids = 1
    while frontier:
        next_frontier = []
        for node, class_id in frontier:
            absent, present = tree.children_left[node], tree.children_right[node]
            if node_class[node] >= 0:
                id_class[class_id] = int(classes_of[node_class[node]])
                continue
            splits.append((class_id, int(features[tree.feature[node]])))
            next_frontier += [(absent, class_id), (present, n_ids)]
            n_ids += 1
        frontier = next_frontier
    return splits, [id_class[i] for i in range(n_ids)]


def _node_classes(
    tree, leaf_of: np.ndarray, labels: np.ndarray, weight: np.ndarray, n_classes: int
) -> np.ndarray:
    """(nodes,) the class of every node of a fitted scikit-learn ``tree`` whose leaves all have
    one class, else -1.

    A leaf has the class of the percepts in it (``leaf_of`` (N,) their leaves, ``labels`` (N,)
    their classes, ``weight`` (N,) how many times each was seen). Where only copies reach it,
    it has the class that most percepts have at its nearest ancestor that percepts reach: the
    copies choose the tests, but they do not send unseen percepts to classes that no seen
    percept around them has.
    """
    left, right = tree.children_left, tree.children_right
    counts = np.zeros((tree.node_count, n_classes), dtype=np.int64)
    np.add.at(counts, (leaf_of, labels), weight)
    # scikit-learn numbers a node's children after it.
    for node in range(tree.node_count - 1, -1, -1):
        if left[node] >= 0:
            counts[node] = counts[left[node]] + counts[right[node]]
    majority = counts.argmax(axis=1)
    for node in range(tree.node_count):
        if left[node] >= 0:
            for child in (left[node], right[node]):
                if counts[child].sum() == 0:
                    majority[child] = majority[node]
    node_class = np.where(left < 0, majority, -1)
    for node in range(tree.node_count - 1, -1, -1):
        if left[node] >= 0 and node_class[left[node]] == node_class[right[node]]:
            node_class[node] = node_class[left[node]]
    return node_class


__all__ = [
    "DROP_RATE",
    "DROP_VALUE_TOLERANCE",
    "NOISY_COPIES",
    "acceptable",
    "induced_splits",
    "interchangeable",
    "merge_groups",
]
