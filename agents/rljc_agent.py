"""RLJCAgent: RLJC on any Gymnasium image environment with continuous actions, SB3's API."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from vistask.agents.visual_agent import MAX_BLOCKED, VisualAgent
from vistask.checks import checked
from vistask.rlvc import RLJC, JointClassifier


@checked
class RLJCAgent(VisualAgent):
    """Learns joint classes of percepts and continuous actions by RLJC (paper 2.5.3).

    One decision tree splits the joint space of percepts and actions: a node tests a visual
    feature or "action component i >= t". The joint classes compatible with a percept each
    carry a box of actions; the agent acts at the centre of the box of highest Q.

    ``learn(total_timesteps)`` collects ``databases`` equal databases of interactions: the
    first with uniformly random actions, each later one on the classes learned so far, drawing
    an action uniformly inside the best box (with probability ``epsilon`` inside any compatible
    box); each database joins the earlier ones. After each database, RLJC stages run until no
    joint class splits. SIFT keypoints of every percept are matched to a vocabulary of
    ``n_words`` visual features fitted on the first database; a class is split where a feature
    or an action threshold (a midpoint between the actions seen in the class) reduces the
    variance of the TD errors significantly. Callbacks, ``tensorboard_log`` (``rljc/classes``,
    ``rljc/selected_features``, ``rljc/mean_abs_td``, ``rljc/splits``) and a second ``learn``
    call behave as in ``RLVCAgent``.

    Example:
        >>> import gymnasium as gym, vistask.envs
        >>> env = gym.make("vistask/VisualMazeContinuous-v0")
        >>> agent = RLJCAgent(env, seed=0).learn(total_timesteps=60_000)
        >>> action, _ = agent.predict(obs)        # (1,) float32 angle for one image
        >>> agent.save("rljc.pt"); agent = RLJCAgent.load("rljc.pt", env=env)

    Args:
        env: env with (H, W, 3) or (H, W) uint8 image observations and a bounded ``Box``
            action space of shape (m,) (``None`` only when loading).
        n_words: visual features: words of the SIFT vocabulary (>= 2, default 8192).
        databases: equal databases that ``total_timesteps`` is split into (>= 1, default 3).
        alpha: significance level of the Welch t-test that accepts a split (in (0, 1),
            default 0.05).
        min_count: interactions needed on each side of a split (>= 2, default 10).
        max_stages: stage cap of the stages that follow each database (>= 1, default 300).
        epsilon: share of exploring draws inside a random compatible box, in the later
            databases and in ``predict(deterministic=False)`` (in [0, 1], default 0.1).
        n_envs: episodes collected side by side on the classes, on copies of the env made
            again by ``gym.make`` from its spec (settings changed after ``gym.make`` do
            not reach them) or deep-copied (>= 1, default 128).
        max_blocked: an exploring episode (databases after the first) also ends after this
            many steps in a row that leave the view unchanged, so that a policy stuck against
            a wall does not fill the database (0: only where the env ends it, for envs whose
            view can stay the same while their state changes, such as a wait action or a
            blank stretch; >= 0, default 2).
        max_keypoints: strongest SIFT keypoints kept per percept (0: all; default 24).
        contrast_threshold: SIFT's detection threshold (> 0, default 0.02; lower: more,
            weaker keypoints).
        enlarge: SIFT runs on each view enlarged this many times, keeping the keypoints whose
            descriptor lies inside the view (``SiftExtractor``'s ``enlarge``; >= 1), or
            ``"auto"`` (the default): 2 where the views are under 56 pixels on a side and
            keep at least as many keypoints enlarged (``choose_enlarge``, on the first
            database's views), else 1.
        gamma: discount in [0, 1) (default: the env's ``gamma`` attribute, else 0.99).
        tensorboard_log: folder of TensorBoard runs (None, the default: no logging).
        seed: seeds the episodes, the exploration and the vocabulary (default 0).
    """

    continuous = True
    learner_class = RLJC

    def __init__(
        self,
        env: gym.Env | None,
        n_words: int = 8192,
        databases: int = 3,
        alpha: float = 0.05,
        min_count: int = 10,
        max_stages: int = 300,
        epsilon: float = 0.1,
        n_envs: int = 128,
        max_blocked: int = MAX_BLOCKED,
        max_keypoints: int = 24,
        contrast_threshold: float = 0.02,
        enlarge: int | str = "auto",
        gamma: float | None = None,
        tensorboard_log: str | Path | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__(
            env,
            n_words,
            databases,
            alpha,
            min_count,
            max_stages,
            epsilon,
            n_envs,
            max_keypoints,
            contrast_threshold,
            gamma,
            tensorboard_log,
            seed,
            max_blocked,
            enlarge,
        )

    @property
    def rljc(self) -> RLJC | None:
        """The learner: joint classes, Q, stage history."""
        return self.learner

    def _new_learner(self) -> RLJC:
        space = self.action_space
        return RLJC(
            self.extractor.n_features,
            space.low.tolist(),
            space.high.tolist(),
            self.gamma,
            self.alpha,
            self.split_count,
        )

    def _greedy(self, presence: torch.Tensor) -> np.ndarray:
        return self.rljc.greedy(presence)

    def _explore(self, presence: torch.Tensor, rng: np.random.Generator) -> np.ndarray:
        return self.rljc.explore(presence, self.epsilon, rng)

    @property
    def classifier(self) -> JointClassifier:
        """Image -> compatible joint classes and their boxes (``vistask.wrappers.JointClasses``)."""
        self._check_learned()
        return JointClassifier(self.extractor, self.rljc.structure)
