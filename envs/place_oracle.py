"""The oracle of place navigation (shortest paths over the place graph) and its evaluation
protocol."""

from __future__ import annotations

from collections import deque

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding

from vistask.checks import checked
from vistask.envs.maze_oracle import EvaluationResult, Policy
from vistask.envs.place_navigation import navigation_env
from vistask.envs.place_scene import TEST_VIEWS_PER_STATE
from vistask.envs.place_world import FORWARD, LEFT, RIGHT, PlaceWorld, check_int

# -- oracle and evaluation -----------------------------------------------------------------------
DEFAULT_MAX_STEPS = 50  # the time limit of vistask/PlaceNavigation-v0


@checked
class PlaceOracle:
    """Shortest paths over (place, heading) states, by breadth-first search back from the goal.

    A state k actions away from the goal place has the optimal discounted return
    ``reward * gamma ** (k - 1)``: the reward arrives with the k-th action, discounted k - 1
    times (returns are sum_t gamma^t r_{t+1}, as ``evaluate_policy`` scores the maze).

    Example:
        >>> env = gym.make("vistask/PlaceNavigation-v0")
        >>> oracle = PlaceOracle(env)
        >>> oracle.values[0, 1]                  # V of place 0 facing east
        >>> oracle.optimal_actions((0, 1))       # (3,) bool: every optimal action
        >>> result = oracle.evaluate(lambda percepts, states: agent_actions(percepts))
        >>> result.mean, oracle.return_ratio(result)

    Args:
        env: a place-navigation env (``gym.make`` of it or the raw class).

    Attributes:
        env: the unwrapped env.
        steps: (places, 4) fewest actions from each state to the goal place (0 on it, -1 where
            it cannot be reached, which a connected town never has).
        values: (places, 4) optimal discounted returns (0 on the goal place).
        q: (places, 4, 3) optimal action values (0 on the goal place).
    """

    def __init__(self, env: gym.Env) -> None:
        self.env = navigation_env(env, "PlaceOracle")
        world = self.world
        successor = world.next_state  # (states, 3)
        place = np.arange(world.n_states) // 4
        steps = np.where(place == world.goal, 0, -1)
        predecessors: list[list[int]] = [[] for _ in range(world.n_states)]
        for state, following in enumerate(successor.tolist()):
            for t in following:
                predecessors[t].append(state)
        queue = deque(np.flatnonzero(steps == 0).tolist())
        while queue:
            t = queue.popleft()
            for s in predecessors[t]:
                if steps[s] < 0:
                    steps[s] = steps[t] + 1
                    queue.append(s)
        values = np.where(steps > 0, world.reward * world.gamma ** (steps - 1.0), 0.0)
        into_goal = (place[successor] == world.goal) & (place != world.goal)[:, None]
        q = np.where(into_goal, world.reward, world.gamma * values[successor])
        q[place == world.goal] = 0.0
        self.steps = steps.reshape(world.n_places, 4)
        self.values = values.reshape(world.n_places, 4)
        self.q = q.reshape(world.n_places, 4, 3)

    @property
    def world(self) -> PlaceWorld:
        """The place graph of the env."""
        return self.env.world

    def value(self, states) -> np.ndarray:
        """(N,) optimal values of (N, 2) states (place, heading)."""
        states = self.world.check_states(states)
        return self.values[states[:, 0], states[:, 1]]

    def optimal_actions(self, states) -> np.ndarray:
        """Bool mask of every optimal action (ties included): (3,) for one (place, heading),
        (N, 3) for (N, 2) states. On the goal place every action counts as optimal."""
        array = self.world.check_states(states)
        q = self.q[array[:, 0], array[:, 1]]
        mask = np.isclose(q, q.max(axis=1, keepdims=True), rtol=1e-12, atol=1e-9)
        return mask[0] if np.asarray(states).ndim == 1 else mask

    def act(self, states) -> np.ndarray:
        """(N,) an optimal action of each state (forward when it is one, else left, else
        right)."""
        mask = self.optimal_actions(self.world.check_states(states))
        return np.where(mask[:, FORWARD], FORWARD, np.where(mask[:, LEFT], LEFT, RIGHT))

    def as_policy(self) -> Policy:
        """The oracle as a ``Policy`` ``(percepts, states) -> actions`` (reads true states)."""
        return lambda percepts, states: self.act(states)

    def optimal_return(self, starts=None) -> float:
        """Mean optimal discounted return from ``starts`` (default ``evaluation_starts``)."""
        starts = self.world.start_states if starts is None else starts
        return float(self.value(starts).mean())

    def evaluate(
        self,
        policy: Policy,
        starts=None,
        max_steps: int = DEFAULT_MAX_STEPS,
        seed: int = 0,
        views: str = "test",
        per_state: int = TEST_VIEWS_PER_STATE,
    ) -> EvaluationResult:
        """Run ``policy`` once from each start, all episodes in lockstep, and return the
        discounted returns sum_t gamma^t r_{t+1}.

        Episode i draws its views from its own generator seeded ``seed + i``; with
        ``views="train"`` exactly as ``env.reset(seed=seed + i, options={"state": start})``
        followed by ``env.step`` would, so a batched policy is scored as if each episode ran
        alone in the env.

        Args:
            policy: batched ``policy(percepts (k, H, W, 3), states (k, 2)) -> (k,) actions``
                (see ``Policy``); a visual agent must ignore the states.
            starts: (n, 2) start states (default ``evaluation_starts``: every state off the
                goal place).
            max_steps: episode cut-off (the registered env's time limit).
            seed: base seed of the view draws.
            views: ``"test"``: held-out views (``env.test_bank(per_state)``), never seen in
                training; ``"train"``: the env's own bank.
            per_state: held-out views per state with ``views="test"``.
        """
        world = self.world
        starts = world.start_states if starts is None else world.check_states(starts, "starts")
        if (starts[:, 0] == world.goal).any():
            raise ValueError(f"starts must lie off the goal place {world.goal}")
        check_int("max_steps", max_steps, 1)
        if views == "test":
            bank = self.env.test_bank(per_state)
        elif views == "train":
            bank = self.env.views
        else:
            raise ValueError(f"views must be 'test' or 'train', got {views!r}")
        n, per = len(starts), bank.shape[1]
        rngs = [seeding.np_random(seed + i)[0] for i in range(n)]  # as env.reset(seed=seed + i)
        states = starts.copy()
        shown = np.array([rng.integers(per) for rng in rngs])
        returns, steps = np.zeros(n), np.full(n, max_steps)
        live = np.arange(n)
        for t in range(max_steps):
            percepts = bank[world.index(states[live]), shown[live]]
            actions = np.asarray(policy(percepts, states[live].copy())).reshape(-1)
            if (
                len(actions) != len(live)
                or not np.issubdtype(actions.dtype, np.integer)
                or actions.min() < 0
                or actions.max() > 2
            ):
                raise ValueError(f"policy must return {len(live)} integer actions in 0..2")
            states[live], reached = world.step(states[live], actions)
            returns[live[reached]] = world.gamma**t * world.reward
            steps[live[reached]] = t + 1
            live = live[~reached]
            if len(live) == 0:
                break
            for i in live:
                shown[i] = rngs[i].integers(per)
        return EvaluationResult(returns, steps)

    def return_ratio(self, result: EvaluationResult | Policy, starts=None, **kwargs) -> float:
        """Mean discounted return of a policy (or of its ``evaluate`` result) over the
        oracle's, from the same starts (1: optimal).

        Args:
            result: an ``EvaluationResult`` from ``starts``, or a policy to ``evaluate``.
            starts: the start states (default ``evaluation_starts``).
            **kwargs: ``evaluate`` arguments when ``result`` is a policy.
        """
        if not isinstance(result, EvaluationResult):
            result = self.evaluate(result, starts, **kwargs)
        return result.mean / self.optimal_return(starts)


@checked
def evaluation_starts(env: gym.Env, n: int | None = None, seed: int = 12345) -> np.ndarray:
    """The fixed evaluation start set: (n, 2) states off the goal place; every one of them
    (state-index order) when ``n`` is None, else ``n`` drawn without replacement with
    ``seed`` (with replacement when ``n`` exceeds their number)."""
    states = navigation_env(env, "evaluation_starts").world.start_states
    if n is None:
        return states
    check_int("n", n, 1)
    rng = np.random.default_rng(seed)
    return states[rng.choice(len(states), size=n, replace=n > len(states))]


# -- pictures ------------------------------------------------------------------------------------
