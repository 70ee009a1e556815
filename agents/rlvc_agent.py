"""RLVCAgent: RLVC on a Gymnasium image environment, with an SB3-like API."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from vistask.features import SiftExtractor, VisualFeatureExtractor, check_image
from vistask.rlvc import (
    RLVC,
    InteractionDatabase,
    StageRecord,
    VisualClassifier,
    check_image_env,
    collect,
)


class RLVCAgent:
    """Collects interactions, learns a feature vocabulary and visual classes, acts greedily.

    ``learn`` runs, top to bottom: collect a database with the exploration policy, extract
    keypoints of every percept once, fit the vocabulary (first database only), build the
    interaction database, run RLVC stages; with ``database_size`` it splits the budget into
    databases of that size, each collected epsilon-greedily on the current classes (the first
    at random) and used for ``refresh_every`` stages.

    Example:
        >>> env = gym.make("vistask/VisualMaze-v0")
        >>> agent = RLVCAgent(env, seed=0).learn(total_timesteps=10_000)
        >>> action, _ = agent.predict(obs)            # obs: (H, W, 3) uint8 image
        >>> agent.save("rlvc.pt"); RLVCAgent.load("rlvc.pt", env)

    Args:
        env: environment with (H, W, 3) uint8 images and Discrete actions.
        n_words: vocabulary size F.
        alpha: significance level of the split t-tests.
        min_count: minimum interactions on each side of a split.
        bonferroni: correct alpha for the number of candidate features (see ``find_splits``).
        max_stages: stage cap.
        max_episode_steps: exploration episodes are cut after this many steps.
        database_size: interactions per database (None: one database of the whole budget).
        refresh_every: stages run on each database when ``database_size`` is set.
        epsilon: exploration rate when collecting on the current classes (refreshed databases).
        gamma: discount (default ``env.unwrapped.gamma``, else 0.99).
        keypoints: descriptor extractor (default ``SiftExtractor()``).
        soft_ratio: soft vocabulary assignment (see ``VisualFeatureExtractor``).
        seed: seeds collection and the vocabulary.
    """

    def __init__(
        self,
        env: gym.Env | None,
        n_words: int = 8192,
        alpha: float = 0.05,
        min_count: int = 10,
        bonferroni: bool = False,
        max_stages: int = 300,
        max_episode_steps: int = 50,
        database_size: int | None = None,
        refresh_every: int = 20,
        epsilon: float = 0.2,
        gamma: float | None = None,
        keypoints: SiftExtractor | None = None,
        soft_ratio: float = 1.0,
        seed: int = 0,
    ) -> None:
        if env is not None:
            check_image_env(env)
            gamma = gamma if gamma is not None else getattr(env.unwrapped, "gamma", 0.99)
        self.env = env
        self.n_words, self.alpha, self.min_count, self.bonferroni = (
            n_words,
            alpha,
            min_count,
            bonferroni,
        )
        self.max_stages, self.max_episode_steps = max_stages, max_episode_steps
        self.database_size, self.refresh_every = database_size, refresh_every
        self.epsilon, self.seed = epsilon, seed
        self.gamma = 0.99 if gamma is None else float(gamma)
        self.keypoints = keypoints or SiftExtractor()
        self.soft_ratio = soft_ratio
        self.extractor: VisualFeatureExtractor | None = None
        self.rlvc: RLVC | None = None
        self.num_timesteps = 0
        self.timing = {"collect": 0.0, "extract": 0.0, "vocabulary": 0.0}

    # -- learning ---------------------------------------------------------------------------
    def learn(
        self,
        total_timesteps: int,
        evaluate: Callable[[RLVCAgent], float] | None = None,
        eval_every: int = 5,
        progress_bar: bool = True,
        on_stage: Callable[[StageRecord], None] | None = None,
    ) -> RLVCAgent:
        """Learn visual classes from ``total_timesteps`` environment interactions.

        Args:
            total_timesteps: interactions in all (one database, or split evenly over the
                refreshed databases).
            evaluate: optional ``evaluate(agent) -> return`` of the greedy policy, logged every
                ``eval_every`` stages.
            progress_bar: show progress bars.
            on_stage: called with every stage's record (TensorBoard logging).
        """
        if self.env is None:
            raise ValueError("this agent has no env: pass one to RLVCAgent.load(path, env)")
        if total_timesteps < 1:
            raise ValueError(f"total_timesteps must be >= 1, got {total_timesteps}")
        per_round = self.database_size or total_timesteps
        rounds = max(1, total_timesteps // per_round)
        for k in range(rounds):
            t0 = time.perf_counter()
            policy = None if self.rlvc is None else self._exploration_policy()
            transitions = collect(
                self.env, per_round, policy, self.max_episode_steps, seed=self.seed + k
            )
            t1 = time.perf_counter()
            detected = self.keypoints.batch(transitions.percepts)
            t2 = time.perf_counter()
            if self.extractor is None:
                self.extractor = VisualFeatureExtractor.fit(
                    detected=detected,
                    n_words=self.n_words,
                    keypoints=self.keypoints,
                    max_descriptors=20_000,
                    iters=10,
                    soft_ratio=self.soft_ratio,
                    seed=self.seed,
                )
                self.rlvc = RLVC(
                    self.extractor.n_features,
                    int(self.env.action_space.n),
                    self.gamma,
                    self.alpha,
                    self.min_count,
                    self.bonferroni,
                )
            t3 = time.perf_counter()
            db = InteractionDatabase.build(transitions, self.extractor, detected)
            t4 = time.perf_counter()
            self.timing["collect"] += t1 - t0
            self.timing["extract"] += t2 - t1 + t4 - t3
            self.timing["vocabulary"] += t3 - t2
            self.num_timesteps += len(transitions)
            stages = self.max_stages if rounds == 1 else self.refresh_every
            if k == rounds - 1:  # the last database runs until nothing splits
                stages = self.max_stages - len(self.rlvc.history)
            if stages <= 0:
                break
            history_before = len(self.rlvc.history)
            self.rlvc.learn(
                db,
                max_stages=stages,
                evaluate=None if evaluate is None else (lambda _: evaluate(self)),
                eval_every=eval_every,
                progress=progress_bar,
                on_stage=on_stage,
            )
            splits = sum(r.splits for r in self.rlvc.history[history_before:])
            if rounds > 1 and splits == 0:
                break
        return self

    def _exploration_policy(self):
        def policy(obs: np.ndarray, rng: np.random.Generator) -> int:
            if rng.random() < self.epsilon:
                return int(rng.integers(self.rlvc.n_actions))
            return int(self.predict(obs)[0])

        return policy

    # -- acting -----------------------------------------------------------------------------
    @property
    def classifier(self) -> VisualClassifier:
        """Image -> visual class (for ``vistask.wrappers.VisualClasses``)."""
        self._check_learned()
        return VisualClassifier(self.extractor, self.rlvc.tree)

    def _check_learned(self) -> None:
        if self.rlvc is None or self.extractor is None:
            raise RuntimeError("the agent has not learned yet: call learn() or load()")

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """SB3's signature: one (H, W, 3) image -> (action, None); a batch (N, H, W, 3) ->
        ((N,) actions, None). Greedy on the learned classes (RLVC's policy is deterministic)."""
        self._check_learned()
        images = np.asarray(observation)
        single = images.ndim == 3
        batch = images[None] if single else images
        for image in batch[:1]:
            check_image(image)
        actions = self.rlvc.greedy(self.extractor.presence(list(batch))).numpy()
        return (int(actions[0]) if single else actions), None

    # -- persistence ------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        self._check_learned()
        torch.save(
            {
                "config": {
                    "n_words": self.n_words,
                    "alpha": self.alpha,
                    "min_count": self.min_count,
                    "bonferroni": self.bonferroni,
                    "max_stages": self.max_stages,
                    "max_episode_steps": self.max_episode_steps,
                    "database_size": self.database_size,
                    "refresh_every": self.refresh_every,
                    "epsilon": self.epsilon,
                    "gamma": self.gamma,
                    "soft_ratio": self.soft_ratio,
                    "seed": self.seed,
                },
                "classifier": self.classifier.state_dict(),
                "rlvc": self.rlvc.state_dict(),
                "num_timesteps": self.num_timesteps,
            },
            path,
        )

    @classmethod
    def load(cls, path: str | Path, env: gym.Env | None = None) -> RLVCAgent:
        state = torch.load(path, weights_only=True)
        classifier = VisualClassifier.from_state_dict(state["classifier"])
        agent = cls(env, keypoints=classifier.extractor.keypoints, **state["config"])
        agent.extractor = classifier.extractor
        agent.rlvc = RLVC.from_state_dict(state["rlvc"])
        if agent.rlvc.n_features != agent.extractor.n_features:
            raise ValueError("saved classes and vocabulary do not match: the file is corrupt")
        agent.num_timesteps = state["num_timesteps"]
        return agent
