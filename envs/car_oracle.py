"""An oracle for the visual car on the hill that sees the true state, and its evaluation protocol.

``CarOracle.solve`` runs value iteration on a fine grid of true states (p, s) over
[-1, 1] x [-3, 3], reading the value of a successor state by bilinear interpolation between
the four grid nodes around it (paper Fig. 7 right). Its greedy policy looks one control step
ahead with the true dynamics. ``evaluate_car_policy`` runs any policy from fixed start states
to the end of each episode and returns the discounted returns: every method is scored with it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vistask.checks import checked
from vistask.envs.maze_oracle import EvaluationResult, Policy
from vistask.envs.mountain_car import (
    FORCES,
    GAMMA,
    MAX_POSITION,
    MAX_SPEED,
    VisualMountainCarEnv,
    check_states,
    hill_step,
    sample_states,
)

EVAL_STEPS = 100  # a scored episode's steps: gamma^100 = 0.006


@checked
@dataclass
class CarOracle:
    """Optimal value function on a grid of true states and its greedy one-step-lookahead policy.

    Example:
        >>> oracle = CarOracle.solve(grid=301)            # ~0.3 s
        >>> oracle.act(np.array([[-0.5, 0.0], [0.5, 2.0]]))
        >>> oracle.values.shape                           # (301, 301), [s index, p index]

    Attributes:
        q: (2, G, G) action values at the grid nodes, indexed [action, s index, p index]; node
            (i, j) is the state (positions[j], speeds[i]).
        gamma: discount factor.
    """

    q: np.ndarray
    gamma: float = GAMMA

    @property
    def grid(self) -> int:
        """Cells of the value grid along each of position and speed."""
        return self.q.shape[1]

    @property
    def positions(self) -> np.ndarray:
        """(G,) positions p of the grid's columns, -1 to 1."""
        return np.linspace(-MAX_POSITION, MAX_POSITION, self.grid)

    @property
    def speeds(self) -> np.ndarray:
        """(G,) speeds s of the grid's rows, -3 to 3."""
        return np.linspace(-MAX_SPEED, MAX_SPEED, self.grid)

    @property
    def values(self) -> np.ndarray:
        """(G, G) optimal values V = max_a Q at the nodes, indexed [s index, p index]."""
        return self.q.max(axis=0)

    @property
    def policy(self) -> np.ndarray:
        """(G, G) greedy action ids at the nodes, indexed [s index, p index]."""
        return self.q.argmax(axis=0)

    @classmethod
    def solve(
        cls, grid: int = 301, gamma: float = GAMMA, tol: float = 1e-8, max_iterations: int = 10_000
    ) -> CarOracle:
        """Value iteration on a grid x grid lattice of nodes over [-1, 1] x [-3, 3].

        The successor of every node under every action is computed once (``hill_step``); a
        successor that ends the episode contributes its reward and nothing more, any other
        contributes gamma times V interpolated bilinearly at it, so each action's transition
        is a sparse (nodes x nodes) matrix with four entries per row.

        Args:
            grid: nodes per side (301: steps of 0.0067 in p and 0.02 in s).
            gamma: discount factor.
            tol: stop when no value changes by more than this.
            max_iterations: give up (RuntimeError) after this many sweeps.
        """
        if grid < 2:
            raise ValueError(f"grid must be >= 2 nodes per side, got {grid}")
        if not 0 <= gamma < 1:
            raise ValueError(f"gamma must be in [0, 1), got {gamma}")
        nodes = grid_states(grid)
        rewards, transitions = [], []
        for force in FORCES:
            new, reward, terminal = hill_step(nodes, np.full(len(nodes), force))
            rewards.append(reward)
            transitions.append(interpolation_matrix(new, grid, keep=~terminal))
        values = np.zeros(len(nodes))
        for _ in range(max_iterations):
            q = np.stack(
                [r + gamma * (t @ values) for r, t in zip(rewards, transitions, strict=True)]
            )
            new_values = q.max(axis=0)
            delta = np.abs(new_values - values).max()
            values = new_values
            if delta < tol:
                return cls(q.reshape(len(FORCES), grid, grid), float(gamma))
        raise RuntimeError(
            f"value iteration did not converge to {tol} in {max_iterations} sweeps; "
            "raise max_iterations or tol"
        )

    def value(self, states: np.ndarray) -> np.ndarray:
        """(N,) V interpolated bilinearly at states (N, 2) inside [-1, 1] x [-3, 3]."""
        states = np.asarray(states, dtype=np.float64).reshape(-1, 2)
        return interpolation_matrix(states, self.grid) @ self.values.ravel()

    def lookahead(self, states: np.ndarray) -> np.ndarray:
        """(N, 2) one-step action values r + gamma V(next) (no bootstrap at terminal next
        states) at states (N, 2)."""
        states = np.asarray(states, dtype=np.float64).reshape(-1, 2)
        q = np.empty((len(states), len(FORCES)))
        for a, force in enumerate(FORCES):
            new, reward, terminal = hill_step(states, np.full(len(states), force))
            q[:, a] = reward
            live = ~terminal
            q[live, a] += self.gamma * self.value(new[live])
        return q

    def act(self, states: np.ndarray) -> np.ndarray:
        """(N,) greedy actions at states (N, 2) by one-step lookahead (ties: push left)."""
        return self.lookahead(states).argmax(axis=1)

    def as_policy(self) -> Policy:
        """The oracle as a ``Policy`` ``(percepts, states) -> actions`` (reads true states)."""
        return lambda percepts, states: self.act(states)


def grid_states(grid: int) -> np.ndarray:
    """(grid*grid, 2) the lattice nodes (p, s), row-major with rows along s: node
    ``i * grid + j`` is (p_j, s_i), p and s from ``np.linspace`` over [-1, 1] and [-3, 3]."""
    p = np.linspace(-MAX_POSITION, MAX_POSITION, grid)
    s = np.linspace(-MAX_SPEED, MAX_SPEED, grid)
    pp, ss = np.meshgrid(p, s)
    return np.stack([pp.ravel(), ss.ravel()], axis=1)


def interpolation_matrix(
    states: np.ndarray, grid: int, keep: np.ndarray | None = None
) -> sp.csr_matrix:
    """(N, grid*grid) sparse bilinear interpolation weights of states (N, 2) between the nodes
    of ``grid_states(grid)``; rows where ``keep`` is False are empty. States are clipped to the
    box (a kept state must lie in it up to rounding)."""
    states = np.asarray(states, dtype=np.float64).reshape(-1, 2)
    n = len(states)
    keep = np.ones(n, bool) if keep is None else np.asarray(keep, bool)
    u = (np.clip(states[:, 0], -MAX_POSITION, MAX_POSITION) + MAX_POSITION) / (2 * MAX_POSITION)
    v = (np.clip(states[:, 1], -MAX_SPEED, MAX_SPEED) + MAX_SPEED) / (2 * MAX_SPEED)
    x, y = u * (grid - 1), v * (grid - 1)
    j, i = np.minimum(x.astype(int), grid - 2), np.minimum(y.astype(int), grid - 2)
    fx, fy = x - j, y - i
    rows = np.repeat(np.flatnonzero(keep), 4)
    cols = np.stack([i * grid + j, i * grid + j + 1, (i + 1) * grid + j, (i + 1) * grid + j + 1], 1)
    weights = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    return sp.csr_matrix(
        (weights[keep].ravel(), (rows, cols[keep].ravel())), shape=(n, grid * grid)
    )


def rollout(
    act: Callable[[np.ndarray, np.ndarray], np.ndarray],
    starts: np.ndarray,
    gamma: float = GAMMA,
    max_steps: int = EVAL_STEPS,
    render: Callable[[np.ndarray], np.ndarray] | None = None,
) -> EvaluationResult:
    """Run all episodes from ``starts`` (n, 2) in lockstep until each ends (terminal or
    ``max_steps``) and return their discounted returns sum_t gamma^t r_{t+1}.

    Args:
        act: batched ``act(percepts, states) -> actions`` over the live episodes (percepts are
            None when ``render`` is None).
        starts: (n, 2) start states (p, s).
        gamma: discount of the returns.
        max_steps: episode cut-off.
        render: states (k, 2) -> percepts (k, H, W, 3), e.g. ``env.percepts``.
    """
    states = check_states(starts, "starts").copy()
    n = len(states)
    returns, steps = np.zeros(n), np.full(n, max_steps)
    live = np.arange(n)
    for t in range(max_steps):
        percepts = None if render is None else render(states[live])
        actions = np.asarray(act(percepts, states[live].copy())).reshape(-1)
        if len(actions) != len(live) or not np.isin(actions, range(len(FORCES))).all():
            raise ValueError(f"policy must return {len(live)} actions in 0..1, got {actions}")
        new, rewards, terminal = hill_step(states[live], FORCES[actions.astype(int)])
        states[live] = new
        returns[live] += gamma**t * rewards
        steps[live[terminal]] = t + 1
        live = live[~terminal]
        if len(live) == 0:
            break
    return EvaluationResult(returns, steps)


@checked
def start_states(
    oracle: CarOracle | None = None,
    n: int = 100,
    seed: int = 12345,
    max_steps: int = EVAL_STEPS,
) -> np.ndarray:
    """The fixed evaluation start set: (n, 2) states drawn uniformly in [-1, 1) x [-3, 3)
    with ``seed``, keeping only those from which the oracle's discounted return is > 0 (the
    top is reachable within ``max_steps`` without breaking the speed limit).

    Args:
        oracle: the oracle that decides reachability (default: ``CarOracle.solve()``, ~0.3 s).
        n: number of starts.
        seed: seed of the draws.
        max_steps: episode cut-off within which the top must be reachable.
    """
    if n < 1:
        raise ValueError(f"need at least one start, got n={n}")
    oracle = oracle or CarOracle.solve()
    rng = np.random.default_rng(seed)
    found: list[np.ndarray] = []
    count = 0
    while count < n:
        candidates = sample_states(rng, 2 * (n - count) + 8)
        result = rollout(lambda _, states: oracle.act(states), candidates, oracle.gamma, max_steps)
        found.append(candidates[result.returns > 0])
        count += len(found[-1])
    return np.concatenate(found)[:n]


@checked
def evaluate_car_policy(
    env: VisualMountainCarEnv,
    policy: Policy,
    starts: np.ndarray,
    max_steps: int = EVAL_STEPS,
) -> EvaluationResult:
    """Run ``policy`` once from each start, all episodes in lockstep on the true dynamics
    (``hill_step``, as the env and its vector env step), and return the discounted returns.

    The dynamics have no noise, so an episode depends only on its start and the policy.

    Example:
        >>> env = gym.make("vistask/VisualMountainCar-v0")
        >>> oracle = CarOracle.solve()
        >>> starts = start_states(oracle)
        >>> evaluate_car_policy(env, oracle.as_policy(), starts).mean

    Args:
        env: a visual car (``gym.make("vistask/VisualMountainCar-v0")`` or the raw class).
        policy: batched ``policy(percepts, states) -> actions`` (see ``Policy``); a visual
            agent must ignore the states.
        starts: (n, 2) start states (``start_states``).
        max_steps: episode cut-off (default ``EVAL_STEPS`` = 100, whatever the env's time
            limit for learning is).
    """
    car = env.unwrapped
    if not isinstance(car, VisualMountainCarEnv):
        raise TypeError(
            f"evaluate_car_policy needs a VisualMountainCarEnv, got {type(car).__name__}"
        )
    return rollout(policy, starts, car.gamma, max_steps, render=car.percepts)
