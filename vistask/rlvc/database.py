"""The interaction database that the split searches of RLVC and RLJC read.

Interactions (x_t, a_t, r_{t+1}, x_{t+1}, terminal) are stored as indices into a table of
unique percepts, each percept as a row of a bool feature-presence matrix. Feature extraction,
the dominant cost, runs once per percept. The split search reads the database as a sparse
(interaction, feature) COO list, so that per-class sums over all features are a few
scatter-adds (sparse products) instead of dense (interactions x features) products.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import gymnasium as gym
import numpy as np
import torch

from vistask.checks import checked
from vistask.features import (
    Compound,
    Keypoints,
    Occurrences,
    VisualFeatureExtractor,
    add_compound_occurrences,
    check_image_space,
)
from vistask.features.compounds import concatenated_ranges
from vistask.memory import base_pages

# An exploration policy maps a batch of observations (B, H, W, 3) and a generator to (B,)
# action ids, or (B, m) continuous actions: batches let a policy over visual classes extract
# features of many views at once.
ExplorationPolicy = Callable[[np.ndarray, np.random.Generator], np.ndarray]


@checked
def check_image_env(env: gym.Env, continuous: bool = False) -> None:
    """Raise a clear error unless ``env`` has (H, W, 3) uint8 image observations and the
    actions that the learner needs: ``Discrete`` for RLVC, a bounded 1-D ``Box`` for RLJC
    (``continuous``)."""
    learner = "RLJC" if continuous else "RLVC"
    spec = getattr(env, "spec", None)
    if spec is not None:
        learner = f"{learner} (on {spec.id})"
    check_image_space(env.observation_space, learner)
    space = env.action_space
    if not continuous and not isinstance(space, gym.spaces.Discrete):
        hint = " (RLJCAgent learns continuous actions)" if isinstance(space, gym.spaces.Box) else ""
        raise TypeError(f"RLVC needs a Discrete action space, got {space}{hint}")
    if continuous and not (
        isinstance(space, gym.spaces.Box) and len(space.shape) == 1 and space.is_bounded()
    ):
        hint = (
            " (RLVCAgent learns discrete actions)" if isinstance(space, gym.spaces.Discrete) else ""
        )
        raise TypeError(f"RLJC needs a bounded Box action space of shape (m,), got {space}{hint}")
    if continuous and not np.issubdtype(space.dtype, np.floating):
        raise TypeError(
            f"RLJC needs a float action space (it splits actions at thresholds), got {space}"
        )
    if continuous and not (space.shape[0] >= 1 and bool(np.all(space.low < space.high))):
        raise ValueError(
            f"RLJC needs an action space with low < high in every dimension, got {space}"
        )


@checked
@dataclass
class Transitions:
    """Raw interactions as collected: percepts (M images), and per interaction i the indices
    ``obs[i]``, ``next_obs[i]`` into ``percepts``, ``actions``, ``rewards``, ``terminal``.
    ``positions`` (M, ...) keeps ``info["position"]`` when the env reports it (plots and the
    true-grid ceiling only; the learner never reads it); ``episode_returns`` the undiscounted
    return of each episode that ended during collection."""

    percepts: list[np.ndarray]
    obs: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    next_obs: np.ndarray
    terminal: np.ndarray
    positions: np.ndarray | None = None
    episode_returns: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.actions)


@checked
def random_policy(space: gym.spaces.Discrete | gym.spaces.Box) -> ExplorationPolicy:
    """Uniformly random actions for a batch of observations: (B,) ids of a ``Discrete`` space,
    or (B, m) points of a bounded ``Box``."""
    if isinstance(space, gym.spaces.Box):
        low, high = space.low.astype(np.float64), space.high.astype(np.float64)
        return lambda observations, rng: rng.uniform(
            low, high, size=(len(observations), *low.shape)
        )
    n, start = int(space.n), int(space.start)
    return lambda observations, rng: start + rng.integers(n, size=len(observations))


@checked
def vector_copies(env: gym.Env, n_envs: int) -> gym.vector.VectorEnv:
    """``n_envs`` copies of ``env`` as one vector env without autoreset.

    An env whose unwrapped class steps copies of itself as one batch (defines ``vector_copies``,
    as the visual maze does) gets those, with ``gym.make``'s time limit, unless other wrappers
    surround it or it is a subclass (their changes would be lost); any other env is copied
    into a ``SyncVectorEnv`` (``_copy``).
    """
    inner, spec = env.unwrapped, env.spec
    only_make_wrappers = env is inner or (spec is not None and not spec.additional_wrappers)
    if only_make_wrappers and "vector_copies" in vars(type(inner)):
        limit = None if env is inner else spec.max_episode_steps  # a wrapper has a spec here
        return inner.vector_copies(n_envs, limit)
    copies = [env] + [_copy(env) for _ in range(n_envs - 1)]
    return gym.vector.SyncVectorEnv(
        [lambda e=e: e for e in copies], autoreset_mode=gym.vector.AutoresetMode.DISABLED
    )


def _copy(env: gym.Env) -> gym.Env:
    """A fresh env like ``env``: made again from its spec (wrappers included) where it has
    one, since renderers (pygame, MuJoCo) do not deep-copy; else a deep copy."""
    if env.spec is not None:
        try:
            return gym.make(env.spec)
        except Exception:  # a wrapper that does not record its arguments, say
            pass
    return copy.deepcopy(env)


@checked
@base_pages()  # each call runs inside the block
def collect(
    env: gym.Env,
    n: int,
    policy: ExplorationPolicy | None = None,
    seed: int = 0,
    max_blocked: int | None = None,
    n_envs: int = 1,
    on_step: Callable[[int], None] | None = None,
) -> Transitions:
    """Collect ``n`` interactions over episodes from the env's random starts.

    An episode ends when the env terminates or truncates it (its own time limit, e.g. the
    ``max_episode_steps`` of ``gym.make``), or after ``max_blocked`` blocked moves in a row.

    Args:
        env: image env with Discrete actions, or continuous ones (a bounded 1-D Box).
        n: number of interactions.
        policy: batched exploration policy (default: uniformly random actions).
        seed: seeds the first reset of each env copy (``seed + i``) and the policy's generator.
        max_blocked: cut an episode after this many blocked moves in a row (the view did not
            change), so that a greedy policy stuck against a wall does not fill the database
            with copies of one interaction (None: never).
        n_envs: episodes run side by side on copies of ``env`` (``vector_copies``), so that the
            policy sees batches of ``n_envs`` views.
        on_step: called with the number of interactions added after each step of the copies
            (a progress bar's ``update``).
    """
    continuous = isinstance(env.action_space, gym.spaces.Box)
    check_image_env(env, continuous)
    if n < 1:
        raise ValueError(f"need at least one interaction, got n={n}")
    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    rng = np.random.default_rng(seed)
    policy = policy or random_policy(env.action_space)
    envs = vector_copies(env, n_envs)
    percepts: list[np.ndarray] = []
    positions: list[np.ndarray] = []
    obs_i, act, rew, next_i, term = [], [], [], [], []

    def add(obs: np.ndarray, infos: dict, i: int) -> int:
        percepts.append(obs)
        if "position" in infos:
            positions.append(np.asarray(infos["position"][i]))
        return len(percepts) - 1

    # Per env copy: the percept index of its view and its blocked moves in a row.
    views, infos = envs.reset(seed=[seed + i for i in range(n_envs)])
    current = [add(views[i], infos, i) for i in range(n_envs)]
    blocked = np.zeros(n_envs, dtype=int)
    returns, episode_returns = np.zeros(n_envs), []
    while len(act) < n:
        actions = np.asarray(policy(views, rng))
        obs, rewards, terminated, truncated, infos = envs.step(actions)
        # A blocked move shows the same view again: store (and later extract) it once.
        same = (obs == views).reshape(n_envs, -1).all(axis=1)
        added = min(n_envs, n - len(act))  # the last round may need fewer
        for i in range(added):
            following = current[i] if same[i] else add(obs[i], infos, i)
            obs_i.append(current[i])
            act.append(actions[i])
            rew.append(float(rewards[i]))
            next_i.append(following)
            term.append(bool(terminated[i]))
            current[i] = following
            returns[i] += float(rewards[i])
        if on_step is not None:
            on_step(added)
        blocked = np.where(same, blocked + 1, 0)
        ended = terminated | truncated | (blocked == max_blocked)
        episode_returns.extend(returns[:added][ended[:added]])
        returns[ended] = 0.0
        views = obs
        if ended.any() and len(act) < n:
            views, infos = envs.reset(options={"reset_mask": ended})
            for i in np.flatnonzero(ended):
                current[i] = add(views[i], infos, i)
            blocked[ended] = 0
    return Transitions(
        percepts,
        np.asarray(obs_i),
        # A (B,) batch of 1-D continuous actions is as valid as (B, 1): keep the space's shape.
        np.asarray(act, np.float64).reshape(len(act), -1) if continuous else np.asarray(act),
        np.asarray(rew, dtype=np.float64),
        np.asarray(next_i),
        np.asarray(term, dtype=bool),
        np.stack(positions) if len(positions) == len(percepts) else None,
        np.asarray(episode_returns, dtype=np.float64),
    )


@dataclass
class ColumnRoom:
    """A (M, capacity) bool buffer whose first ``used`` columns hold a presence matrix, with
    spare columns after them.

    A compound search adds a few presence columns at a time, dozens of times in a run, and a
    copy of the whole presence for each took 0.17-0.19 s on the mountain car's (44,000,
    8,282), about 50 times a run.
    """

    buffer: torch.Tensor
    used: int

    SPARE = 128

    @classmethod
    def append(
        cls, presence: torch.Tensor, columns: torch.Tensor, room: ColumnRoom | None
    ) -> tuple[torch.Tensor, ColumnRoom]:
        """``presence`` (M, F) with ``columns`` (M, C) after it (a view of the room's buffer),
        and the room. The columns go into ``room``'s spare columns when ``presence`` is its
        filled part; otherwise (no room yet, a full one, or one that a database sharing it
        has filled further) into a new room."""
        m, f = presence.shape
        c = columns.shape[1]
        if (
            room is None
            or room.used != f
            or room.buffer.data_ptr() != presence.data_ptr()
            or f + c > room.buffer.shape[1]
        ):
            room = cls(torch.empty(m, f + c + cls.SPARE, dtype=torch.bool), f)
            room.buffer[:, :f] = presence
        room.buffer[:, f : f + c] = columns
        room.used = f + c
        return room.buffer[:, : f + c], room


@checked
@dataclass
class InteractionDatabase:
    """Interactions with feature presence, laid out for the split search.

    Attributes:
        presence: (M, F) bool, feature presence of each unique percept.
        obs, next_obs: (N,) long percept indices of x_t and x_{t+1}.
        actions: (N,) long action ids, or (N, m) float64 continuous actions.
        rewards: (N,) float64. terminal: (N,) bool.
        positions: (M, 2) true positions when the env reported them, else None (plots and the
            true-grid ceiling only; the learner never reads them).
        occurrences: where each feature occurs in each percept (compounds included), for the
            compound search; None when only presence is known.
    """

    presence: torch.Tensor
    obs: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    next_obs: torch.Tensor
    terminal: torch.Tensor
    positions: np.ndarray | None = None
    occurrences: Occurrences | None = None
    _coo: tuple[torch.Tensor, torch.Tensor] | None = field(default=None, repr=False)
    _room: ColumnRoom | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        n = len(self.actions)
        if n == 0:
            raise ValueError("the interaction database is empty: collect some interactions first")
        if not all(len(t) == n for t in (self.obs, self.rewards, self.next_obs, self.terminal)):
            raise ValueError("obs, actions, rewards, next_obs and terminal need one entry each")
        m = len(self.presence)
        indices = torch.cat([self.obs, self.next_obs])
        if indices.min() < 0 or indices.max() >= m:
            raise ValueError(f"percept indices must lie in 0..{m - 1}")
        if self.occurrences is not None and self.occurrences.n_images != m:
            raise ValueError(f"occurrences are of {self.occurrences.n_images} percepts, not {m}")

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def n_features(self) -> int:
        """Number of visual features (the vocabulary's words; compounds come after them)."""
        return self.presence.shape[1]

    @classmethod
    def build(
        cls,
        transitions: Transitions,
        extractor: VisualFeatureExtractor,
        detected: list[Keypoints] | None = None,
        compounds: Sequence[Compound] = (),
    ) -> InteractionDatabase:
        """Extract features of every percept once and build the database.

        Args:
            transitions: output of ``collect``.
            extractor: the visual feature extractor (vocabulary).
            detected: keypoints of ``transitions.percepts`` if already extracted (else the
                extractor's percept cache serves the percepts that a policy has already seen).
            compounds: compound features learned so far, feature ids after the vocabulary's.
        """
        if detected is None:
            occurrences = extractor.occurrences(transitions.percepts, compounds)
        else:
            occurrences = extractor.occurrences_of(detected, compounds)
        return cls(
            presence=occurrences.presence(extractor.n_features + len(compounds)),
            obs=torch.as_tensor(transitions.obs, dtype=torch.long),
            actions=torch.as_tensor(
                transitions.actions,
                dtype=torch.float64 if transitions.actions.dtype.kind == "f" else torch.long,
            ),
            rewards=torch.as_tensor(transitions.rewards, dtype=torch.float64),
            next_obs=torch.as_tensor(transitions.next_obs, dtype=torch.long),
            terminal=torch.as_tensor(transitions.terminal, dtype=torch.bool),
            positions=transitions.positions,
            occurrences=occurrences,
        )

    @classmethod
    def concat(cls, first: InteractionDatabase, second: InteractionDatabase) -> InteractionDatabase:
        """Both databases' interactions in one (same vocabulary; percepts are not merged)."""
        if first.n_features != second.n_features:
            raise ValueError(
                f"cannot join databases over {first.n_features} and {second.n_features} features"
            )
        m = len(first.presence)
        has_positions = first.positions is not None and second.positions is not None
        has_occurrences = first.occurrences is not None and second.occurrences is not None
        if (first.occurrences is None) != (second.occurrences is None):
            raise ValueError(
                "cannot join a database that keeps feature occurrences with one that does not"
            )
        return cls(
            presence=torch.cat([first.presence, second.presence]),
            obs=torch.cat([first.obs, second.obs + m]),
            actions=torch.cat([first.actions, second.actions]),
            rewards=torch.cat([first.rewards, second.rewards]),
            next_obs=torch.cat([first.next_obs, second.next_obs + m]),
            terminal=torch.cat([first.terminal, second.terminal]),
            positions=np.concatenate([first.positions, second.positions])
            if has_positions
            else None,
            occurrences=Occurrences.concat([first.occurrences, second.occurrences])
            if has_occurrences
            else None,
        )

    def take(self, index: torch.Tensor) -> InteractionDatabase:
        """The interactions ``index`` (N',) long, repeats allowed, over the same percepts."""
        columns = ("obs", "actions", "rewards", "next_obs", "terminal")
        return replace(self, **{k: getattr(self, k)[index] for k in columns}, _coo=None)

    def state_dict(self) -> dict:
        """Plain tensors for a checkpoint; presence as its (2, nnz) nonzero indices (a percept
        shows a few dozen of thousands of features)."""
        rows, cols = self.presence.nonzero(as_tuple=True)
        occ = self.occurrences
        return {
            "presence_shape": list(self.presence.shape),
            "present": torch.stack([rows, cols]).int(),
            **{k: getattr(self, k) for k in ("obs", "actions", "rewards", "next_obs", "terminal")},
            "positions": None if self.positions is None else torch.from_numpy(self.positions),
            "occurrences": None
            if occ is None
            else {
                **{
                    k: torch.from_numpy(getattr(occ, k))
                    for k in ("image", "feature", "xy", "scale", "part")
                },
                "n_images": occ.n_images,
            },
        }

    @classmethod
    def from_state_dict(cls, state: dict) -> InteractionDatabase:
        """The database of ``state_dict()``."""
        presence = torch.zeros(state["presence_shape"], dtype=torch.bool)
        presence[state["present"][0].long(), state["present"][1].long()] = True
        occ = state["occurrences"]
        return cls(
            presence=presence,
            **{k: state[k] for k in ("obs", "actions", "rewards", "next_obs", "terminal")},
            positions=None if state["positions"] is None else state["positions"].numpy(),
            occurrences=None
            if occ is None
            else Occurrences(
                occ["image"].numpy(),
                occ["feature"].numpy(),
                occ["xy"].numpy(),
                occ["scale"].numpy(),
                occ["n_images"],
                occ["part"].numpy(),
            ),
        )

    def add_compounds(self, compounds: list[Compound]) -> None:
        """Add compound features as the next feature ids (their occurrences and presence)."""
        if self.occurrences is None:
            raise ValueError("this database keeps no feature occurrences: compounds need them")
        first = self.n_features
        self.occurrences = add_compound_occurrences(self.occurrences, compounds, first)
        new = self.occurrences.take(self.occurrences.feature >= first)
        new.feature = new.feature - first
        added = new.presence(len(compounds))
        self.presence, self._room = ColumnRoom.append(self.presence, added, self._room)
        if self._coo is not None:
            # The compounds' pairs go after the others, not in row order: the split search
            # sums each feature's pairs in their order, and each feature's pairs keep theirs.
            # Finding every pair again costs a pass over the whole (M, F) presence.
            rows, features = interaction_pairs(added, self.obs)
            self._coo = (
                torch.cat([self._coo[0], rows]),
                torch.cat([self._coo[1], features + first]),
            )

    def interaction_features(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Sparse (interaction, feature) pairs of x_t: rows (nnz,), features (nnz,), cached;
        each feature's pairs in the order of their interactions."""
        if self._coo is None:
            self._coo = interaction_pairs(self.presence, self.obs)
        return self._coo


def interaction_pairs(
    presence: torch.Tensor, obs: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The (interaction, feature) pairs of the percepts ``obs`` (N,) whose features are
    ``presence`` (M, F): rows (nnz,) and features (nnz,), by interaction then feature."""
    percept, feature = presence.nonzero(as_tuple=True)
    counts = torch.bincount(percept, minlength=len(presence))
    starts = torch.cumsum(counts, 0) - counts
    # For each interaction, the slice of its percept's nonzeros in the percept COO.
    sizes = counts[obs]
    rows = torch.repeat_interleave(torch.arange(len(obs)), sizes)
    return rows, feature[torch.from_numpy(concatenated_ranges(starts[obs].numpy(), sizes.numpy()))]
