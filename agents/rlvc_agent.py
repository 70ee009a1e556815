"""RLVCAgent: RLVC on any Gymnasium image environment, with Stable-Baselines3's API."""

from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from vistask.agents.sb3_model import SB3Model
from vistask.checks import check_at_least, check_integers
from vistask.features import SiftExtractor, VisualFeatureExtractor
from vistask.rlvc import (
    RLVC,
    InteractionDatabase,
    StageRecord,
    VisualClassifier,
    check_image_env,
    collect,
)
from vistask.saving import load_state, save_state

MAX_BLOCKED = 2  # an epsilon-greedy episode ends after this many blocked moves in a row
VOCABULARY_SAMPLE = 20_000  # descriptors that k-means fits the vocabulary on


class RLVCAgent(SB3Model):
    """Learns visual classes of an image env by RLVC and acts greedily on them.

    ``learn(total_timesteps)`` collects ``databases`` equal databases of interactions, one
    after the other: the first with uniformly random actions, each later one epsilon-greedily
    on the classes learned so far (``n_envs`` episodes side by side), each added to the earlier
    ones. After each database, RLVC stages run until no class splits: SIFT keypoints of every
    percept are extracted once, matched to a vocabulary of ``n_words`` visual features (fitted
    on the first database), and classes are split where a feature reduces the variance of the
    TD errors significantly. A second ``learn`` call continues: more databases, more stages.

    Episodes end where the env ends them: its terminal states and its own time limit (the
    ``max_episode_steps`` of ``gym.make``); wrap an env without one in ``TimeLimit``.

    Callbacks (SB3's ``BaseCallback``, a list of them, or a function) are called once per
    RLVC stage, where the policy changes: ``CheckpointCallback(save_freq=50)`` saves every 50
    stages, ``EvalCallback(eval_env, eval_freq=50)`` evaluates every 50 stages; returning
    False stops learning. ``num_timesteps`` counts the interactions collected. With
    ``tensorboard_log``, every stage logs ``rlvc/classes``, ``rlvc/selected_features``,
    ``rlvc/mean_abs_td`` and ``rlvc/splits``, with the stage as the step.

    Example:
        >>> import gymnasium as gym, vistask.envs
        >>> env = gym.make("vistask/VisualMaze-v0")
        >>> agent = RLVCAgent(env, seed=0).learn(total_timesteps=30_000)
        >>> action, _ = agent.predict(obs)               # obs: one image, or a batch
        >>> agent.save("rlvc.pt"); agent = RLVCAgent.load("rlvc.pt", env=env)

    Args:
        env: env with (H, W, 3) or (H, W) uint8 image observations and ``Discrete`` actions
            (``None`` only when loading, to predict without an env).
        n_words: vocabulary size: the number of visual features.
        databases: number of equal databases that ``total_timesteps`` is split into.
        alpha: significance level of the split t-tests (Welch).
        min_count: minimum interactions on each side of a split.
        max_stages: stage cap of one ``learn`` call.
        epsilon: exploration rate of the epsilon-greedy databases and of
            ``predict(deterministic=False)``.
        n_envs: episodes collected side by side on the classes, so that features are
            extracted for batches of views.
        max_keypoints: SIFT keeps the strongest keypoints of each percept (0: all).
        compounds: make compound features (pairs of parts, coarse groups of words or
            compounds, in a stable spatial relation) for the most aliased classes that no
            feature splits. Off by default: on the maze
            they lowered the mean return (0.917 of the oracle's against 0.927, seeds 0-4);
            where a relation carries the state (a gauge's needle), they are what reads it.
        compaction: hold the classes in a BDD; when the stages of a database end, merge
            classes with close values and interchangeable greedy actions, then drop the
            features that no percept seen needs (False: a decision tree that only splits).
        compact_every: with ``compaction``, merge every this many stages as well (None:
            only when the stages of a database end).
        compaction_tolerance: merge classes whose values, and the values of their greedy
            actions in each other, differ by at most this share of the range of values.
        gamma: discount (default: the env's ``gamma`` attribute if it has one, else 0.99).
        tensorboard_log: folder of TensorBoard runs (None: no logging).
        seed: seeds the episodes, the exploration and the vocabulary.
    """

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
        max_keypoints: int = 24,
        compounds: bool = False,
        compaction: bool = False,
        compact_every: int | None = None,
        compaction_tolerance: float = 0.02,
        gamma: float | None = None,
        tensorboard_log: str | Path | None = None,
        seed: int = 0,
    ) -> None:
        counts = {
            "n_words": n_words,
            "databases": databases,
            "min_count": min_count,
            "max_stages": max_stages,
            "n_envs": n_envs,
            "max_keypoints": max_keypoints,
        }
        check_integers(**counts)
        check_at_least(2, n_words=n_words, min_count=min_count)
        check_at_least(1, databases=databases, max_stages=max_stages, n_envs=n_envs)
        check_at_least(0, max_keypoints=max_keypoints)
        if not 0 < alpha < 1:
            raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
        if not 0 <= epsilon <= 1:
            raise ValueError(f"epsilon must be in [0, 1], got {epsilon!r}")
        if gamma is None:
            gamma = getattr(env.unwrapped, "gamma", 0.99) if env is not None else 0.99
        if not 0 <= gamma < 1:
            raise ValueError(f"gamma must be in [0, 1), got {gamma!r}")
        self.n_words, self.databases = int(n_words), int(databases)
        self.alpha, self.min_count, self.max_stages = float(alpha), int(min_count), max_stages
        self.epsilon, self.n_envs, self.max_keypoints = float(epsilon), n_envs, max_keypoints
        if compact_every is not None:
            check_integers(compact_every=compact_every)
            check_at_least(1, compact_every=compact_every)
        if not 0 <= compaction_tolerance < 1:
            raise ValueError(
                f"compaction_tolerance must be in [0, 1), got {compaction_tolerance!r}"
            )
        self.compounds = bool(compounds)
        self.compaction, self.compact_every = bool(compaction), compact_every
        self.compaction_tolerance = float(compaction_tolerance)
        self.gamma, self.seed = float(gamma), int(seed)
        self.tensorboard_log = tensorboard_log
        self.env: gym.Env | None = None
        self.observation_space: gym.spaces.Box | None = None
        self.action_space: gym.spaces.Discrete | None = None
        self.env_id: str | None = None
        if env is not None:
            self.set_env(env)
        self.extractor: VisualFeatureExtractor | None = None
        self.rlvc: RLVC | None = None
        self.database: InteractionDatabase | None = None
        self.num_timesteps = 0
        self.timing = {"collect": 0.0, "extract": 0.0, "vocabulary": 0.0}
        self._next_seed = self.seed  # env copy i of the next database resets with this + i
        self._rng = np.random.default_rng(self.seed)  # predict(deterministic=False)

    # -- env --------------------------------------------------------------------------------
    def set_env(self, env: gym.Env) -> None:
        """Use ``env`` from now on; a learned agent checks that its spaces are the ones it
        learned on."""
        check_image_env(env)
        if self.observation_space is not None:
            self._check_spaces(env)
        self.env, self._vec_env = env, None
        self.observation_space, self.action_space = env.observation_space, env.action_space
        self.env_id = self.env_id or (env.spec.id if env.spec is not None else None)

    def _check_spaces(self, env: gym.Env) -> None:
        space, n = env.observation_space, getattr(env.action_space, "n", None)
        if (
            tuple(space.shape) != tuple(self.observation_space.shape)
            or space.dtype != self.observation_space.dtype
            or n != self.action_space.n
        ):
            raise ValueError(
                f"the agent learned on {self.env_id or 'an env'} with observations "
                f"{tuple(self.observation_space.shape)} {self.observation_space.dtype} and "
                f"{self.action_space.n} actions; this env has {tuple(space.shape)} "
                f"{space.dtype} and {env.action_space}"
            )

    # -- learning ---------------------------------------------------------------------------
    def learn(
        self,
        total_timesteps: int,
        callback: Any = None,
        tb_log_name: str = "RLVC",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> RLVCAgent:
        """Collect ``total_timesteps`` interactions in ``databases`` databases and learn
        visual classes from them, continuing from what the agent has learned already.

        Args:
            total_timesteps: interactions to collect in this call.
            callback: SB3 callback(s), called once per RLVC stage (see the class).
            tb_log_name: name of the TensorBoard run under ``tensorboard_log``.
            reset_num_timesteps: count interactions from 0 and start a new TensorBoard run
                (False: go on counting, in the same run).
            progress_bar: show progress bars of the stages.
        """
        if not isinstance(total_timesteps, int | np.integer) or total_timesteps < self.databases:
            raise ValueError(
                f"total_timesteps must be an integer >= databases ({self.databases}), "
                f"got {total_timesteps!r}"
            )
        callback = self._start_learning(callback, tb_log_name, reset_num_timesteps)
        sizes = [total_timesteps // self.databases] * self.databases
        sizes[0] += total_timesteps - sum(sizes)
        stages_left = self.max_stages
        for size in sizes:
            callback.on_rollout_start()
            self._add_database(size)
            callback.on_rollout_end()
            stages_before = len(self.rlvc.history)
            stopped = False

            def on_stage(record: StageRecord) -> bool:
                nonlocal stopped
                stopped = not callback.on_step()  # before the dump: its records join the stage's
                self._log_stage(record)
                return not stopped

            self.rlvc.learn(self.database, stages_left, progress_bar, on_stage)
            stages_left -= len(self.rlvc.history) - stages_before
            if stopped or stages_left <= 0:
                break
        self._end_learning(callback)
        return self

    def _add_database(self, size: int) -> None:
        """Collect ``size`` interactions and add them to the database (the first database
        also fits the vocabulary and starts the learner)."""
        t0 = time.perf_counter()
        exploring = self.rlvc is not None
        n_envs = self.n_envs if exploring else 1
        transitions = collect(
            self.env,
            size,
            self._epsilon_greedy if exploring else None,
            seed=self._next_seed,
            max_blocked=MAX_BLOCKED if exploring else None,
            n_envs=n_envs,
        )
        self._next_seed += n_envs  # no two databases share an episode seed
        t1 = time.perf_counter()
        detected, fitting = None, 0.0  # later databases: the cache holds what the policy saw
        if self.extractor is None:
            keypoints = SiftExtractor(max_keypoints=self.max_keypoints)
            detected = keypoints.batch(transitions.percepts)
            t2 = time.perf_counter()
            self.extractor = VisualFeatureExtractor.fit(
                detected=detected,
                n_words=self._vocabulary_size(detected),
                keypoints=keypoints,
                max_descriptors=VOCABULARY_SAMPLE,
                iters=10,
                seed=self.seed,
            )
            self.rlvc = RLVC(
                self.extractor.n_features,
                int(self.action_space.n),
                self.gamma,
                self.alpha,
                self.min_count,
                use_compounds=self.compounds,
                compaction=self.compaction,
                compact_every=self.compact_every,
                compaction_tolerance=self.compaction_tolerance,
            )
            fitting = time.perf_counter() - t2
        latest = InteractionDatabase.build(
            transitions, self.extractor, detected, self.rlvc.compounds
        )
        self.database = (
            latest if self.database is None else InteractionDatabase.concat(self.database, latest)
        )
        self.timing["collect"] += t1 - t0
        self.timing["extract"] += time.perf_counter() - t1 - fitting
        self.timing["vocabulary"] += fitting
        self.num_timesteps += len(transitions)

    def _vocabulary_size(self, detected: list) -> int:
        """``n_words``, or half the descriptors of a first database too small to fit them."""
        descriptors = sum(len(k) for k in detected)
        if descriptors >= self.n_words:
            return self.n_words
        if descriptors < 4:
            raise ValueError(
                f"the first database shows only {descriptors} SIFT descriptors: collect more "
                "interactions (total_timesteps) or use an env with textured images"
            )
        warnings.warn(
            f"the first database has {descriptors} SIFT descriptors, too few for "
            f"{self.n_words} words: fitting {descriptors // 2} (collect more interactions, "
            "or lower n_words)",
            stacklevel=3,
        )
        return descriptors // 2

    def _log_stage(self, record: StageRecord) -> None:
        for key in ("classes", "selected_features", "mean_abs_td", "splits"):
            self.logger.record(f"rlvc/{key}", getattr(record, key))
        self.logger.record("time/total_timesteps", self.num_timesteps)
        self.logger.dump(step=record.stage)

    def _epsilon_greedy(self, observations: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(N,) actions: greedy on the classes, uniformly random with probability epsilon."""
        greedy = self.rlvc.greedy(self._presence(observations)).numpy()
        explore = rng.random(len(greedy)) < self.epsilon
        return np.where(explore, rng.integers(self.rlvc.n_actions, size=len(greedy)), greedy)

    # -- acting -----------------------------------------------------------------------------
    def _presence(self, images: np.ndarray) -> torch.Tensor:
        """(N, F + C) presence of the words and the learned compounds in a batch of images."""
        return self.extractor.presence(list(images), self.rlvc.compounds)

    @property
    def classifier(self) -> VisualClassifier:
        """Image -> visual class (for ``vistask.wrappers.VisualClasses``)."""
        self._check_learned()
        return VisualClassifier(self.extractor, self.rlvc.structure, self.rlvc.compounds)

    def _check_learned(self) -> None:
        if self.rlvc is None or self.extractor is None:
            raise RuntimeError("the agent has not learned yet: call learn() or load()")

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[int | np.ndarray, None]:
        """SB3's signature: one image -> (action, None); a batch (N, ...) -> ((N,) actions,
        None). Greedy on the learned classes; ``deterministic=False`` acts epsilon-greedily.
        ``state`` and ``episode_start`` are unused (the policy has no memory)."""
        self._check_learned()
        images = np.asarray(observation)
        shape = tuple(self.observation_space.shape)
        single = images.shape == shape
        if not single and images.shape[1:] != shape:
            raise ValueError(
                f"observation must be one image of shape {shape} or a batch (N, *{shape}), "
                f"got shape {images.shape}"
            )
        if images.dtype != self.observation_space.dtype:
            raise TypeError(
                f"observation must have dtype {self.observation_space.dtype}, got {images.dtype}"
            )
        batch = images[None] if single else images
        if deterministic:
            actions = self.rlvc.greedy(self._presence(batch)).numpy()
        else:
            actions = self._epsilon_greedy(batch, self._rng)
        return (int(actions[0]) if single else actions), None

    # -- persistence ------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Save the vocabulary, the classes, Q and the settings (not the databases)."""
        self._check_learned()
        save_state(
            path,
            "RLVCAgent",
            {
                "params": {
                    "n_words": self.n_words,
                    "databases": self.databases,
                    "alpha": self.alpha,
                    "min_count": self.min_count,
                    "max_stages": self.max_stages,
                    "epsilon": self.epsilon,
                    "n_envs": self.n_envs,
                    "max_keypoints": self.max_keypoints,
                    "compounds": self.compounds,
                    "compaction": self.compaction,
                    "compact_every": self.compact_every,
                    "compaction_tolerance": self.compaction_tolerance,
                    "gamma": self.gamma,
                    "seed": self.seed,
                },
                "observation_shape": list(self.observation_space.shape),
                "observation_dtype": str(self.observation_space.dtype),
                "n_actions": int(self.action_space.n),
                "env_id": self.env_id,
                "extractor": self.extractor.state_dict(),
                "rlvc": self.rlvc.state_dict(),
                "num_timesteps": self.num_timesteps,
                "next_seed": self._next_seed,
            },
        )

    @classmethod
    def load(
        cls, path: str | Path, env: gym.Env | None = None, tensorboard_log: str | None = None
    ) -> RLVCAgent:
        """Load a saved agent; with ``env``, check that its spaces are the ones it learned on
        (it can then ``learn`` more)."""
        state = load_state(path, "RLVCAgent")
        agent = cls(None, tensorboard_log=tensorboard_log, **state["params"])
        dtype = np.dtype(state["observation_dtype"])
        agent.observation_space = gym.spaces.Box(0, 255, tuple(state["observation_shape"]), dtype)
        agent.action_space = gym.spaces.Discrete(state["n_actions"])
        agent.env_id = state["env_id"]
        agent.extractor = VisualFeatureExtractor.from_state_dict(state["extractor"])
        agent.rlvc = RLVC.from_state_dict(state["rlvc"])
        if agent.rlvc.n_features != agent.extractor.n_features + len(agent.rlvc.compounds):
            raise ValueError(f"{path}: its classes and vocabulary do not match (corrupt file)")
        agent.num_timesteps, agent._next_seed = state["num_timesteps"], state["next_seed"]
        if env is not None:
            agent.set_env(env)
        return agent
