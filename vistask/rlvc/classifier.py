"""Image -> visual class (the vocabulary, the learned compounds and the class structure), and
image -> compatible joint classes (the vocabulary and the joint tree of RLJC)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from vistask.checks import checked
from vistask.features import Compound, VisualFeatureExtractor, check_image
from vistask.rlvc.bdd import ClassBDD
from vistask.rlvc.joint_tree import JointTree
from vistask.rlvc.seen import SeenPercepts, classify
from vistask.rlvc.tree import ClassTree
from vistask.saving import load_state, save_state


@checked
class VisualClassifier:
    """Image -> visual class: a feature extractor, the compounds learned on its vocabulary, and
    the class structure over both (a ``ClassTree`` or a ``ClassBDD``), with the percepts the
    classes were learned on if new percepts take the class of the nearest of them
    (``SeenPercepts``).

    Example:
        >>> classifier = VisualClassifier(extractor, structure, compounds)
        >>> classifier(image)          # int class of one (H, W, 3) uint8 image
        >>> classifier.classify(images)  # (N,) long
        >>> classifier.save("classes.pt"); VisualClassifier.load("classes.pt")
    """

    def __init__(
        self,
        extractor: VisualFeatureExtractor,
        structure: ClassTree | ClassBDD,
        compounds: Sequence[Compound] = (),
        seen: SeenPercepts | None = None,
    ) -> None:
        if structure.n_features != extractor.n_features + len(compounds):
            raise ValueError(
                f"the classes test {structure.n_features} features but the vocabulary has "
                f"{extractor.n_features} and {len(compounds)} compounds: they were not learned "
                "together"
            )
        self.extractor, self.structure, self.seen = extractor, structure, seen
        self.compounds = list(compounds)

    @property
    def n_classes(self) -> int:
        """Number of classes."""
        return self.structure.n_classes

    def classify(self, images: list[np.ndarray]) -> torch.Tensor:
        """(N,) visual classes of a list of images."""
        presence = self.extractor.presence(images, self.compounds)
        return classify(self.structure, self.seen, presence)

    def __call__(self, image: np.ndarray) -> int:
        """The visual class of one image (or, for joint classes, its mask)."""
        return int(self.classify([check_image(image)])[0])

    def state_dict(self) -> dict:
        """Its settings and learned values as plain values and tensors (for ``save``)."""
        return {
            "extractor": self.extractor.state_dict(),
            "fingerprint": self.extractor.fingerprint,
            "compounds": [c.as_list() for c in self.compounds],
            "structure": self.structure.state_dict(),
            "kind": type(self.structure).__name__,
            "seen": None if self.seen is None else self.seen.state_dict(),
        }

    @classmethod
    def from_state_dict(
        cls, state: dict, extractor: VisualFeatureExtractor | None = None
    ) -> VisualClassifier:
        """Rebuild; with ``extractor`` given, check that it is the vocabulary the tree was
        learned on (a tree is meaningless on another vocabulary)."""
        if extractor is None:
            extractor = VisualFeatureExtractor.from_state_dict(state["extractor"])
        elif extractor.fingerprint != state["fingerprint"]:
            raise ValueError(
                f"vocabulary mismatch: the classes were learned on vocabulary "
                f"{state['fingerprint']}, got {extractor.fingerprint}"
            )
        compounds = [Compound.from_list(c) for c in state.get("compounds", [])]
        kinds = {"ClassTree": ClassTree, "ClassBDD": ClassBDD}
        structure = kinds[state["kind"]].from_state_dict(state["structure"])
        seen = state.get("seen")
        seen = None if seen is None else SeenPercepts.from_state_dict(seen)
        return cls(extractor, structure, compounds, seen)

    def save(self, path: str | Path) -> None:
        """Write it to ``path``; ``load`` reads it back."""
        save_state(path, "VisualClassifier", self.state_dict())

    @classmethod
    def load(cls, path: str | Path, extractor: VisualFeatureExtractor | None = None):
        """Read what ``save`` wrote to ``path``."""
        return cls.from_state_dict(load_state(path, "VisualClassifier"), extractor)


@checked
class JointClassifier:
    """Image -> the joint classes compatible with it (its perceptual cell), and the classes'
    action boxes: the discretisation that RLJC learned.

    Example:
        >>> classifier = JointClassifier(extractor, tree)     # a JointTree learned by RLJC
        >>> mask = classifier(image)            # (J,) bool, the compatible joint classes
        >>> classifier.box_low[mask], classifier.box_high[mask]   # their action boxes (k, m)
        >>> classifier.cells(images)            # (N,) cell ids, a batch at once
    """

    def __init__(self, extractor: VisualFeatureExtractor, structure: JointTree) -> None:
        if structure.n_features != extractor.n_features:
            raise ValueError(
                f"the joint classes test {structure.n_features} features but the vocabulary "
                f"has {extractor.n_features}: they were not learned together"
            )
        self.extractor, self.structure = extractor, structure

    @property
    def n_classes(self) -> int:
        """Number of classes."""
        return self.structure.n_classes

    @property
    def box_low(self) -> np.ndarray:
        """(J, m) lower corners of the joint classes' action boxes."""
        return self.structure.box_low

    @property
    def box_high(self) -> np.ndarray:
        """(J, m) upper corners of the joint classes' action boxes."""
        return self.structure.box_high

    def compatible(self, images: list[np.ndarray]) -> torch.Tensor:
        """(N, J) bool: the joint classes compatible with each image."""
        rows, classes = self.structure.compatible(self.extractor.presence(images))
        mask = torch.zeros(len(images), self.n_classes, dtype=torch.bool)
        mask[rows, classes] = True
        return mask

    def cells(self, images: list[np.ndarray]) -> torch.Tensor:
        """(N,) perceptual cell of each image, numbered within this batch."""
        return self.structure.cells(self.extractor.presence(images))[0]

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """The visual class of one image (or, for joint classes, its mask)."""
        return self.compatible([check_image(image)])[0].numpy()

    def state_dict(self) -> dict:
        """Its settings and learned values as plain values and tensors (for ``save``)."""
        return {
            "extractor": self.extractor.state_dict(),
            "structure": self.structure.state_dict(),
        }

    @classmethod
    def from_state_dict(cls, state: dict) -> JointClassifier:
        """The object that ``state_dict`` described."""
        return cls(
            VisualFeatureExtractor.from_state_dict(state["extractor"]),
            JointTree.from_state_dict(state["structure"]),
        )

    def save(self, path: str | Path) -> None:
        """Write it to ``path``; ``load`` reads it back."""
        save_state(path, "JointClassifier", self.state_dict())

    @classmethod
    def load(cls, path: str | Path) -> JointClassifier:
        """Read what ``save`` wrote to ``path``."""
        return cls.from_state_dict(load_state(path, "JointClassifier"))
