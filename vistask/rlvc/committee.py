"""Acting on several class structures at once: the mean of their Q at each percept.

One RLVC structure's classes hang on which of its splits happen to pass their tests first; a
structure learned on a bootstrap sample of the same interactions errs in other places.
``RLVC.fuse`` fuses such structures into one partition of the percepts it learned on, and keeps
them as a ``Committee`` to act: every structure classes a percept by its own tests, and the
action is the best of the mean of their classes' Q. A new percept thus never hangs on one
tree's path, as it does in the fused partition's tree.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from vistask.checks import checked
from vistask.rlvc.bdd import ClassBDD
from vistask.rlvc.presence import PackedPresence


@checked
@dataclass
class Committee:
    """Class structures and their classes' Q, acting on the mean of their Q.

    Example:
        >>> committee = Committee.of([structure_a, structure_b], [q_a, q_b])
        >>> classes = committee.classify(presence)   # (N, F) bool -> (N, 2) long
        >>> committee.mean_q(classes)                # (N, A) mean Q
        >>> committee.greedy(presence)               # (N,) long

    Attributes:
        structures: the class structures, as their history (``ClassBDD`` outside the BDD:
            classifying needs no BDD, and keeping one per structure costs CUDD's memory).
        q: (S_k, A) float64 Q of each structure's classes.
    """

    structures: list[ClassBDD]
    q: list[torch.Tensor]

    @classmethod
    def of(cls, structures: Sequence[ClassBDD], q: Sequence[torch.Tensor]) -> Committee:
        """A committee of ``structures`` (kept as their history) and their classes' ``q``."""
        if not structures or len(structures) != len(q):
            raise ValueError(
                f"need one Q per structure and at least one, got {len(structures)} structures "
                f"and {len(q)} Q"
            )
        for structure, values in zip(structures, q, strict=True):
            if values.ndim != 2 or len(values) != structure.n_classes:
                raise ValueError(
                    f"Q must be (classes, actions) = ({structure.n_classes}, A), got "
                    f"{tuple(values.shape)}"
                )
        return cls([history_only(s) for s in structures], [v.double() for v in q])

    def classify(self, presence: torch.Tensor | PackedPresence) -> torch.Tensor:
        """(N, K) the class that each of the K structures puts each percept in (``presence``
        (N, F) bool)."""
        return torch.stack([s.classify(presence) for s in self.structures], 1)

    def mean_q(self, classes: torch.Tensor) -> torch.Tensor:
        """(N, A) mean over the structures of their Q of ``classes`` (N, K), ``classify``'s."""
        return sum(q[classes[:, k]] for k, q in enumerate(self.q)) / len(self.q)

    def greedy(self, presence: torch.Tensor | PackedPresence) -> torch.Tensor:
        """(N,) the action of best mean Q of each percept (``presence`` (N, F) bool)."""
        return self.mean_q(self.classify(presence)).argmax(dim=1)

    def state_dict(self) -> dict:
        """Its settings and learned values as plain values and tensors (for ``save``)."""
        return {"structures": [s.state_dict() for s in self.structures], "q": self.q}

    @classmethod
    def from_state_dict(cls, state: dict) -> Committee:
        """The object that ``state_dict`` described."""
        structures = [ClassBDD.from_state_dict(s) for s in state["structures"]]
        return cls(structures, list(state["q"]))


def history_only(structure: ClassBDD) -> ClassBDD:
    """A copy of ``structure`` that holds its classes as their history alone."""
    return ClassBDD.from_state_dict({**structure.state_dict(), "in_bdd": False})


__all__ = ["Committee"]
