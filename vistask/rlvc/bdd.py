"""The class structure as a reduced ordered BDD (paper section 2.5.2).

Each visual class is a Boolean function of feature tests held in one shared BDD manager of
the ``dd`` package (CUDD through ``dd.cudd``; the pure-Python ``dd.autoref`` where the CUDD
extension is missing). A split conjoins a feature test to a class, as in the tree; a merge
makes a class the disjunction of several, which a tree cannot express. Variables are the
features, named ``f<i>`` and declared when first tested, in that order. A feature no class
depends on drops out of every class's support, and ``simplify`` drops the features that the
percepts seen so far do not need (the classes are free to differ on feature combinations never
seen: the cofactor "feature absent" replaces every class). Dynamic reordering is off: the
support of a class does not depend on the order, and sifting took minutes a stage on the maze.

Classification runs on a compiled form of the same partition: a decision tree over the same
tests whose leaves map to classes (a merge relabels leaves, a split splits every leaf of the
class, a dropped feature's nodes are bypassed by their "absent" branch). It classifies a batch
in one vectorized walk; compiling the classes to one multi-terminal diagram instead grew
exponentially with the merges on the maze. Splitting a merged class splits all its leaves,
so periodic compaction (``RLVC(compact_every=...)``) multiplies the leaves of classes that
merge and split again: on the maze it slows stages down within 150 stages.
"""

from __future__ import annotations

import numpy as np
import torch

from vistask.rlvc.tree import ClassTree

try:
    from dd import cudd as _dd
except ImportError:  # pragma: no cover - wheels without the CUDD extension
    from dd import autoref as _dd


def _name(feature: int) -> str:
    return f"f{feature}"


class ClassBDD:
    """Visual classes as disjoint Boolean functions of feature presence, in a shared BDD.

    Example:
        >>> classes = ClassBDD(n_features=100)   # one class: everything aliased
        >>> classes.split(0, feature=7)          # class 0 -> {7 absent: 0, 7 present: 1}
        >>> classes.split(0, feature=3)          # {7, 3 absent: 0, 3 present: 2}
        >>> classes.merge(torch.tensor([0, 1, 1]))   # classes 1 and 2 become class 1
        >>> classes.classify(presence)           # presence (N, 100) bool -> (N,) long

    Args:
        n_features: number of visual features F a presence vector holds.
    """

    def __init__(self, n_features: int) -> None:
        if n_features < 1:
            raise ValueError(f"n_features must be >= 1, got {n_features}")
        self.bdd = _dd.BDD()
        self.bdd.configure(reordering=False)
        self.functions = [self.bdd.true]
        self.leaves = ClassTree(n_features)  # the compiled classifier; its classes are leaves
        self.class_of_leaf = np.zeros(1, dtype=np.int64)
        self._selected: set[int] = set()

    @property
    def n_features(self) -> int:
        return self.leaves.n_features

    @property
    def n_classes(self) -> int:
        return len(self.functions)

    @property
    def selected_features(self) -> list[int]:
        """Sorted distinct features that some class depends on."""
        return sorted(self._selected)

    def _update_selected(self) -> None:
        self._selected = {int(name[1:]) for u in self.functions for name in self.bdd.support(u)}

    def widen(self, n_features: int) -> None:
        """Presence vectors hold ``n_features`` features from now on (compounds were added)."""
        self.leaves.widen(n_features)

    def _var(self, feature: int):
        if not 0 <= feature < self.n_features:
            raise ValueError(f"feature {feature} outside 0..{self.n_features - 1}")
        name = _name(feature)
        if name not in self.bdd.vars:
            self.bdd.declare(name)
        return self.bdd.var(name)

    def split(self, class_id: int, feature: int) -> int:
        """Split a class on a feature; returns the id of the new ("present") class."""
        if not 0 <= class_id < self.n_classes:
            raise ValueError(f"no class {class_id} (there are {self.n_classes})")
        test, function = self._var(feature), self.functions[class_id]
        self.functions[class_id] = function & ~test
        self.functions.append(function & test)
        new_class = self.n_classes - 1
        leaves = np.flatnonzero(self.class_of_leaf == class_id)
        for leaf in leaves.tolist():
            self.leaves.split(leaf, feature)
        self.class_of_leaf = np.concatenate([self.class_of_leaf, np.full(len(leaves), new_class)])
        self._selected.add(feature)
        return new_class

    def merge(self, groups: torch.Tensor) -> None:
        """Class c becomes part of class ``groups[c]``; groups (S,) long numbered 0..G-1."""
        groups = torch.as_tensor(groups).long()
        if groups.shape != (self.n_classes,):
            raise ValueError(f"groups must be ({self.n_classes},), got {tuple(groups.shape)}")
        n_groups = int(groups.max()) + 1
        if set(groups.tolist()) != set(range(n_groups)):
            raise ValueError("groups must number the merged classes 0..G-1 without gaps")
        merged = [self.bdd.false] * n_groups
        for function, g in zip(self.functions, groups.tolist(), strict=True):
            merged[g] = merged[g] | function
        self.functions = merged
        self.class_of_leaf = groups.numpy()[self.class_of_leaf]
        self._update_selected()

    def simplify(self, presence: torch.Tensor, allowed: torch.Tensor | None = None) -> list[int]:
        """Drop every feature whose absence moves none of these percepts out of its class, or
        only into classes ``allowed`` for it.

        Features are tried from the rarest up; a dropped feature's test is replaced by its
        "absent" branch in every class. Returns the dropped features.

        Args:
            presence: (N, F) bool presence of the percepts that must stay where they are.
            allowed: (S, S) bool, True where a percept of class i may move to class j (None:
                nowhere else).
        """
        bits = presence.cpu().numpy().copy()
        classes = self._class_ids(bits)
        allowed = np.eye(self.n_classes, dtype=bool) if allowed is None else allowed.numpy()
        dropped = []
        counts = bits.sum(axis=0)
        for feature in sorted(self._selected, key=lambda f: counts[f]):
            rows = bits[:, feature].nonzero()[0]
            changed = bits[rows]
            changed[:, feature] = False
            # Classifying with the dropped columns zeroed is classifying with the cofactors.
            if allowed[classes[rows], self._class_ids(changed)].all():
                bits[rows, feature] = False
                dropped.append(feature)
        if dropped:
            absent = {_name(f): False for f in dropped}
            self.functions = [self.bdd.let(absent, u) for u in self.functions]
            self.leaves.bypass(dropped)
            self._update_selected()
        return dropped

    def classify(self, presence: torch.Tensor) -> torch.Tensor:
        """(N, F) bool presence -> (N,) long class ids, all rows at once."""
        leaves = self.leaves.classify(presence)
        return torch.from_numpy(self.class_of_leaf).to(presence.device)[leaves]

    def _class_ids(self, bits: np.ndarray) -> np.ndarray:
        return self.classify(torch.from_numpy(bits)).numpy()

    def state_dict(self) -> dict:
        return {"leaves": self.leaves.state_dict(), "class_of_leaf": self.class_of_leaf.tolist()}

    @classmethod
    def from_state_dict(cls, state: dict) -> ClassBDD:
        """Rebuild; each class's function is the disjunction of its leaves' paths."""
        leaves = ClassTree.from_state_dict(state["leaves"])
        classes = cls(leaves.n_features)
        classes.leaves = leaves
        classes.class_of_leaf = np.array(state["class_of_leaf"], dtype=np.int64)
        bdd = classes.bdd
        functions = [bdd.false] * (int(classes.class_of_leaf.max()) + 1)
        paths = {0: bdd.true}
        for node, feature in enumerate(leaves.feature):  # parents come before children
            if node not in paths:
                continue  # below a bypassed test
            if feature >= 0:
                test = classes._var(feature)
                paths[leaves.absent[node]] = paths[node] & ~test
                paths[leaves.present[node]] = paths[node] & test
            else:
                c = classes.class_of_leaf[leaves.leaf_class[node]]
                functions[c] = functions[c] | paths[node]
        classes.functions = functions
        classes._update_selected()
        return classes


__all__ = ["ClassBDD"]
