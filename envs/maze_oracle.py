"""An oracle for the visual maze that sees the true position, and the shared evaluation protocol.

``MazeOracle.solve`` discretizes the maze into an N x N grid of true positions and runs value
iteration over the true noisy dynamics (paper Fig. 4 left), over the four actions or over n
evenly spaced move angles (the continuous-action maze). ``evaluate_policy`` runs any policy
from a fixed set of start positions with fixed noise seeds and returns its mean discounted
return: every method in the toolkit is scored with it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from gymnasium.utils import seeding

from vistask.checks import checked
from vistask.envs.visual_maze import (
    ACTION_ANGLES,
    ACTION_DIRECTIONS,
    MazeGeometry,
    VisualMazeContinuousEnv,
    VisualMazeEnv,
    angle_directions,
    valid_angles,
)

# A batched policy: (percepts (n, H, W, 3) uint8, true positions (n, 2)) -> (n,) actions: action
# ids for ``VisualMazeEnv``, move angles in radians for ``VisualMazeContinuousEnv``.
# Positions are for oracles and plots; a visual agent must ignore them.
Policy = Callable[[np.ndarray, np.ndarray], np.ndarray]


@checked
def direction_angles(n: int) -> np.ndarray:
    """(n,) evenly spaced move angles ``-π + 2π k / n``, k = 0..n-1.

    Any n divisible by 4 includes the four actions' directions: left (-π), up (-π/2),
    right (0), down (π/2).

    Example:
        >>> direction_angles(4) / np.pi
        array([-1. , -0.5,  0. ,  0.5])
    """
    if not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"the number of directions must be a positive integer, got {n!r}")
    return -np.pi + 2 * np.pi * np.arange(n) / n


@checked
@dataclass
class MazeOracle:
    """Optimal value function and greedy policy on a grid of true positions.

    Attributes:
        geometry: the maze solved.
        q: (A, N, N) values of the A move directions at the grid cells, indexed
            [direction, row (y), column (x)]: the four actions (``ACTION_NAMES``), or the
            directions ``angles``.
        angles: (A,) move angles in radians of a directional oracle (``solve(...,
            n_directions=A)``), for ``VisualMazeContinuousEnv``; None for the 4-action oracle.
    """

    geometry: MazeGeometry
    q: np.ndarray
    angles: np.ndarray | None = None

    @property
    def grid(self) -> int:
        """Cells of the value grid along each axis of the maze."""
        return self.q.shape[1]

    @property
    def values(self) -> np.ndarray:
        """(N, N) optimal values V = max_a Q, indexed [row (y), column (x)]."""
        return self.q.max(axis=0)

    @property
    def policy(self) -> np.ndarray:
        """(N, N) greedy action ids (indices into ``angles`` for a directional oracle),
        indexed [row (y), column (x)]."""
        return self.q.argmax(axis=0)

    @property
    def move_angles(self) -> np.ndarray:
        """(A,) angles of the directions of ``q``: ``angles``, or ``ACTION_ANGLES``."""
        return ACTION_ANGLES if self.angles is None else self.angles

    @property
    def policy_angles(self) -> np.ndarray:
        """(N, N) greedy move angles in radians, indexed [row (y), column (x)]."""
        return self.move_angles[self.policy]

    @classmethod
    def solve(
        cls,
        geometry: MazeGeometry,
        grid: int = 50,
        samples: int = 64,
        seed: int = 0,
        tol: float = 1e-6,
        n_directions: int | None = None,
    ) -> MazeOracle:
        """Value iteration on the grid-discretized true dynamics.

        Example:
            >>> oracle = MazeOracle.solve(MazeGeometry(), n_directions=32)  # ~ 3 s
            >>> oracle.q.shape, oracle.angle(np.array([[0.5, 0.5]])).shape
            ((32, 50, 50), (1,))

        Args:
            geometry: maze geometry (``env.unwrapped.geometry``).
            grid: cells per side.
            samples: Monte Carlo noise draws per (cell, direction) to estimate transitions.
            seed: seed of the noise draws.
            tol: stop when no value changes by more than this.
            n_directions: None for the four actions of ``VisualMazeEnv``; n for the n move
                angles ``direction_angles(n)`` of ``VisualMazeContinuousEnv`` (32: steps of
                11.25°, the four axes included).
        """
        if grid < 2 or samples < 1:
            raise ValueError(f"grid must be >= 2 and samples >= 1, got {grid}, {samples}")
        if n_directions is None:
            angles, directions = None, ACTION_DIRECTIONS
        else:
            angles = direction_angles(n_directions)
            directions = angle_directions(angles)
        cells = grid * grid
        origins = _cell_origins(geometry, grid)  # (cells, 2)
        noise = np.random.default_rng(seed).standard_normal((samples, 2))
        if geometry.noise_std == 0:
            noise = noise[:1] * 0
        models = [_direction_model(geometry, origins, noise, d, grid) for d in directions]
        rewards = np.stack([reward for reward, _ in models])  # (A, cells)
        # One (A * cells, cells) matrix: a single product per sweep instead of A.
        transitions = sp.vstack([t for _, t in models], format="csr")
        values = np.zeros(cells)
        q = rewards.copy()
        for _ in range(100_000):
            q = rewards + geometry.gamma * (transitions @ values).reshape(rewards.shape)
            new_values = q.max(axis=0)
            delta = np.abs(new_values - values).max()
            values = new_values
            if delta < tol:
                break
        return cls(geometry, q.reshape(len(directions), grid, grid), angles)

    def cell(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, column) grid indices of (N, 2) positions."""
        index = grid_cells(points, self.geometry.size, self.grid)
        return np.divmod(index, self.grid)

    def value(self, points: np.ndarray) -> np.ndarray:
        """(N,) optimal values at (N, 2) positions (value of the containing cell)."""
        return self.values[self.cell(points)]

    def act(self, points: np.ndarray) -> np.ndarray:
        """(N,) greedy actions at (N, 2) positions (direction indices for a directional
        oracle)."""
        return self.policy[self.cell(points)]

    def angle(self, points: np.ndarray) -> np.ndarray:
        """(N,) greedy move angles in radians at (N, 2) positions (``ACTION_ANGLES`` of the
        greedy actions for the 4-action oracle)."""
        return self.move_angles[self.act(points)]

    def as_policy(self) -> Policy:
        """The oracle as a ``Policy`` for ``evaluate_policy`` (reads the true positions):
        action ids for the 4-action oracle, move angles for a directional one."""
        if self.angles is None:
            return lambda percepts, positions: self.act(positions)
        return lambda percepts, positions: self.angle(positions)


def grid_cells(positions: np.ndarray, size: float, grid: int) -> np.ndarray:
    """(N, 2) positions in [0, size]^2 -> (N,) cell ids ``row * grid + column`` of a
    ``grid x grid`` partition (row from y, column from x)."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 2)
    ij = np.clip((positions / size * grid).astype(int), 0, grid - 1)
    return ij[:, 1] * grid + ij[:, 0]


def _direction_model(
    geometry: MazeGeometry, origins: np.ndarray, noise: np.ndarray, direction: np.ndarray, grid: int
) -> tuple[np.ndarray, sp.csr_matrix]:
    """Monte Carlo model of moving along one direction from every cell.

    Args:
        geometry: the maze.
        origins: (cells, 2) start point of each cell (``_cell_origins``).
        noise: (k, 2) standard-normal draws, the same for every cell.
        direction: (2,) unit move direction.
        grid: cells along each axis.

    Returns:
        (cells,) expected immediate rewards, and the (cells, cells) sub-stochastic transition
        matrix among cells (the missing mass is the chance of exiting).
    """
    cells, k = len(origins), len(noise)
    points = np.repeat(origins, k, axis=0)
    directions = np.broadcast_to(direction, points.shape)
    new, exited = geometry.move_towards(points, directions, np.tile(noise, (cells, 1)))
    exited = exited.reshape(cells, k)
    rewards = geometry.reward * exited.mean(axis=1)
    target = grid_cells(new, geometry.size, grid).reshape(cells, k)
    rows = np.repeat(np.arange(cells), k)[~exited.ravel()]
    transition = sp.csr_matrix(
        (np.full(len(rows), 1.0 / k), (rows, target.ravel()[~exited.ravel()])),
        shape=(cells, cells),
    )
    return rewards, transition


def _cell_origins(geometry: MazeGeometry, grid: int, sub: int = 5) -> np.ndarray:
    """(grid*grid, 2) a free point of each cell: its centre, else the free sub-cell point
    nearest to the centre. Cells near walls would otherwise start inside the wall and look
    stuck; fully blocked cells keep their centre (they are never reached)."""
    width = geometry.size / grid
    offsets = (np.arange(sub) + 0.5) / sub - 0.5
    offsets = np.stack(np.meshgrid(offsets, offsets), -1).reshape(-1, 2)
    offsets = offsets[np.argsort(np.linalg.norm(offsets, axis=1), kind="stable")] * width
    jj, ii = np.meshgrid(np.arange(grid), np.arange(grid))  # jj: column (x), ii: row (y)
    centres = (np.stack([jj.ravel(), ii.ravel()], -1) + 0.5) * width
    candidates = centres[:, None, :] + offsets[None]  # (cells, sub*sub, 2)
    free = geometry.is_free(candidates.reshape(-1, 2)).reshape(len(centres), -1)
    first = np.where(free.any(axis=1), free.argmax(axis=1), 0)
    return np.where(free.any(axis=1)[:, None], candidates[np.arange(len(centres)), first], centres)


@checked
def start_positions(geometry: MazeGeometry, n: int = 100, seed: int = 12345) -> np.ndarray:
    """The fixed evaluation start set: (n, 2) free positions drawn with ``seed``."""
    return geometry.sample_free(np.random.default_rng(seed), n)


@checked
@dataclass
class EvaluationResult:
    """Outcome of ``evaluate_policy``: ``returns`` (n,) discounted returns, ``steps`` (n,)."""

    returns: np.ndarray
    steps: np.ndarray

    @property
    def mean(self) -> float:
        """Mean discounted return over the starts."""
        return float(self.returns.mean())


@checked
def evaluate_policy(
    env: VisualMazeEnv,
    policy: Policy,
    starts: np.ndarray | None = None,
    max_steps: int = 100,
    seed: int = 0,
) -> EvaluationResult:
    """Run ``policy`` once from each start, all episodes in lockstep, and return the
    discounted returns.

    Episode i draws its noise from its own generator seeded ``seed + i``, exactly as
    ``env.reset(seed=seed + i)`` followed by ``env.step`` would, so two policies that act
    alike see the same noise, and a batched policy (feature extraction for all live episodes
    at once) is scored as if each episode ran alone. The noise does not depend on the kind of
    maze either: the four actions on ``VisualMazeEnv`` and their ``ACTION_ANGLES`` on
    ``VisualMazeContinuousEnv`` score the same.

    Args:
        env: a visual maze (``gym.make("vistask/VisualMaze-v0")``,
            ``"vistask/VisualMazeContinuous-v0"`` or the raw classes).
        policy: batched ``policy(percepts, positions) -> actions`` (see ``Policy``): (n,)
            action ids in 0..3, or for the continuous maze (n,) or (n, 1) angles in [-π, π].
        starts: (n, 2) start positions (default ``start_positions(geometry)``).
        max_steps: episode cut-off (gamma^100 is negligible).
        seed: base noise seed.
    """
    maze = env.unwrapped
    if not isinstance(maze, VisualMazeEnv):
        raise TypeError(f"evaluate_policy needs a VisualMazeEnv, got {type(maze).__name__}")
    continuous = isinstance(maze, VisualMazeContinuousEnv)
    geometry = maze.geometry
    positions = start_positions(geometry) if starts is None else np.array(starts, dtype=float)
    if positions.ndim != 2 or positions.shape[1] != 2 or not geometry.is_free(positions).all():
        raise ValueError("starts must be an (n, 2) array of free positions")
    n = len(positions)
    rngs = [seeding.np_random(seed + i)[0] for i in range(n)]  # as env.reset(seed=seed + i)
    returns, steps = np.zeros(n), np.full(n, max_steps)
    live = np.arange(n)
    for t in range(max_steps):
        percepts = np.stack([maze.percept_at(p) for p in positions[live]])
        actions = np.asarray(policy(percepts, positions[live].copy()))
        if continuous:
            directions = _policy_directions(actions, len(live))
        else:
            actions = actions.astype(int).reshape(-1)
            if len(actions) != len(live) or actions.min() < 0 or actions.max() >= 4:
                raise ValueError(f"policy must return {len(live)} actions in 0..3, got {actions}")
            directions = ACTION_DIRECTIONS[actions]
        noise = np.concatenate([rngs[i].standard_normal((1, 2)) for i in live])
        positions[live], exited = geometry.move_towards(positions[live], directions, noise)
        returns[live[exited]] = geometry.gamma**t * geometry.reward
        steps[live[exited]] = t + 1
        live = live[~exited]
        if len(live) == 0:
            break
    return EvaluationResult(returns, steps)


def _policy_directions(angles: np.ndarray, n: int) -> np.ndarray:
    """(n, 2) move directions of a continuous-maze policy's (n,) or (n, 1) angles."""
    if angles.shape not in ((n,), (n, 1)) or not valid_angles(angles):
        raise ValueError(
            f"policy must return {n} move angles as an ({n},) or ({n}, 1) array of finite"
            f" radians within [-π, π], got {angles}"
        )
    return angle_directions(angles)
