"""Gymnasium observation wrappers: image -> visual features, image -> visual class."""

from __future__ import annotations

from typing import Protocol

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from vistask.features import VisualFeatureExtractor, check_image_space


class Classifier(Protocol):
    """Anything that maps one image to a class id in ``range(n_classes)``."""

    n_classes: int

    def __call__(self, image: np.ndarray) -> int: ...


class VisualFeatures(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Image observation -> ``MultiBinary(F)`` presence vector of the F visual features.

    Example:
        >>> env = gym.make("vistask/VisualMaze-v0")
        >>> env = VisualFeatures(env, VisualFeatureExtractor.load("vocab.pt"))
        >>> obs, info = env.reset(seed=0)   # (F,) int8 0/1

    Args:
        env: environment with (H, W, 3) uint8 image observations.
        extractor: the visual feature extractor (vocabulary).
    """

    def __init__(self, env: gym.Env, extractor: VisualFeatureExtractor) -> None:
        check_image_space(env.observation_space, "VisualFeatures")
        gym.utils.RecordConstructorArgs.__init__(self, extractor=extractor)
        gym.ObservationWrapper.__init__(self, env)
        self.extractor = extractor
        self.observation_space = spaces.MultiBinary(extractor.n_features)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return self.extractor(observation)


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
        check_image_space(env.observation_space, "VisualClasses")
        gym.utils.RecordConstructorArgs.__init__(self, classifier=classifier)
        gym.ObservationWrapper.__init__(self, env)
        self.classifier = classifier
        self.observation_space = spaces.Discrete(classifier.n_classes)

    def observation(self, observation: np.ndarray) -> int:
        return int(self.classifier(observation))
