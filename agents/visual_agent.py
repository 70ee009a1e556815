"""What RLVCAgent and RLJCAgent share: a visual vocabulary fitted on the first database,
databases collected random first then epsilon-greedily, stages of a learner after each, SB3's
callbacks and TensorBoard, ``predict`` on one image or a batch, ``save`` and ``load``."""

from __future__ import annotations

import pickle
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import psutil
import torch

from vistask.agents.progress import LearnProgress
from vistask.agents.sb3_model import SB3Model
from vistask.checks import (
    check_at_least,
    check_auto_or_integer,
    check_discount,
    check_integers,
    check_same_env,
    checked,
    env_identity,
    warn,
)
from vistask.features import SiftExtractor, VisualFeatureExtractor, choose_enlarge
from vistask.features.keypoints import extract_once
from vistask.features.vocabulary import CACHE_SIZE, VOCABULARY_GROUPS
from vistask.rlvc import (
    InteractionDatabase,
    StageRecord,
    Transitions,
    check_image_env,
    collect_chunks,
)
from vistask.rlvc.copies import copy_env, steps_own_copies, warn_unmade_settings
from vistask.saving import load_state, save_state

MAX_BLOCKED = 2  # default: an exploring episode ends after this many unchanged views in a row
# What min_count="auto" means: interactions a split needs on each side, on views as they are
# and on enlarged views (see ``VisualAgent.split_count``).
MIN_COUNT, ENLARGED_MIN_COUNT = 10, 5
VOCABULARY_SAMPLE = 20_000  # descriptors that k-means fits the vocabulary on
SIFT_CHUNK = 1024  # percepts of the first database extracted between two bar updates
PERCEPTS_PER_CHUNK = 16_384  # images a database holds at once while it is collected
# What ``memory_needed_mb`` counts, in bytes: an occurrence (image, word, x, y, scale and part
# as 32-bit numbers) and the split search's pairs of each keypoint of a percept (two int64,
# and its temporaries: deltas, keys); an interaction's percept ids, action, reward, terminal
# flag and position; a SIFT descriptor (128 float32); a cached percept besides its keypoints.
OCCURRENCE_BYTES, PAIR_BYTES, INTERACTION_BYTES = 24, 56, 49
DESCRIPTOR_BYTES, CACHE_ENTRY_BYTES = 512, 600
COMPOUND_ROOM = 256  # compound features a run makes, at most about
UNCAPPED_KEYPOINTS = 128  # keypoints counted per percept when max_keypoints is 0


def space_state(space: gym.spaces.Discrete | gym.spaces.Box) -> dict:
    """An action space as plain values for a saved file."""
    if isinstance(space, gym.spaces.Discrete):
        return {"n": int(space.n), "start": int(space.start)}
    return {"low": space.low.tolist(), "high": space.high.tolist(), "dtype": str(space.dtype)}


def space_from_state(state: dict) -> gym.spaces.Discrete | gym.spaces.Box:
    """The action space that ``space_state`` described (files without ``start`` start at 0)."""
    if "n" in state:
        return gym.spaces.Discrete(state["n"], start=state.get("start", 0))
    dtype = np.dtype(state["dtype"])
    return gym.spaces.Box(
        np.array(state["low"], dtype), np.array(state["high"], dtype), dtype=dtype
    )


@checked
class VisualAgent(SB3Model):
    """Base of the agents that learn a decision structure over visual features.

    A subclass says which actions it learns (``continuous``), makes its learner
    (``_new_learner``), acts with it (``_greedy``, ``_explore``) and names the settings it adds
    (``_extra_params``). Its learner has ``learn(db, max_stages, progress, on_stage)``,
    ``history``, ``compounds``, ``state_dict`` and ``from_state_dict``.
    """

    continuous: ClassVar[bool] = False
    learner_class: ClassVar[type]
    compounds: bool = False  # whether the learner makes compound features

    def __init__(
        self,
        env: gym.Env | None,
        n_words: int,
        databases: int,
        alpha: float,
        min_count: int | str,
        max_stages: int,
        epsilon: float,
        n_envs: int,
        max_keypoints: int,
        contrast_threshold: float,
        gamma: float | None,
        tensorboard_log: str | Path | None,
        seed: int,
        max_blocked: int = MAX_BLOCKED,
        enlarge: int | str = "auto",
    ) -> None:
        counts = {
            "n_words": n_words,
            "databases": databases,
            "max_stages": max_stages,
            "n_envs": n_envs,
            "max_keypoints": max_keypoints,
            "seed": seed,
            "max_blocked": max_blocked,
        }
        check_integers(**counts)
        check_at_least(0, seed=seed, max_blocked=max_blocked)
        check_at_least(2, n_words=n_words)
        check_at_least(1, databases=databases, max_stages=max_stages, n_envs=n_envs)
        check_auto_or_integer(2, min_count=min_count)
        check_auto_or_integer(1, enlarge=enlarge)
        check_at_least(0, max_keypoints=max_keypoints)
        if not contrast_threshold > 0:
            raise ValueError(f"contrast_threshold must be > 0, got {contrast_threshold!r}")
        if not 0 < alpha < 1:
            raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
        if not 0 <= epsilon <= 1:
            raise ValueError(f"epsilon must be in [0, 1], got {epsilon!r}")
        if gamma is None and env is not None and hasattr(env.unwrapped, "gamma"):
            gamma = env.unwrapped.gamma
            try:
                check_discount(gamma)
            except (TypeError, ValueError):
                raise ValueError(
                    f"the env's gamma attribute ({gamma!r}) is the agent's discount unless "
                    "gamma is given, and a discount is a number in [0, 1): pass gamma"
                ) from None
        gamma = 0.99 if gamma is None else gamma
        check_discount(gamma)
        self.n_words, self.databases = int(n_words), int(databases)
        self.alpha, self.max_stages = float(alpha), max_stages
        self.min_count = min_count if isinstance(min_count, str) else int(min_count)
        self.epsilon, self.n_envs, self.max_keypoints = float(epsilon), n_envs, max_keypoints
        self.contrast_threshold = float(contrast_threshold)
        self.enlarge = enlarge if isinstance(enlarge, str) else int(enlarge)
        self.gamma, self.seed, self.max_blocked = float(gamma), int(seed), int(max_blocked)
        self.tensorboard_log = tensorboard_log
        self.vocabulary_groups = VOCABULARY_GROUPS
        self.env: gym.Env | None = None
        self.observation_space: gym.spaces.Box | None = None
        self.action_space: gym.spaces.Discrete | gym.spaces.Box | None = None
        self.env_id: str | None = None
        self.env_kwargs: dict | None = None  # the gym.make arguments of env_id
        if env is not None:
            self.set_env(env)
        self.extractor: VisualFeatureExtractor | None = None
        self.learner = None
        self.database: InteractionDatabase | None = None
        self.num_timesteps = 0
        self.timing = {"collect": 0.0, "extract": 0.0, "vocabulary": 0.0}
        self._next_seed = self.seed  # env copy i of the next database resets with this + i
        self._rng = np.random.default_rng(self.seed)  # predict(deterministic=False)
        self._plan: dict | None = None  # what is left of the learn call a checkpoint stopped

    # -- what a subclass adds ---------------------------------------------------------------
    def _new_learner(self):
        raise NotImplementedError

    def _greedy(self, presence: torch.Tensor) -> np.ndarray:
        """(N, F) presence -> (N,) or (N, m) greedy actions."""
        raise NotImplementedError

    def _explore(self, presence: torch.Tensor, rng: np.random.Generator) -> np.ndarray:
        """(N, F) presence -> (N,) or (N, m) exploring actions (rate ``epsilon``)."""
        raise NotImplementedError

    def _extra_params(self) -> dict:
        """The subclass's own constructor arguments, for ``save``."""
        return {}

    def _end_databases(self) -> None:
        """Called once the stages of a ``learn`` call's last database have run."""

    @contextmanager
    def _exploring(self, to_collect: int) -> Iterator[None]:
        """The database's rewards while the learner learns, with ``to_collect`` databases of
        the call still to collect on its classes: the env's by default."""
        yield

    @classmethod
    def _params_from_state(cls, params: dict) -> dict:
        """The constructor arguments of a saved file's settings; files without ``enlarge``
        saw every view as it is."""
        return {"enlarge": 1, **params}

    @property
    def enlarged(self) -> bool:
        """Whether the vocabulary sees its views enlarged (False before it is built)."""
        return self.extractor is not None and self.extractor.keypoints.enlarge > 1

    @property
    def split_count(self) -> int:
        """Interactions a split needs on each side: ``min_count``, or for ``"auto"``
        ``ENLARGED_MIN_COUNT`` where the vocabulary sees its views enlarged, else
        ``MIN_COUNT``."""
        if self.min_count != "auto":
            return self.min_count
        return ENLARGED_MIN_COUNT if self.enlarged else MIN_COUNT

    # -- env --------------------------------------------------------------------------------
    def set_env(self, env: gym.Env) -> None:
        """Use ``env`` from now on; a learned agent checks that its spaces are the ones it
        learned on."""
        check_image_env(env, self.continuous)
        if self.observation_space is not None:
            self._check_spaces(env)
            self._check_same_env(env)
        self.env, self._vec_env = env, None
        self.observation_space, self.action_space = env.observation_space, env.action_space
        if self.env_id is None and env_identity(env) is not None:
            self.env_id, self.env_kwargs = env_identity(env)

    def _check_same_env(self, env: gym.Env, learning: bool = False) -> None:
        """Another env id or other ``gym.make`` arguments than the agent learned on: an error
        when it would learn on (a checkpoint's databases, or ``learn``), else a warning."""
        learned = None if self.env_kwargs is None else (self.env_id, self.env_kwargs)
        check_same_env(learned, env, learning or self.database is not None)

    def _check_spaces(self, env: gym.Env) -> None:
        space = env.observation_space
        if (
            tuple(space.shape) != tuple(self.observation_space.shape)
            or space.dtype != self.observation_space.dtype
            or env.action_space != self.action_space
        ):
            raise ValueError(
                f"the agent learned on {self.env_id or 'an env'} with observations "
                f"{tuple(self.observation_space.shape)} {self.observation_space.dtype} and "
                f"actions {self.action_space}; this env has {tuple(space.shape)} "
                f"{space.dtype} and {env.action_space}"
            )

    # -- learning ---------------------------------------------------------------------------
    def learn(
        self,
        total_timesteps: int,
        callback: Any = None,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
        checkpoint: str | Path | None = None,
    ):
        """Collect ``total_timesteps`` interactions in ``databases`` databases and learn
        classes from them, continuing from what the agent has learned already.

        Args:
            total_timesteps: interactions to collect in this call.
            callback: SB3 callback(s), called once per stage (see the class).
            tb_log_name: name of the TensorBoard run under ``tensorboard_log`` (default: the
                learner's name).
            reset_num_timesteps: count interactions from 0 and start a new TensorBoard run
                (False: go on counting, in the same run).
            progress_bar: show one bar over the call: interactions collected, with the phase,
                stage, classes and the mean return of the latest database's episodes.
            checkpoint: a file to which the agent, its databases, its random generator and
                what is left of this call are written after each database's stages.
                ``load(checkpoint, env)`` then ``learn(total_timesteps -
                agent.num_timesteps, reset_num_timesteps=False)`` goes on where the file left
                off and ends as an uninterrupted call would, bit for bit on the CPU.
        """
        if not isinstance(total_timesteps, int | np.integer) or total_timesteps < self.databases:
            raise ValueError(
                f"total_timesteps must be an integer >= databases ({self.databases}), "
                f"got {total_timesteps!r}"
            )
        if checkpoint is not None and Path(checkpoint).is_dir():
            raise ValueError(f"checkpoint: {checkpoint} is a folder; name a file in it")
        if self.env is None:
            raise RuntimeError(
                "the agent has no env to learn on: load it with load(path, env=...) or call "
                "set_env(env) first"
            )
        self._check_same_env(self.env, learning=True)
        self._check_memory(total_timesteps)
        name = tb_log_name or self.learner_class.__name__
        callback = self._start_learning(callback, name, reset_num_timesteps)
        plan, self._plan = self._plan, None
        if plan is not None and not reset_num_timesteps and sum(plan["sizes"]) == total_timesteps:
            sizes = list(plan["sizes"])  # a checkpoint's call
        else:
            sizes = [total_timesteps // self.databases] * self.databases
            sizes[0] += total_timesteps - sum(sizes)
        with LearnProgress(total_timesteps, len(sizes), progress_bar) as progress:
            for database, size in enumerate(sizes, 1):
                callback.on_rollout_start()
                progress.phase("collecting", database)
                self._add_database(size, progress)
                callback.on_rollout_end()
                progress.phase("stages")
                stopped = False

                def on_stage(record: StageRecord) -> bool:
                    nonlocal stopped
                    self.logger.stage = record.stage  # the step of every dump, callbacks' too
                    stopped = not callback.on_step()  # before the dump: its records join it
                    self._log_stage(record)
                    progress.show(stage=record.stage, classes=record.classes)
                    return not stopped

                with self._exploring(to_collect=len(sizes) - database):
                    self.learner.learn(self.database, self.max_stages, False, on_stage)
                if stopped:
                    break
                if checkpoint is not None and database < len(sizes):
                    state = self._state()
                    state["resume"] = {
                        "database": self.database.state_dict(),
                        "rng": self._rng.bit_generator.state,
                        "plan": {"sizes": sizes[database:]},
                    }
                    save_state(checkpoint, type(self).__name__, state)
            progress.phase("ending")
            self._end_databases()
            progress.show(classes=self.learner.n_classes)  # merged, fused or regrown
        self._end_learning(callback)
        if not self.rewards_seen:
            warn(
                f"no reward in the {len(self.database)} interactions learned on: every class "
                "has the same value, so the greedy policy is arbitrary; collect more "
                "interactions (total_timesteps) or check the env's rewards"
            )
        elif self.learner.n_classes == 1:
            warn(
                f"one class after {len(self.database)} interactions: no feature's presence "
                f"parted interactions of different values in at least min_count "
                f"({self.split_count}) on each side, so the agent acts alike on every percept; "
                "collect more interactions (total_timesteps)"
            )
        return self

    def memory_needed_mb(self, total_timesteps: int) -> float:
        """About how many MB of memory ``learn(total_timesteps)`` takes at its peak beyond what
        the process holds before it: the databases (joined with the earlier ones), one chunk
        of images and the vocabulary's descriptors.

        Raises:
            ValueError: total_timesteps below 1."""
        check_at_least(1, total_timesteps=total_timesteps)
        keypoints = self.max_keypoints or UNCAPPED_KEYPOINTS
        interactions = self.num_timesteps + total_timesteps
        per_interaction = (
            -(-(self.n_words + COMPOUND_ROOM) // 8)  # presence bits of its percept
            + keypoints * (OCCURRENCE_BYTES * self.compounds + PAIR_BYTES)
            + INTERACTION_BYTES
        )
        image = int(np.prod(self.observation_space.shape))
        chunk = min(interactions, PERCEPTS_PER_CHUNK) * (image + keypoints * DESCRIPTOR_BYTES)
        cache = min(interactions, CACHE_SIZE) * (keypoints * 16 + CACHE_ENTRY_BYTES)
        # A database is held twice while it joins the earlier ones.
        need = 2 * interactions * per_interaction + chunk + cache
        return need / 2**20

    def _check_memory(self, total_timesteps: int) -> None:
        copies = self._env_copies_mb()
        need = self.memory_needed_mb(total_timesteps) + copies
        free = psutil.virtual_memory().available
        if need > free / 2**20:
            of_copies = f" ({copies:.0f} MB of them the env's copies)" if copies else ""
            raise MemoryError(
                f"learn({total_timesteps}) would need about {need:.0f} MB more memory at its "
                f"peak{of_copies}, and {free / 2**20:.0f} MB are available: collect fewer "
                "interactions, lower n_words, max_keypoints or n_envs, or free memory"
            )

    def _env_copies_mb(self) -> float:
        """MB that the ``n_envs - 1`` copies of the env that the exploring databases step take:
        the size of the env pickled (0 where it does not pickle). One copy is made and dropped
        first, so that an env that cannot be copied says so before any work is done."""
        if self.n_envs == 1 or steps_own_copies(self.env):
            return 0.0
        made = copy_env(self.env)
        warn_unmade_settings(self.env, made)
        made.close()
        buffers = []  # arrays' data, counted without being copied (out-of-band)
        try:
            stream = pickle.dumps(self.env, protocol=5, buffer_callback=buffers.append)
        except Exception:  # a lambda, a lock: deep copies may still work
            return 0.0
        size = len(stream) + sum(buffer.raw().nbytes for buffer in buffers)
        return (self.n_envs - 1) * size / 2**20

    @property
    def rewards_seen(self) -> int:
        """Interactions with a nonzero reward in the database learned on (0 before
        learning)."""
        return 0 if self.database is None else int((self.database.rewards != 0).sum())

    def _add_database(self, size: int, progress: LearnProgress) -> None:
        """Collect ``size`` interactions and add them to the database (the first chunk of the
        first database also fits the vocabulary and starts the learner). The images of one
        chunk are held at a time: each chunk is reduced to its features before the next."""
        exploring = self.learner is not None
        if self.database is not None:  # the join makes its own: not held while collecting
            self.database.drop_split_rows()
        n_envs = self.n_envs if exploring else 1
        chunks = collect_chunks(
            self.env,
            size,
            self._exploration_policy if exploring else None,
            seed=self._next_seed,
            max_blocked=(self.max_blocked or None) if exploring else None,
            n_envs=n_envs,
            on_step=progress.update,
            chunk_percepts=PERCEPTS_PER_CHUNK,
        )
        self._next_seed += n_envs  # no two databases share an episode seed
        parts, returns = [], []
        while True:
            t0 = time.perf_counter()
            transitions = next(chunks, None)
            t1 = time.perf_counter()
            self.timing["collect"] += t1 - t0
            if transitions is None:
                break
            returns.append(transitions.episode_returns)
            vocabulary = self.timing["vocabulary"]
            # Later chunks and databases: the cache holds what the policy saw.
            detected = None
            if self.extractor is None:
                detected = self._fit_vocabulary(transitions, progress)
            progress.phase("features")
            part = InteractionDatabase.build(
                transitions, self.extractor, detected, self.learner.compounds
            )
            if not self.compounds:
                part.occurrences = None  # only the compound search reads where words occur
            parts.append(part)
            fitting = self.timing["vocabulary"] - vocabulary  # SIFT and words only
            self.timing["extract"] += time.perf_counter() - t1 - fitting
            self.num_timesteps += len(transitions)
            progress.phase("collecting")
        self._log_returns(np.concatenate(returns), progress)
        # A percept seen again is held once. The join replaces the earlier database and the
        # parts, which are let go before it drops the repeats across parts: the percepts are
        # held twice at most.
        earlier = [] if self.database is None else [self.database]
        parts = [part.without_repeats() for part in parts]
        self.database = InteractionDatabase.concat(*earlier, *parts)
        del earlier, parts
        self.database = self.database.without_repeats()

    def _fit_vocabulary(self, transitions: Transitions, progress: LearnProgress) -> list:
        """SIFT on the first chunk's percepts, the vocabulary fitted on their descriptors and
        the learner made; the keypoints detected."""
        panel_widths = getattr(self.env.unwrapped, "panel_widths", ())
        percepts, detected = transitions.percepts, []
        progress.phase("SIFT")
        enlarge = self.enlarge
        if enlarge == "auto":
            enlarge = choose_enlarge(
                percepts, self.contrast_threshold, self.max_keypoints, panel_widths
            )
        keypoints = SiftExtractor(
            self.contrast_threshold, self.max_keypoints, panel_widths=panel_widths, enlarge=enlarge
        )
        met: dict = {}  # a percept met again is extracted once
        for start in range(0, len(percepts), SIFT_CHUNK):
            chunk = percepts[start : start + SIFT_CHUNK]
            detected += extract_once(met, chunk, keypoints.batch, len(percepts))
            progress.show(sift=f"{len(detected)}/{len(percepts)}")
        t0 = time.perf_counter()
        progress.phase("vocabulary")
        self.extractor = VisualFeatureExtractor.fit(
            detected=detected,
            n_words=self._vocabulary_size(detected),
            keypoints=keypoints,
            max_descriptors=VOCABULARY_SAMPLE,
            iters=10,
            groups=self.vocabulary_groups,
            seed=self.seed,
            image_shape=self.observation_space.shape,
            env_id=getattr(self.env.spec, "id", None),
        )
        self.learner = self._new_learner()
        self.timing["vocabulary"] += time.perf_counter() - t0
        return detected

    def _log_returns(self, returns: np.ndarray, progress: LearnProgress) -> None:
        """Mean return of the episodes a database's collection ended, in the bar and as SB3's
        ``rollout/ep_rew_mean`` (logged with the next stage)."""
        if len(returns):
            progress.show(ep_return=float(returns.mean()))
            self.logger.record("rollout/ep_rew_mean", float(returns.mean()))
        self.logger.record("rollout/episodes", len(returns))

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
        warn(
            f"the first database has {descriptors} SIFT descriptors, too few for "
            f"{self.n_words} words: fitting {descriptors // 2} (collect more interactions, "
            "or lower n_words)"
        )
        return descriptors // 2

    def _log_stage(self, record: StageRecord) -> None:
        prefix = self.learner_class.__name__.lower()
        for key in ("classes", "selected_features", "mean_abs_td", "splits"):
            self.logger.record(f"{prefix}/{key}", getattr(record, key))
        self.logger.record("time/total_timesteps", self.num_timesteps)
        self.logger.dump(step=record.stage)

    def _exploration_policy(self, observations: np.ndarray, rng: np.random.Generator):
        return self._explore(self._presence(observations), rng) + self._first_action

    @property
    def _first_action(self) -> int:
        """The env's id of the learner's action 0: the ``start`` of a ``Discrete`` space."""
        return int(getattr(self.action_space, "start", 0))

    # -- acting -----------------------------------------------------------------------------
    def _presence(self, images: np.ndarray) -> torch.Tensor:
        """(N, F + C) presence of the words and the learned compounds in a batch of images."""
        return self.extractor.presence(list(images), self.learner.compounds)

    def _check_learned(self) -> None:
        if self.learner is None or self.extractor is None:
            raise RuntimeError("the agent has not learned yet: call learn() or load()")

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[int | np.ndarray, None]:
        """SB3's signature: one image -> (action, None); a batch (N, ...) -> (N actions,
        None). Greedy on the learned classes; ``deterministic=False`` explores (see the
        class). ``state`` and ``episode_start`` are unused (the policy has no memory)."""
        self._check_learned()
        shape = tuple(self.observation_space.shape)
        expected = f"one image of shape {shape} or a batch (N, *{shape}) with N >= 1"
        if isinstance(observation, list | tuple):  # np.asarray would cast odd images silently
            for image in observation:
                image = np.asarray(image)
                self._check_dtype(image)
                if image.shape != shape:
                    raise ValueError(f"observation must be {expected}, got an image {image.shape}")
        images = np.asarray(observation)
        single = images.shape == shape
        if not single and (images.shape[1:] != shape or len(images) == 0):
            raise ValueError(f"observation must be {expected}, got shape {images.shape}")
        self._check_dtype(images)
        presence = self._presence(images[None] if single else images)
        actions = self._greedy(presence) if deterministic else self._explore(presence, self._rng)
        if isinstance(self.action_space, gym.spaces.Box):
            actions = actions.astype(self.action_space.dtype)
            return (actions[0] if single else actions), None
        actions = actions + self._first_action
        return (int(actions[0]) if single else actions), None

    def _check_dtype(self, images: np.ndarray) -> None:
        if images.dtype != self.observation_space.dtype:
            raise TypeError(
                f"observation must have dtype {self.observation_space.dtype}, got {images.dtype}"
            )

    # -- persistence ------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Save the vocabulary, the classes, Q and the settings (not the databases: see
        ``learn``'s ``checkpoint`` for files that learning goes on from)."""
        self._check_learned()
        save_state(path, type(self).__name__, self._state())

    def _state(self) -> dict:
        return {
            "params": {
                "n_words": self.n_words,
                "databases": self.databases,
                "alpha": self.alpha,
                "min_count": self.min_count,
                "max_stages": self.max_stages,
                "epsilon": self.epsilon,
                "n_envs": self.n_envs,
                "max_keypoints": self.max_keypoints,
                "contrast_threshold": self.contrast_threshold,
                "gamma": self.gamma,
                "seed": self.seed,
                "max_blocked": self.max_blocked,
                "enlarge": self.enlarge,
                **self._extra_params(),
            },
            "observation_shape": list(self.observation_space.shape),
            "observation_dtype": str(self.observation_space.dtype),
            "action_space": space_state(self.action_space),
            "env_id": self.env_id,
            "env_kwargs": self.env_kwargs,
            "extractor": self.extractor.state_dict(),
            "learner": self.learner.state_dict(),
            "num_timesteps": self.num_timesteps,
            "next_seed": self._next_seed,
            "tensorboard_log": self._saved_tensorboard_log,
        }

    @classmethod
    def load(
        cls, path: str | Path, env: gym.Env | None = None, tensorboard_log: str | Path | None = None
    ):
        """Load a saved agent; with ``env``, check that its spaces are the ones it learned on
        (it can then ``learn`` more). Its ``tensorboard_log`` is the one it was saved with
        unless given (set ``agent.tensorboard_log = None`` to log no more)."""
        state = load_state(path, cls.__name__)
        params = cls._params_from_state(state["params"])
        tensorboard_log = tensorboard_log or state.get("tensorboard_log")
        agent = cls(None, tensorboard_log=tensorboard_log, **params)
        dtype = np.dtype(state["observation_dtype"])
        agent.observation_space = gym.spaces.Box(0, 255, tuple(state["observation_shape"]), dtype)
        # RLVCAgent files that name the actions by their number and the learner "rlvc".
        if "action_space" in state:
            agent.action_space = space_from_state(state["action_space"])
        else:
            agent.action_space = gym.spaces.Discrete(state["n_actions"])
        agent.env_id, agent.env_kwargs = state["env_id"], state.get("env_kwargs")
        agent.extractor = VisualFeatureExtractor.from_state_dict(state["extractor"])
        learner = state["learner"] if "learner" in state else state["rlvc"]
        agent.learner = cls.learner_class.from_state_dict(learner)
        words = agent.extractor.n_features + len(agent.learner.compounds)
        if agent.learner.n_features != words:
            raise ValueError(f"{path}: its classes and vocabulary do not match (corrupt file)")
        agent.num_timesteps, agent._next_seed = state["num_timesteps"], state["next_seed"]
        if "resume" in state:  # a checkpoint of learn: its databases and what is left to do
            resume = state["resume"]
            agent.database = InteractionDatabase.from_state_dict(resume["database"])
            agent._rng.bit_generator.state = resume["rng"]
            agent._plan = resume["plan"]
        if env is not None:
            agent.set_env(env)
        return agent
