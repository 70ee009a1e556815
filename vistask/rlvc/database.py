"""The interaction database that the split searches of RLVC and RLJC read.

Interactions (x_t, a_t, r_{t+1}, x_{t+1}, terminal) are stored as indices into a table of
unique percepts, each percept as a row of a feature-presence matrix held as bits. Feature
extraction, the dominant cost, runs once per percept. The split search reads the database as
a sparse (interaction, feature) COO list, so that per-class sums over all features are a few
scatter-adds (sparse products) instead of dense (interactions x features) products; where the
interactions repeat their (percept, action) pairs, as views drawn from a bank do, it reads
each distinct pair once.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator, Sequence
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
from vistask.rlvc.copies import vector_copies
from vistask.rlvc.presence import PackedPresence

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
    return next(collect_chunks(env, n, policy, seed, max_blocked, n_envs, on_step))


@checked
def collect_chunks(
    env: gym.Env,
    n: int,
    policy: ExplorationPolicy | None = None,
    seed: int = 0,
    max_blocked: int | None = None,
    n_envs: int = 1,
    on_step: Callable[[int], None] | None = None,
    chunk_percepts: int | None = None,
) -> Iterator[Transitions]:
    """``collect``'s ``n`` interactions as a sequence of ``Transitions`` of at most about
    ``chunk_percepts`` percepts each (None: one), so that a caller that reduces each chunk to
    features holds the images of one chunk at a time. The episodes are those of one
    ``collect`` call: an episode going on at the end of a chunk goes on in the next, whose
    percepts start with the copies' current views. Arguments as in ``collect``.

    Example:
        >>> for part in collect_chunks(env, 600_000, chunk_percepts=16_384):
        ...     databases.append(InteractionDatabase.build(part, extractor))
    """
    continuous = isinstance(env.action_space, gym.spaces.Box)
    check_image_env(env, continuous)
    if n < 1:
        raise ValueError(f"need at least one interaction, got n={n}")
    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    if chunk_percepts is not None and chunk_percepts < n_envs:
        raise ValueError(f"chunk_percepts must be >= n_envs ({n_envs}), got {chunk_percepts}")
    rng = np.random.default_rng(seed)
    policy = policy or random_policy(env.action_space)
    # Interactions keep action ids 0..n-1 of a Discrete(n, start) space: the learner's rows.
    first_action = 0 if continuous else int(env.action_space.start)
    envs = vector_copies(env, n_envs)
    chunk = _Chunk(continuous)
    # Per env copy: the percept index of its view and its blocked moves in a row.
    with base_pages():
        views, infos = envs.reset(seed=[seed + i for i in range(n_envs)])
    current = [chunk.add(views[i], infos, i) for i in range(n_envs)]
    blocked = np.zeros(n_envs, dtype=int)
    returns, collected = np.zeros(n_envs), 0
    while collected < n:
        with base_pages():  # released at each yield: the caller's setting between chunks
            actions = np.asarray(policy(views, rng))
            obs, rewards, terminated, truncated, infos = envs.step(actions)
            if not np.isfinite(rewards).all():
                raise ValueError(
                    f"{env.unwrapped} returned the reward {rewards[~np.isfinite(rewards)][0]}: "
                    "rewards must be finite numbers"
                )
            # A blocked move shows the same view again: store (and later extract) it once.
            same = (obs == views).reshape(n_envs, -1).all(axis=1)
            added = min(n_envs, n - collected)  # the last round may need fewer
            for i in range(added):
                following = current[i] if same[i] else chunk.add(obs[i], infos, i)
                chunk.link(
                    current[i], actions[i] - first_action, rewards[i], following, terminated[i]
                )
                current[i] = following
                returns[i] += float(rewards[i])
            collected += added
            if on_step is not None:
                on_step(added)
            blocked = np.where(same, blocked + 1, 0)
            ended = terminated | truncated | (blocked == max_blocked)
            chunk.episode_returns.extend(returns[:added][ended[:added]])
            returns[ended] = 0.0
            views = obs
            if ended.any() and collected < n:
                views, infos = envs.reset(options={"reset_mask": ended})
                for i in np.flatnonzero(ended):
                    current[i] = chunk.add(views[i], infos, i)
                blocked[ended] = 0
        if chunk_percepts is not None and len(chunk.percepts) >= chunk_percepts and collected < n:
            done, chunk = chunk, _Chunk(continuous)
            current = [chunk.carry(done, k) for k in current]
            yield done.transitions()
    yield chunk.transitions()


def _position(infos: dict, i: int) -> np.ndarray | None:
    """Copy ``i``'s ``info["position"]`` where it is a number or an array of numbers, else None
    (an env's own ``position`` of another kind is not the agent's business)."""
    try:
        position = np.asarray(infos["position"][i])
    except (KeyError, IndexError, TypeError, ValueError):
        return None
    return position if position.dtype.kind in "biuf" else None


class _Chunk:
    """The percepts and interactions of one chunk of ``collect_chunks``, as they come."""

    def __init__(self, continuous: bool) -> None:
        self.continuous = continuous
        self.percepts: list[np.ndarray] = []
        self.positions: list[np.ndarray] | None = []  # None: some view had no numeric one
        self.obs, self.actions, self.rewards, self.next_obs, self.terminal = [], [], [], [], []
        self.episode_returns: list[float] = []

    def add(self, view: np.ndarray, infos: dict, i: int) -> int:
        """Add copy ``i``'s view (``infos``: the copies' infos); its percept index."""
        self.percepts.append(view)
        self._keep_position(_position(infos, i))
        return len(self.percepts) - 1

    def carry(self, other: _Chunk, k: int) -> int:
        """Add percept ``k`` of ``other`` (a copy's view when ``other`` ended); its index."""
        self.percepts.append(other.percepts[k])
        self._keep_position(None if other.positions is None else other.positions[k])
        return len(self.percepts) - 1

    def _keep_position(self, position: np.ndarray | None) -> None:
        """Keep the position of the view just added while every view has one of one shape."""
        if self.positions is None:
            return
        if position is None or (self.positions and position.shape != self.positions[0].shape):
            self.positions = None
        else:
            self.positions.append(position)

    def link(self, obs: int, action, reward, next_obs: int, terminal) -> None:
        """Add the interaction from percept ``obs`` to percept ``next_obs``."""
        self.obs.append(obs)
        self.actions.append(action)
        self.rewards.append(float(reward))
        self.next_obs.append(next_obs)
        self.terminal.append(bool(terminal))

    def transitions(self) -> Transitions:
        """The chunk as ``Transitions``."""
        actions = np.asarray(self.actions, np.float64 if self.continuous else None)
        return Transitions(
            self.percepts,
            np.asarray(self.obs, dtype=np.int64),
            # A (B,) batch of 1-D continuous actions is as valid as (B, 1): keep the space's
            # shape.
            actions.reshape(len(actions), -1) if self.continuous else actions,
            np.asarray(self.rewards, dtype=np.float64),
            np.asarray(self.next_obs, dtype=np.int64),
            np.asarray(self.terminal, dtype=bool),
            None if self.positions is None else np.stack(self.positions),
            np.asarray(self.episode_returns, dtype=np.float64),
        )


@checked
@dataclass
class InteractionDatabase:
    """Interactions with feature presence, laid out for the split search.

    Attributes:
        presence: (M, F) feature presence of each unique percept, held as bits
            (``PackedPresence``; a bool tensor given here is packed).
        obs, next_obs: (N,) long percept indices of x_t and x_{t+1}.
        actions: (N,) long action ids, or (N, m) float64 continuous actions.
        rewards: (N,) float64. terminal: (N,) bool.
        positions: (M, 2) true positions when the env reported them, else None (plots and the
            true-grid ceiling only; the learner never reads them).
        occurrences: where each feature occurs in each percept (compounds included), for the
            compound search; None when only presence is known.
        counts: (M,) long, the times each percept was met (None: once each;
            ``without_repeats`` holds a repeated percept once and counts it).
    """

    presence: PackedPresence | torch.Tensor
    obs: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    next_obs: torch.Tensor
    terminal: torch.Tensor
    positions: np.ndarray | None = None
    occurrences: Occurrences | None = None
    counts: torch.Tensor | None = None
    _coo: tuple[torch.Tensor, torch.Tensor] | None = field(default=None, repr=False)
    _pairs: tuple[torch.Tensor, ...] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if isinstance(self.presence, torch.Tensor):
            if self.presence.ndim != 2 or self.presence.dtype != torch.bool:
                raise ValueError(
                    f"presence must be (M, F) bool, got {tuple(self.presence.shape)} "
                    f"{self.presence.dtype}"
                )
            self.presence = PackedPresence.from_dense(self.presence)
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
        if self.counts is not None and (self.counts.shape != (m,) or self.counts.min() < 1):
            raise ValueError(f"counts must be (M,) = ({m},) positive, got {self.counts}")

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def percept_counts(self) -> torch.Tensor:
        """(M,) long, the times each percept was met."""
        if self.counts is None:
            return torch.ones(len(self.presence), dtype=torch.long)
        return self.counts

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
            presence=PackedPresence.from_pairs(
                occurrences.image,
                occurrences.feature,
                occurrences.n_images,
                extractor.n_features + len(compounds),
            ),
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
    def concat(cls, *databases: InteractionDatabase) -> InteractionDatabase:
        """The databases' interactions in one, in order (same vocabulary; percepts are not
        merged)."""
        widths = sorted({db.n_features for db in databases})
        if len(widths) != 1:
            raise ValueError(
                f"cannot join databases over {' and '.join(map(str, widths))} features"
            )
        if len({db.occurrences is None for db in databases}) != 1:
            raise ValueError(
                "cannot join a database that keeps feature occurrences with one that does not"
            )
        # Percept indices of each database after the percepts of those before it.
        offsets = np.cumsum([0] + [len(db.presence) for db in databases[:-1]]).tolist()
        positions = [db.positions for db in databases]
        occurrences = [db.occurrences for db in databases]
        return cls(
            presence=PackedPresence.concat([db.presence for db in databases]),
            obs=torch.cat([db.obs + m for db, m in zip(databases, offsets, strict=True)]),
            actions=torch.cat([db.actions for db in databases]),
            rewards=torch.cat([db.rewards for db in databases]),
            next_obs=torch.cat([db.next_obs + m for db, m in zip(databases, offsets, strict=True)]),
            terminal=torch.cat([db.terminal for db in databases]),
            positions=None if any(p is None for p in positions) else np.concatenate(positions),
            occurrences=None
            if any(o is None for o in occurrences)
            else Occurrences.concat(occurrences),
            counts=None
            if all(db.counts is None for db in databases)
            else torch.cat([db.percept_counts for db in databases]),
        )

    def without_repeats(self) -> InteractionDatabase:
        """The same interactions, each percept that repeats an earlier one (the same features
        and position) held once, in the order they were first seen, with the times it was met
        in ``counts``; a database that keeps feature occurrences as it is (equal features may
        lie in other places).

        An env that draws its views from a bank (place navigation) shows the same percepts
        again and again: its database then grows with the views, not the interactions.
        """
        if self.occurrences is not None:
            return self
        packed = self.presence.numpy().packed
        place = [b""] * len(packed)
        if self.positions is not None:
            place = [p.tobytes() for p in np.asarray(self.positions, dtype=np.float64)]
        # Rows compared by 128-bit digests: sorting the rows themselves copied them twice.
        digests = np.array(
            [
                hashlib.blake2b(row.tobytes() + at, digest_size=16).digest()
                for row, at in zip(packed, place, strict=True)
            ],
            dtype="V16",
        )
        _, first, inverse = np.unique(digests, return_index=True, return_inverse=True)
        if len(first) == len(packed):
            return self
        order = np.argsort(first)  # distinct percepts by first appearance
        new_id = np.empty(len(first), dtype=np.int64)
        new_id[order] = np.arange(len(first))
        percept = torch.from_numpy(new_id[inverse.ravel()])
        kept = first[order]
        counts = torch.zeros(len(kept), dtype=torch.long)
        return replace(
            self,
            presence=PackedPresence(packed[kept], self.n_features),
            obs=percept[self.obs],
            next_obs=percept[self.next_obs],
            positions=None if self.positions is None else self.positions[kept],
            counts=counts.index_add_(0, percept, self.percept_counts),
            _coo=None,
            _pairs=None,
        )

    def take(self, index: torch.Tensor) -> InteractionDatabase:
        """The interactions ``index`` (N',) long, repeats allowed, over the same percepts."""
        columns = ("obs", "actions", "rewards", "next_obs", "terminal")
        return replace(
            self, **{k: getattr(self, k)[index] for k in columns}, _coo=None, _pairs=None
        )

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
            "counts": self.counts,
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
        occ = state["occurrences"]
        return cls(
            presence=PackedPresence.from_pairs(
                state["present"][0].numpy(), state["present"][1].numpy(), *state["presence_shape"]
            ),
            **{k: state[k] for k in ("obs", "actions", "rewards", "next_obs", "terminal")},
            positions=None if state["positions"] is None else state["positions"].numpy(),
            counts=state.get("counts"),  # files saved before counts held each percept once
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
        self.presence = self.presence.with_columns(added)
        # The compounds' pairs go after the others, not in row order: the split search sums
        # each feature's pairs in their order, and each feature's pairs keep theirs. Finding
        # every pair again costs a pass over the whole (M, F) presence.
        if self._coo is not None:
            self._coo = _with_pairs_of(added, self.obs, first, *self._coo)
        if self._pairs is not None:
            pair, percept, rows, features = self._pairs
            self._pairs = (pair, percept, *_with_pairs_of(added, percept, first, rows, features))

    def drop_split_rows(self) -> None:
        """Forget the split search's cached sparse pairs (``split_rows``); they are made again
        when next asked for."""
        self._coo = self._pairs = None

    def interaction_features(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Sparse (interaction, feature) pairs of x_t: rows (nnz,), features (nnz,), cached;
        each feature's pairs in the order of their interactions."""
        if self._coo is None:
            self._coo = interaction_pairs(self.presence, self.obs)
        return self._coo

    def split_rows(self) -> tuple[torch.Tensor | None, torch.Tensor, torch.Tensor]:
        """The rows that the split search reads, with their sparse features: the distinct
        (x_t, action) pairs (``percept_action_features``) where the interactions repeat them
        twice or more on average, else the interactions (``interaction_features``; pair None).
        """
        if self.actions.ndim == 1 and 2 * len(torch.unique(self._pair_keys())) <= len(self):
            return self.percept_action_features()
        return None, *self.interaction_features()

    def percept_action_features(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Each distinct (x_t, action) pair of the interactions once, with the sparse features
        of its percept, cached (discrete actions).

        Returns:
            pair (N,) long, the pair of each interaction; rows (nnz,) and features (nnz,), the
            features of each pair's percept, by pair then feature.
        """
        if self._pairs is None:
            distinct, pair = torch.unique(self._pair_keys(), return_inverse=True)
            percept = torch.zeros(len(distinct), dtype=torch.long).scatter_(0, pair, self.obs)
            self._pairs = (pair, percept, *interaction_pairs(self.presence, percept))
        pair, _, rows, features = self._pairs
        return pair, rows, features

    def _pair_keys(self) -> torch.Tensor:
        if self.actions.ndim != 1:
            raise ValueError("percept-action pairs need discrete actions, got (N, m) actions")
        low = int(self.actions.min())
        return self.obs * (int(self.actions.max()) - low + 1) + self.actions - low


def _with_pairs_of(
    added: torch.Tensor, obs: torch.Tensor, first: int, rows: torch.Tensor, features: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """The sparse pairs ``rows``, ``features`` (nnz,) of percepts ``obs``, followed by those of
    the ``added`` (M, C) columns, numbered from ``first``."""
    more_rows, more_features = interaction_pairs(added, obs)
    return torch.cat([rows, more_rows]), torch.cat([features, more_features + first])


def interaction_pairs(
    presence: PackedPresence | torch.Tensor, obs: torch.Tensor
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
