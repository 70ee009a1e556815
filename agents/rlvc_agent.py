"""RLVCAgent: RLVC on a Gymnasium image environment, with an SB3-like API."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
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

    ``learn`` runs, top to bottom: collect a database, extract keypoints of every percept once,
    fit the vocabulary (first database only), build the interaction database, run RLVC stages.
    ``databases`` splits the budget into successive databases: the first is collected with
    uniformly random actions, each later one epsilon-greedily on the current classes. With
    ``keep_databases`` the stages run on the union of all databases so far (each round until
    nothing splits); without, each database replaces the previous one for ``refresh_every``
    stages. After ``learn``, ``database`` holds the interactions the last stages ran on (like
    SB3's replay buffer, it is not saved).

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
        blocked_is_stuck: act on Q solved with blocked moves (the same image again) as
            dead ends, since the greedy policy would repeat them forever (see ``RLVC``).
        max_stages: stage cap.
        max_episode_steps: exploration episodes are cut after this many steps.
        databases: fractions of the budget collected in successive databases (sum 1), or
            their number, for databases of equal size (the paper's "databases of 10,000
            interactions": ``databases=3`` with 30,000 timesteps).
        keep_databases: run the stages on the union of the databases so far, not the latest.
        refresh_every: stages run on each database but the last, without ``keep_databases``.
        epsilon: exploration rate when collecting on the current classes.
        max_blocked: an epsilon-greedy episode is cut after this many blocked moves in a row.
        n_envs: epsilon-greedy episodes run side by side on copies of ``env``, so that the
            policy extracts features of ``n_envs`` views at once.
        gamma: discount (default ``env.unwrapped.gamma``, else 0.99).
        keypoints: descriptor extractor (default ``SiftExtractor()``).
        soft_ratio: soft vocabulary assignment (see ``VisualFeatureExtractor``).
        vocabulary_groups: coarse groups of the two-level vocabulary, whose matching is several
            times faster than exact matching (0: flat vocabulary, exact nearest prototype).
        probes: groups searched per descriptor in the two-level vocabulary.
        seed: seeds collection and the vocabulary.
    """

    def __init__(
        self,
        env: gym.Env | None,
        n_words: int = 8192,
        alpha: float = 0.05,
        min_count: int = 10,
        bonferroni: bool = False,
        blocked_is_stuck: bool = False,
        max_stages: int = 300,
        max_episode_steps: int = 50,
        databases: int | Sequence[float] = 1,
        keep_databases: bool = True,
        refresh_every: int = 20,
        epsilon: float = 0.1,
        max_blocked: int | None = 2,
        n_envs: int = 128,
        gamma: float | None = None,
        keypoints: SiftExtractor | None = None,
        soft_ratio: float = 1.0,
        vocabulary_groups: int = 64,
        probes: int = 3,
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
        self.blocked_is_stuck = blocked_is_stuck
        self.max_stages, self.max_episode_steps = max_stages, max_episode_steps
        if isinstance(databases, int):
            if databases < 1:
                raise ValueError(f"databases must be >= 1, got {databases}")
            databases = (1 / databases,) * databases
        if not databases or min(databases) <= 0 or abs(sum(databases) - 1) > 1e-6:
            raise ValueError(f"databases must be positive fractions summing to 1, got {databases}")
        self.databases, self.keep_databases = tuple(databases), keep_databases
        self.refresh_every, self.epsilon, self.max_blocked = refresh_every, epsilon, max_blocked
        self.n_envs = n_envs
        self.seed = seed
        self.gamma = 0.99 if gamma is None else float(gamma)
        self.keypoints = keypoints or SiftExtractor()
        self.soft_ratio = soft_ratio
        self.vocabulary_groups, self.probes = vocabulary_groups, probes
        self.extractor: VisualFeatureExtractor | None = None
        self.rlvc: RLVC | None = None
        self.database: InteractionDatabase | None = None
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
            total_timesteps: interactions in all, split over ``databases``.
            evaluate: optional ``evaluate(agent) -> return`` of the greedy policy, logged every
                ``eval_every`` stages.
            progress_bar: show progress bars.
            on_stage: called with every stage's record (TensorBoard logging).
        """
        if self.env is None:
            raise ValueError("this agent has no env: pass one to RLVCAgent.load(path, env)")
        if total_timesteps < 1:
            raise ValueError(f"total_timesteps must be >= 1, got {total_timesteps}")
        sizes = [round(f * total_timesteps) for f in self.databases]
        sizes[0] += total_timesteps - sum(sizes)
        if min(sizes) < 1:
            raise ValueError(f"{total_timesteps} interactions cannot fill {len(sizes)} databases")
        db, seed = None, self.seed
        for k, size in enumerate(sizes):
            t0 = time.perf_counter()
            exploring = self.rlvc is not None
            n_envs = self.n_envs if exploring else 1
            transitions = collect(
                self.env,
                size,
                self._exploration_policy() if exploring else None,
                self.max_episode_steps,
                seed=seed,
                max_blocked=self.max_blocked if exploring else None,
                n_envs=n_envs,
            )
            seed += n_envs  # env copy i resets with seed + i: no two databases share a seed
            t1 = time.perf_counter()
            detected, fitting = None, 0.0  # later databases: the cache holds what the policy saw
            if self.extractor is None:
                detected = self.keypoints.batch(transitions.percepts)
                t2 = time.perf_counter()
                self.extractor = VisualFeatureExtractor.fit(
                    detected=detected,
                    n_words=self.n_words,
                    keypoints=self.keypoints,
                    max_descriptors=20_000,
                    iters=10,
                    soft_ratio=self.soft_ratio,
                    groups=self.vocabulary_groups,
                    probes=self.probes,
                    seed=self.seed,
                )
                self.rlvc = RLVC(
                    self.extractor.n_features,
                    int(self.env.action_space.n),
                    self.gamma,
                    self.alpha,
                    self.min_count,
                    self.bonferroni,
                    blocked_is_stuck=self.blocked_is_stuck,
                )
                fitting = time.perf_counter() - t2
            latest = InteractionDatabase.build(transitions, self.extractor, detected)
            keep = self.keep_databases and db is not None
            db = InteractionDatabase.concat(db, latest) if keep else latest
            self.database = db
            self.timing["collect"] += t1 - t0
            self.timing["extract"] += time.perf_counter() - t1 - fitting
            self.timing["vocabulary"] += fitting
            self.num_timesteps += len(transitions)
            stages = self.max_stages - len(self.rlvc.history)
            last = k == len(sizes) - 1
            if not (last or self.keep_databases):
                stages = min(stages, self.refresh_every)
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
            # A fresh database that splits nothing means the classes have converged.
            if not self.keep_databases and k > 0 and splits == 0:
                break
        return self

    def _exploration_policy(self):
        def policy(observations: np.ndarray, rng: np.random.Generator) -> np.ndarray:
            greedy = self.predict(observations)[0]
            explore = rng.random(len(greedy)) < self.epsilon
            return np.where(explore, rng.integers(self.rlvc.n_actions, size=len(greedy)), greedy)

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
                    "blocked_is_stuck": self.blocked_is_stuck,
                    "max_stages": self.max_stages,
                    "max_episode_steps": self.max_episode_steps,
                    "databases": list(self.databases),
                    "keep_databases": self.keep_databases,
                    "refresh_every": self.refresh_every,
                    "epsilon": self.epsilon,
                    "max_blocked": self.max_blocked,
                    "n_envs": self.n_envs,
                    "gamma": self.gamma,
                    "soft_ratio": self.soft_ratio,
                    "vocabulary_groups": self.vocabulary_groups,
                    "probes": self.probes,
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
        config = dict(state["config"])
        config.pop("database_size", None)  # older files; it only shaped how they learned
        agent = cls(env, keypoints=classifier.extractor.keypoints, **config)
        agent.extractor = classifier.extractor
        agent.rlvc = RLVC.from_state_dict(state["rlvc"])
        if agent.rlvc.n_features != agent.extractor.n_features:
            raise ValueError("saved classes and vocabulary do not match: the file is corrupt")
        agent.num_timesteps = state["num_timesteps"]
        return agent
