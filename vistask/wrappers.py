"""Gymnasium observation wrappers: image -> visual features, image -> visual class, image ->
compatible joint classes."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Protocol

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from vistask.checks import checked
from vistask.features import Compound, VisualFeatureExtractor, check_image_space

if TYPE_CHECKING:
    from vistask.rlvc import JointClassifier


class Classifier(Protocol):
    """Anything that maps one image to a class id in ``range(n_classes)``."""

    n_classes: int

    def __call__(self, image: np.ndarray) -> int:
        """The class id of one image."""


@checked
class VisualFeatures(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Image observation -> ``MultiBinary(F + C)`` presence vector of the F visual features
    (words) and of C compound features.

    Example:
        >>> env = gym.make("vistask/VisualMountainCar-v0")
        >>> agent = RLVCAgent.load("car.pt")
        >>> env = VisualFeatures(env, agent.extractor, agent.rlvc.compounds)
        >>> obs, info = env.reset(seed=0)   # (F + C,) int8 0/1, words then compounds

    Args:
        env: environment with (H, W, 3) uint8 image observations.
        extractor: the visual feature extractor (vocabulary).
        compounds: compounds learned on this extractor's words (``RLVC.compounds``).
    """

    def __init__(
        self,
        env: gym.Env,
        extractor: VisualFeatureExtractor,
        compounds: Sequence[Compound] = (),
    ) -> None:
        check_image_space(env.observation_space, "VisualFeatures")
        extractor.check_env(env, "VisualFeatures")
        gym.utils.RecordConstructorArgs.__init__(self, extractor=extractor, compounds=compounds)
        gym.ObservationWrapper.__init__(self, env)
        self.extractor = extractor
        self.compounds = list(compounds)
        self.observation_space = spaces.MultiBinary(extractor.n_features + len(self.compounds))

    def observation(self, observation: np.ndarray) -> np.ndarray:
        """(F + C,) int8 presence of the words, then of the compounds, in the image."""
        return self.extractor.presence([observation], self.compounds)[0].numpy().astype(np.int8)


@checked
class VisualClasses(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Image observation -> ``Discrete(m)`` visual class, e.g. learned by RLVC.

    Example:
        >>> agent = RLVCAgent.load("rlvc.pt")
        >>> env = VisualClasses(gym.make("vistask/VisualMaze-v0"), agent.classifier)
        >>> obs, info = env.reset(seed=0)   # an int in range(agent.classifier.n_classes)

    Args:
        env: environment with (H, W, 3) uint8 image observations.
        classifier: maps an image to a class id, with attribute ``n_classes``
            (``vistask.rlvc.VisualClassifier``).
    """

    def __init__(self, env: gym.Env, classifier: Classifier) -> None:
        if not (callable(classifier) and hasattr(classifier, "n_classes")):
            raise TypeError(
                f"classifier must map an image to a class and have n_classes (an agent's "
                f".classifier), got {classifier!r}"
            )
        check_image_space(env.observation_space, "VisualClasses")
        if hasattr(classifier, "extractor"):  # a classifier of vistask's
            classifier.extractor.check_env(env, "VisualClasses")
        gym.utils.RecordConstructorArgs.__init__(self, classifier=classifier)
        gym.ObservationWrapper.__init__(self, env)
        self.classifier = classifier
        self.observation_space = spaces.Discrete(classifier.n_classes)

    def observation(self, observation: np.ndarray) -> int:
        """The visual class of the image."""
        return int(self.classifier(observation))


@checked
class JointClasses(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Image observation -> ``MultiBinary(J)``: the joint classes that RLJC learned which are
    compatible with the image (its perceptual cell). Each joint class carries a box of actions
    (``box_low``, ``box_high``, (J, m)), so another learner can pick among the boxes of the
    cell, RLJC's discretisation of the percepts and the actions.

    Example:
        >>> agent = RLJCAgent.load("rljc.pt")
        >>> env = JointClasses(gym.make("vistask/VisualMazeContinuous-v0"), agent.classifier)
        >>> mask, info = env.reset(seed=0)           # (J,) int8 0/1
        >>> boxes = env.box_low[mask == 1], env.box_high[mask == 1]

    Args:
        env: environment with (H, W, 3) uint8 image observations and the ``Box`` actions the
            classes were learned on.
        classifier: a ``vistask.rlvc.JointClassifier``.
    """

    def __init__(self, env: gym.Env, classifier: JointClassifier) -> None:
        check_image_space(env.observation_space, "JointClasses")
        classifier.extractor.check_env(env, "JointClasses")
        space = env.action_space
        if not isinstance(space, spaces.Box) or space.shape != (classifier.box_low.shape[1],):
            raise TypeError(
                f"the joint classes hold boxes of {classifier.box_low.shape[1]}-D actions; the "
                f"env's actions are {space}"
            )
        low, high = np.asarray(classifier.box_low).min(0), np.asarray(classifier.box_high).max(0)
        if not (np.allclose(space.low, low) and np.allclose(space.high, high)):
            raise ValueError(
                f"the joint classes' boxes cover actions from {low} to {high}; the env's "
                f"actions are {space}"
            )
        gym.utils.RecordConstructorArgs.__init__(self, classifier=classifier)
        gym.ObservationWrapper.__init__(self, env)
        self.classifier = classifier
        self.box_low, self.box_high = classifier.box_low, classifier.box_high
        self.observation_space = spaces.MultiBinary(classifier.n_classes)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        """(K,) int8 mask of the joint classes compatible with the image."""
        return self.classifier(observation).astype(np.int8)
