"""New percepts take the class of the nearest percept seen while learning.

A class structure sends a percept down a path of feature tests, so one feature that a new
percept shows or lacks by chance (a keypoint just among the strongest or not, a needle's tip at
the edge of a compound's band) sends it down another branch, into a class learned for other
states. ``SeenPercepts`` keeps the tested features of the percepts that the classes were
learned on, and gives a percept the class of the seen percept it differs from in the fewest
tested features (Hamming distance); where the nearest seen percepts are in several classes, the
class that most of them are in. A percept whose tested features equal a seen one's keeps the
structure's class.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch

from vistask.checks import checked
from vistask.rlvc.bdd import ClassBDD
from vistask.rlvc.presence import PackedPresence, distinct_rows
from vistask.rlvc.tree import ClassTree

MAX_DISTANCES = 2**24  # distances held at once (64 MiB of float32)


@checked
@dataclass
class SeenPercepts:
    """The distinct patterns of tested features among the percepts seen, and their classes.

    Example:
        >>> seen = SeenPercepts.of(structure, db.presence)   # (M, F) bool, the percepts seen
        >>> classify(structure, seen, presence)              # (N,) long, new percepts

    Attributes:
        features: (T,) long, the features that the structure tests.
        patterns: (U, T) sparse 0/1 rows, the distinct patterns of those features seen.
        classes: (U,) long, each pattern's class.
        counts: (U,) long, the percepts seen with each pattern.
    """

    features: torch.Tensor
    patterns: sp.csr_matrix
    classes: torch.Tensor
    counts: torch.Tensor

    @classmethod
    def of(
        cls,
        structure: ClassTree | ClassBDD,
        presence: torch.Tensor | PackedPresence,
        counts: torch.Tensor | None = None,
    ) -> SeenPercepts:
        """The seen patterns of ``presence`` (M, F) bool, met ``counts`` (M,) times each
        (None: once), classified by ``structure``."""
        features = torch.as_tensor(structure.selected_features, dtype=torch.long)
        bits, first, inverse, counts = distinct_rows(presence, features, counts)  # rows in order
        classes = structure.classify(presence)
        first, inverse = torch.from_numpy(first), torch.from_numpy(inverse)
        if not torch.equal(classes, classes[first][inverse]):
            raise ValueError("the structure's classes depend on features it does not list")
        patterns = np.unpackbits(bits, axis=1, count=len(features))
        patterns = sp.csr_matrix(patterns, dtype=np.float32)
        return cls(features, patterns, classes[first], torch.from_numpy(counts))

    def nearest(self, presence: torch.Tensor | PackedPresence) -> torch.Tensor:
        """(N,) the class that most of the nearest seen percepts of each percept are in
        (``presence`` (N, F) bool; ties: the lowest class id)."""
        ones = np.asarray(self.patterns.sum(axis=1)).ravel()  # (U,)
        classes, counts = self.classes.numpy(), self.counts.numpy()
        out = torch.empty(len(presence), dtype=torch.long)
        chunk = max(1, MAX_DISTANCES // len(ones))
        for start in range(0, len(presence), chunk):
            rows = presence[start : start + chunk, self.features].numpy().astype(np.float32)
            # Hamming distance of 0/1 rows: |a| + |b| - 2 a.b, one sparse product for a chunk.
            distance = ones[:, None] + rows.sum(axis=1)[None, :] - 2 * (self.patterns @ rows.T)
            pattern, row = np.nonzero(distance == distance.min(axis=0, keepdims=True))
            votes = np.zeros((len(rows), int(classes.max()) + 1))
            np.add.at(votes, (row, classes[pattern]), counts[pattern])
            out[start : start + len(rows)] = torch.from_numpy(votes.argmax(axis=1))
        return out

    def state_dict(self) -> dict:
        """Its settings and learned values as plain values and tensors (for ``save``)."""
        return {
            "features": self.features,
            "indptr": torch.from_numpy(self.patterns.indptr.astype(np.int64)),
            "indices": torch.from_numpy(self.patterns.indices.astype(np.int32)),
            "classes": self.classes,
            "counts": self.counts,
        }

    @classmethod
    def from_state_dict(cls, state: dict) -> SeenPercepts:
        """The object that ``state_dict`` described."""
        indptr, indices = state["indptr"].numpy(), state["indices"].numpy()
        shape = (len(indptr) - 1, len(state["features"]))
        ones = np.ones(len(indices), np.float32)
        patterns = sp.csr_matrix((ones, indices, indptr), shape)
        return cls(state["features"], patterns, state["classes"], state["counts"])


def classify(
    structure: ClassTree | ClassBDD,
    seen: SeenPercepts | None,
    presence: torch.Tensor | PackedPresence,
) -> torch.Tensor:
    """(N,) classes of ``presence`` (N, F) bool: the structure's, or with ``seen`` the
    nearest seen percepts' (``SeenPercepts.nearest``)."""
    return structure.classify(presence) if seen is None else seen.nearest(presence)
