"""The interaction database that RLVC's split search reads.

Interactions (x_t, a_t, r_{t+1}, x_{t+1}, terminal) are stored as indices into a table of
unique percepts, each percept as a row of a bool feature-presence matrix. Feature extraction,
the dominant cost, runs once per percept. The split search reads the database as a sparse
(interaction, feature) COO list, so that per-class sums over all features are a few
scatter-adds (sparse products) instead of dense (interactions x features) products.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
import torch

from vistask.features import Keypoints, VisualFeatureExtractor, check_image_space

# An exploration policy maps a batch of observations (B, H, W, 3) and a generator to (B,)
# action ids: batches let a policy over visual classes extract features of many views at once.
ExplorationPolicy = Callable[[np.ndarray, np.random.Generator], np.ndarray]


def check_image_env(env: gym.Env) -> None:
    """Raise a clear error unless ``env`` has (H, W, 3) uint8 image observations and
    ``Discrete`` actions, which is what RLVC needs."""
    check_image_space(env.observation_space, "RLVC")
    if not isinstance(env.action_space, gym.spaces.Discrete):
        raise TypeError(f"RLVC needs a Discrete action space, got {env.action_space}")


@dataclass
class Transitions:
    """Raw interactions as collected: percepts (M images), and per interaction i the indices
    ``obs[i]``, ``next_obs[i]`` into ``percepts``, ``actions``, ``rewards``, ``terminal``.
    ``positions`` (M, ...) keeps ``info["position"]`` when the env reports it (plots and the
    true-grid ceiling only; the learner never reads it)."""

    percepts: list[np.ndarray]
    obs: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    next_obs: np.ndarray
    terminal: np.ndarray
    positions: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.actions)


def random_policy(n_actions: int) -> ExplorationPolicy:
    return lambda observations, rng: rng.integers(n_actions, size=len(observations))


def collect(
    env: gym.Env,
    n: int,
    policy: ExplorationPolicy | None = None,
    max_episode_steps: int = 50,
    seed: int = 0,
    max_blocked: int | None = None,
    n_envs: int = 1,
) -> Transitions:
    """Collect ``n`` interactions over episodes from the env's random starts.

    Args:
        env: image env with Discrete actions.
        n: number of interactions.
        policy: batched exploration policy (default: uniformly random actions).
        max_episode_steps: episodes are cut after this many steps (a cut is not terminal).
        seed: seeds the first reset of each env copy (``seed + i``) and the policy's generator.
        max_blocked: cut an episode after this many blocked moves in a row (the view did not
            change), so that a greedy policy stuck against a wall does not fill the database
            with copies of one interaction (None: never).
        n_envs: episodes run side by side on deep copies of ``env``, so that the policy sees
            batches of ``n_envs`` views.
    """
    check_image_env(env)
    if n < 1:
        raise ValueError(f"need at least one interaction, got n={n}")
    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    rng = np.random.default_rng(seed)
    policy = policy or random_policy(int(env.action_space.n))
    envs = [env] + [copy.deepcopy(env) for _ in range(n_envs - 1)]
    percepts: list[np.ndarray] = []
    positions: list[np.ndarray] = []
    obs_i, act, rew, next_i, term = [], [], [], [], []

    def add(obs: np.ndarray, info: dict) -> int:
        percepts.append(obs)
        if "position" in info:
            positions.append(np.asarray(info["position"]))
        return len(percepts) - 1

    # Per env copy: its view, the view's percept index, steps and blocked moves in a row.
    views, current, steps, blocked = [None] * n_envs, [0] * n_envs, [0] * n_envs, [0] * n_envs

    def start(i: int, first: bool) -> None:
        views[i], info = envs[i].reset(seed=seed + i if first else None)
        current[i], steps[i], blocked[i] = add(views[i], info), 0, 0

    for i in range(n_envs):
        start(i, first=True)
    while len(act) < n:
        actions = policy(np.stack(views), rng)
        for i, action in enumerate(actions[: n - len(act)]):
            obs, reward, terminated, truncated, info = envs[i].step(int(action))
            # A blocked move shows the same view again: store (and later extract) it once.
            same = np.array_equal(obs, views[i])
            following = current[i] if same else add(obs, info)
            obs_i.append(current[i])
            act.append(int(action))
            rew.append(reward)
            next_i.append(following)
            term.append(terminated)
            views[i], current[i] = obs, following
            steps[i], blocked[i] = steps[i] + 1, blocked[i] + 1 if same else 0
            ended = terminated or truncated or steps[i] == max_episode_steps
            if (ended or blocked[i] == max_blocked) and len(act) < n:
                start(i, first=False)
    return Transitions(
        percepts,
        np.asarray(obs_i),
        np.asarray(act),
        np.asarray(rew, dtype=np.float64),
        np.asarray(next_i),
        np.asarray(term, dtype=bool),
        np.stack(positions) if len(positions) == len(percepts) else None,
    )


@dataclass
class InteractionDatabase:
    """Interactions with feature presence, laid out for the split search.

    Attributes:
        presence: (M, F) bool, feature presence of each unique percept.
        obs, next_obs: (N,) long percept indices of x_t and x_{t+1}.
        actions: (N,) long. rewards: (N,) float64. terminal: (N,) bool.
        positions: (M, 2) true positions when the env reported them, else None (plots and the
            true-grid ceiling only; the learner never reads them).
    """

    presence: torch.Tensor
    obs: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    next_obs: torch.Tensor
    terminal: torch.Tensor
    positions: np.ndarray | None = None
    _coo: tuple[torch.Tensor, torch.Tensor] | None = field(default=None, repr=False)

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

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def n_features(self) -> int:
        return self.presence.shape[1]

    @classmethod
    def build(
        cls,
        transitions: Transitions,
        extractor: VisualFeatureExtractor,
        detected: list[Keypoints] | None = None,
    ) -> InteractionDatabase:
        """Extract features of every percept once and build the database.

        Args:
            transitions: output of ``collect``.
            extractor: the visual feature extractor (vocabulary).
            detected: keypoints of ``transitions.percepts`` if already extracted (else the
                extractor's percept cache serves the percepts that a policy has already seen).
        """
        if detected is None:
            presence = extractor.presence(transitions.percepts)
        else:
            presence = extractor.presence_of(detected)
        return cls(
            presence=presence,
            obs=torch.as_tensor(transitions.obs, dtype=torch.long),
            actions=torch.as_tensor(transitions.actions, dtype=torch.long),
            rewards=torch.as_tensor(transitions.rewards, dtype=torch.float64),
            next_obs=torch.as_tensor(transitions.next_obs, dtype=torch.long),
            terminal=torch.as_tensor(transitions.terminal, dtype=torch.bool),
            positions=transitions.positions,
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
        )

    def interaction_features(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Sparse (interaction, feature) pairs of x_t: rows (nnz,), features (nnz,), cached."""
        if self._coo is None:
            percept, feature = self.presence.nonzero(as_tuple=True)
            counts = torch.bincount(percept, minlength=len(self.presence))
            starts = torch.cumsum(counts, 0) - counts
            # For each interaction, the slice of its percept's nonzeros in the percept COO.
            sizes = counts[self.obs]
            rows = torch.repeat_interleave(torch.arange(len(self)), sizes)
            offsets = torch.arange(int(sizes.sum())) - torch.repeat_interleave(
                torch.cumsum(sizes, 0) - sizes, sizes
            )
            self._coo = (rows, feature[starts[self.obs][rows] + offsets])
        return self._coo
