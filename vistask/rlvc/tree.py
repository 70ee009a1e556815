"""The class structure C_k: a binary decision tree over feature-presence tests.

Internal nodes test one visual feature; leaves are visual classes. Splitting a leaf keeps its
class id for the "feature absent" child and gives the "present" child a new id, so class ids
stay stable across stages (and Q values of untouched classes keep their meaning).
"""

from __future__ import annotations

import numpy as np
import torch

from vistask.checks import checked
from vistask.rlvc.presence import PackedPresence


@checked
class ClassTree:
    """Binary decision tree over feature presence; classifies batches in one vectorized call.

    Example:
        >>> tree = ClassTree(n_features=100)      # one class: everything aliased
        >>> tree.split(0, feature=7)              # class 0 -> {7 absent: 0, 7 present: 1}
        >>> tree.classify(presence)               # presence (N, 100) bool -> (N,) long

    Args:
        n_features: number of visual features F a presence vector holds.
    """

    def __init__(self, n_features: int) -> None:
        if n_features < 1:
            raise ValueError(f"n_features must be >= 1, got {n_features}")
        self.n_features = int(n_features)
        # Per node: tested feature (-1 at leaves), children, class id (-1 at internal nodes).
        self.feature: list[int] = [-1]
        self.absent: list[int] = [-1]
        self.present: list[int] = [-1]
        self.leaf_class: list[int] = [0]
        self._leaf_of_class: list[int] = [0]
        self._tables: dict[str | torch.device, tuple] = {}  # classify's node tables

    @property
    def n_classes(self) -> int:
        """Number of classes."""
        return len(self._leaf_of_class)

    @property
    def selected_features(self) -> list[int]:
        """Sorted distinct features tested somewhere in the tree."""
        return sorted({f for f in self.feature if f >= 0})

    @property
    def depth(self) -> int:
        """Length of the longest path from the root to a leaf."""
        depth = {0: 0}
        for node, f in enumerate(self.feature):
            if f >= 0:
                depth[self.absent[node]] = depth[self.present[node]] = depth[node] + 1
        return max(depth.values())

    def widen(self, n_features: int) -> None:
        """Presence vectors hold ``n_features`` features from now on (compounds were added)."""
        if n_features < self.n_features:
            raise ValueError(f"cannot narrow the tree from {self.n_features} to {n_features}")
        self.n_features = int(n_features)

    def split(self, class_id: int, feature: int) -> int:
        """Split a class on a feature; returns the id of the new ("present") class."""
        if not 0 <= class_id < self.n_classes:
            raise ValueError(f"no class {class_id} (tree has {self.n_classes})")
        if not 0 <= feature < self.n_features:
            raise ValueError(f"feature {feature} outside 0..{self.n_features - 1}")
        leaf, new_class = self._leaf_of_class[class_id], self.n_classes
        absent, present = len(self.feature), len(self.feature) + 1
        self.feature += [-1, -1]
        self.absent += [-1, -1]
        self.present += [-1, -1]
        self.leaf_class += [class_id, new_class]
        self.feature[leaf], self.absent[leaf], self.present[leaf] = feature, absent, present
        self.leaf_class[leaf] = -1
        self._leaf_of_class[class_id] = absent
        self._leaf_of_class.append(present)
        self._tables.clear()
        return new_class

    def splits(self) -> list[tuple[int, int]]:
        """The splits (class, feature) that made the tree, in order: ``ClassBDD.from_splits``
        rebuilds the same classes from them."""
        # A split appends its two children: internal nodes split in the order of their
        # children, and the class a node held is its "absent" descendants' leaf's class.
        internal = sorted((a, node) for node, a in enumerate(self.absent) if a >= 0)
        out = []
        for absent, node in internal:
            while self.feature[absent] >= 0:
                absent = self.absent[absent]
            out.append((self.leaf_class[absent], self.feature[node]))
        return out

    def classify(self, presence: torch.Tensor | PackedPresence) -> torch.Tensor:
        """(N, F) bool presence -> (N,) long class ids, all rows at once (one step per level)."""
        if presence.ndim != 2 or presence.shape[1] != self.n_features:
            raise ValueError(
                f"presence must be (N, {self.n_features}), got {tuple(presence.shape)}"
            )
        device = presence.device
        # The loop runs once per tree level (over 100 after a few databases): on the CPU,
        # numpy's fancy indexing costs about a microsecond a call against torch's ten.
        backend = "numpy" if device.type == "cpu" else device
        if backend not in self._tables:
            internal = np.array(self.feature) >= 0
            nodes = np.arange(len(self.feature))
            # A leaf is its own child on both sides, so rows that reach it early stay put.
            child = np.stack(
                [np.where(internal, self.absent, nodes), np.where(internal, self.present, nodes)], 1
            )
            tables = (np.maximum(self.feature, 0), child, np.array(self.leaf_class))
            if backend != "numpy":
                tables = tuple(torch.from_numpy(t).to(device) for t in tables)
            self._tables[backend] = (*tables, self.depth)
        feature, child, leaf_class, depth = self._tables[backend]
        if backend == "numpy":
            bits, rows = presence.numpy(), np.arange(len(presence))
        else:
            bits, rows = presence, torch.arange(len(presence), device=device)
        node = rows * 0
        for _ in range(depth):
            node = child[node, bits[rows, feature[node]] * 1]
        return torch.as_tensor(leaf_class[node], device=device)

    def state_dict(self) -> dict:
        """Its settings and learned values as plain values and tensors (for ``save``)."""
        return {
            "n_features": self.n_features,
            "feature": list(self.feature),
            "absent": list(self.absent),
            "present": list(self.present),
            "leaf_class": list(self.leaf_class),
        }

    @classmethod
    def from_state_dict(cls, state: dict) -> ClassTree:
        """The object that ``state_dict`` described."""
        tree = cls(state["n_features"])
        tree.feature, tree.absent = list(state["feature"]), list(state["absent"])
        tree.present, tree.leaf_class = list(state["present"]), list(state["leaf_class"])
        tree._tables.clear()
        leaves = {c: node for node, c in enumerate(tree.leaf_class) if c >= 0}
        tree._leaf_of_class = [leaves[c] for c in range(len(leaves))]
        return tree
