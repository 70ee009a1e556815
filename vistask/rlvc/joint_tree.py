"""RLJC's joint classes: a decision tree over (percept, continuous action) pairs (paper 2.5.3).

A node tests either a visual feature ("feature f present") or an action feature ("action
component d >= t"). A leaf is a joint class: a set of percepts times a box of actions. For a
percept alone, visual tests are followed and both branches of action tests are taken: the
leaves reached are the joint classes compatible with the percept, whose boxes tile the action
space. Percepts with the same compatible classes form a perceptual cell.

As in ``ClassTree``, splitting a leaf keeps its class id on the "no" side and gives the "yes"
side a new id, so that class ids stay stable across stages.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from vistask.checks import checked
from vistask.rlvc.presence import PackedPresence


class _Tables(NamedTuple):
    """The tree as arrays, rebuilt after a split: what the batched queries index."""

    feature: np.ndarray  # (nodes,) tested feature, -1 where none
    dim: np.ndarray  # (nodes,) tested action dimension, -1 where none
    threshold: np.ndarray  # (nodes,) threshold of an action test
    child: np.ndarray  # (nodes, 2) "no" and "yes" children; a leaf is its own child
    leaf_class: np.ndarray  # (nodes,) class id, -1 at internal nodes
    leaf: np.ndarray  # (nodes,) bool
    depth: int
    box_low: np.ndarray  # (J, m)
    box_high: np.ndarray  # (J, m)


@checked
class JointTree:
    """Decision tree over visual features and action thresholds; batched queries.

    Example:
        >>> tree = JointTree(n_features=100, low=[-3.14], high=[3.14])
        >>> tree.split_feature(0, feature=7)              # class 0 -> {7 absent: 0, present: 1}
        >>> tree.split_action(1, dim=0, threshold=0.0)    # class 1 -> {a < 0: 1, a >= 0: 2}
        >>> tree.classify(presence, actions)    # (N, 100) bool, (N, 1) float -> (N,) class ids
        >>> rows, classes = tree.compatible(presence)     # (K,), (K,) compatible pairs
        >>> tree.box_low[classes], tree.box_high[classes] # their action boxes (K, 1)

    Args:
        n_features: number of visual features F that presence vectors hold.
        low, high: (m,) bounds of the action space, the box of the root class.
    """

    def __init__(self, n_features: int, low, high) -> None:
        low, high = np.atleast_1d(low).astype(np.float64), np.atleast_1d(high).astype(np.float64)
        if n_features < 1:
            raise ValueError(f"n_features must be >= 1, got {n_features}")
        if low.ndim != 1 or low.shape != high.shape or not np.all(low < high):
            raise ValueError(f"need (m,) bounds with low < high, got {low} and {high}")
        if not np.all(np.isfinite(low) & np.isfinite(high)):
            raise ValueError(f"action bounds must be finite, got {low} and {high}")
        self.n_features, self.n_dims = int(n_features), len(low)
        self.low, self.high = low, high
        # Per node: tested feature or action dimension (-1 when the other kind, both -1 at
        # leaves), threshold of an action test, children, class id (-1 at internal nodes).
        self.feature: list[int] = [-1]
        self.dim: list[int] = [-1]
        self.threshold: list[float] = [0.0]
        self.no: list[int] = [-1]
        self.yes: list[int] = [-1]
        self.leaf_class: list[int] = [0]
        self._leaf_of_class: list[int] = [0]
        self._boxes: list[tuple[np.ndarray, np.ndarray]] = [(low, high)]
        self._tables: _Tables | None = None

    @property
    def n_classes(self) -> int:
        """Number of classes."""
        return len(self._leaf_of_class)

    @property
    def box_low(self) -> np.ndarray:
        """(J, m) lower corners of the joint classes' action boxes."""
        return self._node_tables().box_low

    @property
    def box_high(self) -> np.ndarray:
        """(J, m) upper corners of the joint classes' action boxes."""
        return self._node_tables().box_high

    @property
    def selected_features(self) -> list[int]:
        """Sorted distinct visual features tested somewhere in the tree."""
        return sorted({f for f in self.feature if f >= 0})

    @property
    def action_tests(self) -> int:
        """Number of nodes that test an action threshold."""
        return sum(d >= 0 for d in self.dim)

    def _check_class(self, class_id: int) -> None:
        if not 0 <= class_id < self.n_classes:
            raise ValueError(f"no class {class_id} (tree has {self.n_classes})")

    def _split(self, class_id: int, feature: int, dim: int, threshold: float) -> int:
        leaf, new_class = self._leaf_of_class[class_id], self.n_classes
        no, yes = len(self.feature), len(self.feature) + 1
        self.feature += [-1, -1]
        self.dim += [-1, -1]
        self.threshold += [0.0, 0.0]
        self.no += [-1, -1]
        self.yes += [-1, -1]
        self.leaf_class += [class_id, new_class]
        self.feature[leaf], self.dim[leaf], self.threshold[leaf] = feature, dim, threshold
        self.no[leaf], self.yes[leaf], self.leaf_class[leaf] = no, yes, -1
        self._leaf_of_class[class_id] = no
        self._leaf_of_class.append(yes)
        self._tables = None
        return new_class

    def split_feature(self, class_id: int, feature: int) -> int:
        """Split a class on a visual feature; returns the id of the "present" class."""
        self._check_class(class_id)
        if not 0 <= feature < self.n_features:
            raise ValueError(f"feature {feature} outside 0..{self.n_features - 1}")
        self._boxes.append(self._boxes[class_id])
        return self._split(class_id, feature, -1, 0.0)

    def split_action(self, class_id: int, dim: int, threshold: float) -> int:
        """Split a class on "action component ``dim`` >= ``threshold``"; returns the id of the
        upper class. The threshold must cut the class's box."""
        self._check_class(class_id)
        if not 0 <= dim < self.n_dims:
            raise ValueError(f"action dimension {dim} outside 0..{self.n_dims - 1}")
        low, high = self._boxes[class_id]
        if not low[dim] < threshold < high[dim]:
            raise ValueError(
                f"threshold {threshold} does not cut class {class_id}'s box "
                f"[{low[dim]}, {high[dim]}] on dimension {dim}"
            )
        upper_low, lower_high = low.copy(), high.copy()
        upper_low[dim], lower_high[dim] = threshold, threshold
        self._boxes[class_id] = (low, lower_high)
        self._boxes.append((upper_low, high))
        return self._split(class_id, -1, dim, float(threshold))

    def _node_tables(self) -> _Tables:
        if self._tables is None:
            nodes = np.arange(len(self.feature))
            leaf = np.array(self.leaf_class) >= 0
            # A leaf is its own child on both sides, so rows that reach it early stay put.
            child = np.stack([np.where(leaf, nodes, self.no), np.where(leaf, nodes, self.yes)], 1)
            depth = {0: 0}
            for node in np.flatnonzero(~leaf):
                depth[self.no[node]] = depth[self.yes[node]] = depth[node] + 1
            self._tables = _Tables(
                np.array(self.feature),
                np.array(self.dim),
                np.array(self.threshold),
                child,
                np.array(self.leaf_class),
                leaf,
                max(depth.values()),
                np.stack([low for low, _ in self._boxes]),
                np.stack([high for _, high in self._boxes]),
            )
        return self._tables

    def _check(self, presence: torch.Tensor | PackedPresence) -> np.ndarray:
        if presence.ndim != 2 or presence.shape[1] != self.n_features:
            raise ValueError(
                f"presence must be (N, {self.n_features}), got {tuple(presence.shape)}"
            )
        return presence.cpu().numpy()

    def classify(
        self,
        presence: torch.Tensor | PackedPresence,
        actions: torch.Tensor | np.ndarray,
        percepts: torch.Tensor | np.ndarray | None = None,
    ) -> torch.Tensor:
        """Joint classes of (percept, action) pairs, one vectorized step per tree level.

        Args:
            presence: (M, F) bool feature presence of M percepts.
            actions: (N, m) actions.
            percepts: (N,) the percept of each action, rows of ``presence`` (default: N = M,
                action i taken at percept i).

        Returns:
            (N,) long joint class ids.
        """
        bits = self._check(presence)
        actions = np.asarray(torch.as_tensor(actions, dtype=torch.float64).cpu())
        rows = np.arange(len(bits)) if percepts is None else torch.as_tensor(percepts).cpu().numpy()
        if actions.shape != (len(rows), self.n_dims):
            raise ValueError(f"actions must be ({len(rows)}, {self.n_dims}), got {actions.shape}")
        t = self._node_tables()
        feature, dim, threshold, child = t.feature, t.dim, t.threshold, t.child
        node, steps = np.zeros(len(rows), dtype=int), np.arange(len(rows))
        for _ in range(t.depth):
            f, d = feature[node], dim[node]
            visual = bits[rows, np.maximum(f, 0)]
            above = actions[steps, np.maximum(d, 0)] >= threshold[node]
            node = child[node, np.where(d >= 0, above, visual) * 1]
        return torch.as_tensor(t.leaf_class[node])

    def compatible(
        self, presence: torch.Tensor | PackedPresence
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The joint classes compatible with each percept, as pairs sorted by row.

        Args:
            presence: (N, F) bool feature presence of N percepts.

        Returns:
            rows (K,), classes (K,) long: class ``classes[k]`` is compatible with percept
            ``rows[k]``; every percept has at least one.
        """
        bits = self._check(presence)
        t = self._node_tables()
        feature, dim, child, leaf_class, leaf = t.feature, t.dim, t.child, t.leaf_class, t.leaf
        rows, node = np.arange(len(bits)), np.zeros(len(bits), dtype=int)
        found_rows, found_classes = [], []
        while len(rows):
            at_leaf = leaf[node]
            found_rows.append(rows[at_leaf])
            found_classes.append(leaf_class[node[at_leaf]])
            rows, node = rows[~at_leaf], node[~at_leaf]
            visual = dim[node] < 0
            seen_rows, seen_nodes = rows[visual], node[visual]
            both_rows, both_nodes = rows[~visual], node[~visual]
            followed = child[seen_nodes, bits[seen_rows, feature[seen_nodes]] * 1]
            rows = np.concatenate([seen_rows, both_rows, both_rows])
            node = np.concatenate([followed, child[both_nodes, 0], child[both_nodes, 1]])
        rows, classes = np.concatenate(found_rows), np.concatenate(found_classes)
        order = np.lexsort((classes, rows))
        return torch.as_tensor(rows[order]), torch.as_tensor(classes[order])

    def cells(
        self, presence: torch.Tensor | PackedPresence
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Perceptual cells: the percepts of a batch grouped by their compatible joint classes.

        Args:
            presence: (N, F) bool feature presence of N percepts.

        Returns:
            ``cells_of`` of the percepts' compatible classes.
        """
        return cells_of(*self.compatible(presence), len(presence), self.n_classes)

    def state_dict(self) -> dict:
        """Its settings and learned values as plain values and tensors (for ``save``)."""
        return {
            "n_features": self.n_features,
            "low": self.low.tolist(),
            "high": self.high.tolist(),
            "feature": list(self.feature),
            "dim": list(self.dim),
            "threshold": list(self.threshold),
            "no": list(self.no),
            "yes": list(self.yes),
            "leaf_class": list(self.leaf_class),
        }

    @classmethod
    def from_state_dict(cls, state: dict) -> JointTree:
        """The object that ``state_dict`` described."""
        tree = cls(state["n_features"], state["low"], state["high"])
        # Replay the splits in node order: node k's children are nodes made by its split.
        order = sorted(
            (n for n, c in enumerate(state["leaf_class"]) if c < 0), key=lambda n: state["no"][n]
        )
        class_at = {0: 0}
        for node in order:
            c = class_at[node]
            if state["dim"][node] >= 0:
                new = tree.split_action(c, state["dim"][node], state["threshold"][node])
            else:
                new = tree.split_feature(c, state["feature"][node])
            class_at[state["no"][node]], class_at[state["yes"][node]] = c, new
        if tree.leaf_class != list(state["leaf_class"]):
            raise ValueError("the saved joint tree is inconsistent (corrupt file)")
        return tree


def cells_of(
    rows: torch.Tensor, classes: torch.Tensor, n_rows: int, n_classes: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Group N percepts by their sets of compatible classes.

    Args:
        rows, classes: (K,) pairs "class ``classes[k]`` is compatible with percept
            ``rows[k]``", in any order, every percept in at least one.
        n_rows, n_classes: N and the number of classes J.

    Returns:
        cell (N,) long: each percept's cell, numbered 0..C-1; and the cells' members as pairs
        member_cell (K',), member_class (K',): class ``member_class[k]`` is compatible with
        cell ``member_cell[k]``.
    """
    # Two random 40-bit keys per class: a set's sums of keys identify it (a collision of both
    # sums between two distinct sets is out of reach at these sizes).
    keys = torch.from_numpy(np.random.default_rng(0).integers(0, 2**40, size=(n_classes, 2)))
    sums = torch.zeros(n_rows, 2, dtype=torch.long).index_add_(0, rows, keys[classes])
    _, cell = torch.unique(sums, dim=0, return_inverse=True)
    first_row = torch.full((int(cell.max()) + 1,), n_rows).scatter_reduce_(
        0, cell, torch.arange(n_rows), "amin"
    )
    member = rows == first_row[cell[rows]]
    return cell, cell[rows[member]], classes[member]
