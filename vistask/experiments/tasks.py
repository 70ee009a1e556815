"""The envs that have an oracle, seen alike by the experiments: fixed evaluation starts, the
oracle's return from them, a batched evaluation of any policy, and the true-state cells that the
privileged tabular baseline learns on. Any other env is an ``EpisodeTask``: seeded episodes,
no oracle.

Example:
    >>> task = task_for("vistask/VisualMountainCar-v0")
    >>> task.evaluate(lambda percepts, states: agent.predict(percepts)[0]).mean / task.oracle_return
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

import vistask.envs  # noqa: F401  (registers the environments)
from vistask.checks import check_at_least
from vistask.envs import (
    MazeOracle,
    VisualMazeContinuousEnv,
    VisualMazeEnv,
    evaluate_policy,
    start_positions,
)
from vistask.envs.car_oracle import CarOracle, evaluate_car_policy, start_states
from vistask.envs.maze_oracle import EvaluationResult, Policy, grid_cells
from vistask.envs.maze_plots import grid_positions
from vistask.envs.mountain_car import MAX_POSITION, MAX_SPEED, VisualMountainCarEnv
from vistask.envs.place_navigation import PlaceNavigationEnv
from vistask.envs.place_oracle import PlaceOracle

ORACLE_DIRECTIONS = 32  # the continuous-direction maze's oracle picks among these many angles
# The maze's test set: an action is optimal within this share of the range of optimal values
# (the oracle's action values come from sampled noise: exact ties are rare).
OPTIMAL_WITHIN = 0.01


class MazeTask:
    """The visual maze: starts are free positions, the true state is the position. The oracle
    of the continuous-direction maze moves in ``ORACLE_DIRECTIONS`` directions."""

    def __init__(self, env: VisualMazeEnv, eval_starts: int = 100) -> None:
        self.env = env
        self.starts = start_positions(env.geometry, eval_starts)
        continuous = isinstance(env, VisualMazeContinuousEnv)
        directions = ORACLE_DIRECTIONS if continuous else None
        self.oracle = MazeOracle.solve(env.geometry, n_directions=directions)
        self.oracle_return = self.evaluate(self.oracle.as_policy()).mean

    def evaluate(self, policy: Policy) -> EvaluationResult:
        """Discounted returns of a batched ``policy(percepts, positions)`` from the starts."""
        return evaluate_policy(self.env, policy, self.starts)

    def cells(self, states: np.ndarray, grid: int) -> np.ndarray:
        """(N,) cell of each true position (N, 2) on a ``grid`` x ``grid`` grid."""
        return grid_cells(states, self.env.geometry.size, grid)

    def unit(self, states: np.ndarray) -> np.ndarray:
        """(N, 2) true positions scaled to the unit square."""
        return np.asarray(states, dtype=float).reshape(-1, 2) / self.env.geometry.size

    @staticmethod
    def true_state(env: gym.Env) -> np.ndarray:
        """The true state of ``env`` (for oracles and the true-grid baseline)."""
        return env.unwrapped.position

    def test_set(self, grid: int = 30) -> tuple[np.ndarray, np.ndarray]:
        """Percepts (N, H, W, 3) at the free points of a ``grid`` x ``grid`` grid of true
        positions, and (N, A) bool: the oracle's moves (4 actions, or its directions on the
        continuous maze) optimal there (within ``OPTIMAL_WITHIN``)."""
        points = grid_positions(self.env, grid)
        points = points[self.env.geometry.is_free(points)]
        q = self.oracle.q[(slice(None), *self.oracle.cell(points))].T  # (N, 4)
        values = self.oracle.values
        slack = OPTIMAL_WITHIN * (values.max() - values.min())
        optimal = q >= q.max(axis=1, keepdims=True) - slack
        return np.stack([self.env.percept_at(p) for p in points]), optimal


class CarTask:
    """The visual mountain car: starts are (position, velocity) pairs from which the goal can
    be reached, the true state is (position, velocity)."""

    def __init__(self, env: VisualMountainCarEnv, eval_starts: int = 100) -> None:
        self.env = env
        self.oracle = CarOracle.solve()
        self.starts = start_states(self.oracle, eval_starts)
        self.oracle_returns = self.evaluate(self.oracle.as_policy()).returns  # (n,) per start
        self.oracle_return = float(self.oracle_returns.mean())

    def evaluate(self, policy: Policy) -> EvaluationResult:
        """Discounted returns of a batched ``policy(percepts, states)`` from the starts."""
        return evaluate_car_policy(self.env, policy, self.starts)

    def cells(self, states: np.ndarray, grid: int) -> np.ndarray:
        """(N,) cell of each true (position, velocity) on a ``grid`` x ``grid`` grid."""
        index = np.clip((self.unit(states) * grid).astype(int), 0, grid - 1)
        return index[:, 1] * grid + index[:, 0]

    def unit(self, states: np.ndarray) -> np.ndarray:
        """(N, 2) true (position, velocity) scaled to the unit square."""
        bound = np.array([MAX_POSITION, MAX_SPEED])
        return (np.asarray(states, dtype=float).reshape(-1, 2) + bound) / (2 * bound)

    @staticmethod
    def true_state(env: gym.Env) -> np.ndarray:
        """The true state of ``env`` (for oracles and the true-grid baseline)."""
        return env.unwrapped.state


class PlaceTask:
    """Place navigation: starts are every state off the goal place, and the percepts of the
    evaluation episodes are held-out views, never seen in training."""

    def __init__(self, env: PlaceNavigationEnv) -> None:
        self.env = env
        self.oracle = PlaceOracle(env)
        self.starts = env.world.start_states
        self.oracle_return = self.oracle.optimal_return(self.starts)

    def evaluate(self, policy: Policy) -> EvaluationResult:
        """Discounted returns of a batched ``policy(percepts, states)`` from the starts."""
        return self.oracle.evaluate(policy, self.starts)

    def cells(self, states: np.ndarray, grid: int) -> np.ndarray:
        """(N,) index of each true (place, heading): the states are already discrete."""
        return self.env.world.index(states)

    @staticmethod
    def true_state(env: gym.Env) -> np.ndarray:
        """The true state of ``env`` (for oracles and the true-grid baseline)."""
        return env.unwrapped.state

    def test_set(self) -> tuple[np.ndarray, np.ndarray]:
        """Held-out views (N, H, W, 3) of every state and (N, 3) bool: the optimal actions."""
        percepts, states = self.env.test_views()
        return percepts, self.oracle.optimal_actions(states)

    def train_set(self) -> tuple[np.ndarray, np.ndarray]:
        """Training views (N, H, W, 3) of every state and (N, 3) bool: the optimal actions."""
        percepts, states = self.env.training_views()
        return percepts, self.oracle.optimal_actions(states)


class EpisodeTask:
    """An env without an oracle: a policy's score is its mean episode reward (undiscounted)
    over ``episodes`` episodes, the first reset with seed 0 (SB3's ``evaluate_policy``), so
    that every policy meets the same episodes. ``oracle_return`` is None.

    Example:
        >>> task = EpisodeTask("my_envs:my/Grid-v0", episodes=20)
        >>> task.evaluate(lambda percepts, states: agent.predict(percepts)[0]).mean
    """

    oracle_return = None

    def __init__(self, env_id: str, env_kwargs: dict | None = None, episodes: int = 100) -> None:
        from stable_baselines3.common.monitor import Monitor

        check_at_least(1, episodes=episodes)
        self.env = Monitor(gym.make(env_id, **(env_kwargs or {})))  # the episodes as they end
        self.episodes = episodes

    def evaluate(self, policy: Policy) -> EvaluationResult:
        """Episode rewards of a batched ``policy(percepts, None)``."""
        from stable_baselines3.common.evaluation import evaluate_policy as sb3_evaluate_policy

        self.env.reset(seed=0)  # seeds the episodes that follow
        rewards, steps = sb3_evaluate_policy(
            _Predictor(policy), self.env, self.episodes, return_episode_rewards=True
        )
        return EvaluationResult(np.asarray(rewards, dtype=float), np.asarray(steps))


class _Predictor:
    """A ``Policy`` as SB3's ``evaluate_policy`` calls a model."""

    def __init__(self, policy: Policy) -> None:
        self.policy = policy

    def predict(self, observations, state=None, episode_start=None, deterministic=True):
        return np.asarray(self.policy(observations, None)), None


Task = MazeTask | CarTask | PlaceTask
ORACLE_ENVS = (VisualMazeEnv, VisualMountainCarEnv, PlaceNavigationEnv)


def has_oracle(env: gym.Env) -> bool:
    """Whether ``task_for`` has a task with an oracle for ``env`` (a ``gym.make`` of it)."""
    return isinstance(env.unwrapped, ORACLE_ENVS)


def task_for(env_id: str, env_kwargs: dict | None = None, eval_starts: int = 100) -> Task | None:
    """The task of an env with an oracle (None for any other env: see ``EpisodeTask``)."""
    env = gym.make(env_id, **(env_kwargs or {})).unwrapped
    if isinstance(env, VisualMazeEnv):
        return MazeTask(env, eval_starts)
    if isinstance(env, VisualMountainCarEnv):
        return CarTask(env, eval_starts)
    if isinstance(env, PlaceNavigationEnv):
        return PlaceTask(env)
    return None


class GridCells(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Image observation -> ``Discrete(grid**2)`` cell of the *true* state.

    The privileged-state baseline of the paper's comparisons: tabular Q-learning on this
    wrapper sees the true state (the maze's position, the car's position and velocity),
    never the percept.

    Example:
        >>> env = GridCells(gym.make("vistask/VisualMountainCar-v0"), task, grid=14)

    Args:
        env: the task's env (a ``gym.make`` of it).
        task: its ``Task``.
        grid: cells per dimension.
    """

    def __init__(self, env: gym.Env, task: Task, grid: int = 10) -> None:
        if type(env.unwrapped) is not type(task.env):
            raise TypeError(f"GridCells of a {type(task.env).__name__} task got another env")
        if grid < 1:
            raise ValueError(f"grid must be >= 1, got {grid}")
        gym.utils.RecordConstructorArgs.__init__(self, task=task, grid=grid)
        gym.ObservationWrapper.__init__(self, env)
        self.task, self.grid = task, grid
        self.observation_space = spaces.Discrete(grid * grid)

    def observation(self, observation: np.ndarray) -> int:
        """The true-grid cell of the env's true state."""
        return int(self.task.cells(self.task.true_state(self.env)[None], self.grid)[0])
