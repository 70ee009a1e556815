"""Tabular Q-learning on any environment with ``Discrete`` observations."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from tqdm.auto import tqdm

from vistask.agents.sb3_model import SB3Model
from vistask.checks import (
    check_at_least,
    check_discount,
    check_integers,
    check_same_env,
    checked,
    env_identity,
)
from vistask.saving import load_state, save_state


@checked
class TabularQAgent(SB3Model):
    """Epsilon-greedy tabular Q-learning with an SB3-like API.

    Example:
        >>> env = VisualClasses(gym.make("vistask/VisualMaze-v0"), classifier)
        >>> agent = TabularQAgent(env, seed=0).learn(total_timesteps=20_000)
        >>> action, _ = agent.predict(obs, deterministic=True)
        >>> agent.save("q.pt"); TabularQAgent.load("q.pt", env)

    Args:
        env: environment with ``Discrete`` observation and action spaces (any ``start``: Q's
            rows and columns count from it, ``predict`` returns the env's action ids).
        learning_rate: step size of the Q update.
        gamma: discount (default: ``env.unwrapped.gamma`` if the env exposes one, else 0.99).
        epsilon: exploration rate of the behaviour policy.
        initial_q: initial Q values (optimism drives exploration when rewards are positive).
        tensorboard_log: folder of TensorBoard runs (None: no logging).
        seed: seeds the behaviour policy and the first reset.
        n_states, n_actions: table size without an env (for ``load``).
    """

    def __init__(
        self,
        env: gym.Env | None,
        learning_rate: float = 0.2,
        gamma: float | None = None,
        epsilon: float = 0.2,
        initial_q: float = 0.0,
        tensorboard_log: str | Path | None = None,
        seed: int = 0,
        n_states: int | None = None,
        n_actions: int | None = None,
    ) -> None:
        if env is not None:
            if n_states is not None or n_actions is not None:
                raise ValueError("n_states and n_actions are the env's: pass them only without one")
            if not isinstance(env.observation_space, gym.spaces.Discrete):
                raise TypeError(
                    "TabularQAgent needs a Discrete observation space, got "
                    f"{env.observation_space}; wrap image envs with VisualClasses"
                )
            if not isinstance(env.action_space, gym.spaces.Discrete):
                raise TypeError(f"TabularQAgent needs Discrete actions, got {env.action_space}")
            n_states, n_actions = int(env.observation_space.n), int(env.action_space.n)
            gamma = gamma if gamma is not None else getattr(env.unwrapped, "gamma", 0.99)
        if n_states is None or n_actions is None:
            raise ValueError("pass an env, or n_states and n_actions")
        check_at_least(1, n_states=n_states, n_actions=n_actions)
        if not math.isfinite(initial_q):
            raise ValueError(f"initial_q must be finite, got {initial_q!r}")
        if not 0 < learning_rate <= 1:
            raise ValueError(f"learning_rate must be in (0, 1], got {learning_rate!r}")
        if not 0 <= epsilon <= 1:
            raise ValueError(f"epsilon must be in [0, 1], got {epsilon!r}")
        gamma = 0.99 if gamma is None else gamma
        check_discount(gamma)
        check_integers(seed=seed)
        check_at_least(0, seed=seed)
        self.env, self.tensorboard_log = env, tensorboard_log
        self.env_identity = env_identity(env)  # the gym.make id and arguments learned on
        self.learning_rate, self.epsilon, self.seed = learning_rate, epsilon, seed
        self.gamma = float(gamma)
        self.q = np.full((n_states, n_actions), float(initial_q))
        # The first state and action ids (gymnasium's Discrete start): Q's row and column 0.
        self.starts = (
            (int(env.observation_space.start), int(env.action_space.start)) if env else (0, 0)
        )
        self.num_timesteps = 0
        self._seeded = False
        self.rng = np.random.default_rng(seed)
        self._resume_env_rng: dict | None = None

    def learn(
        self,
        total_timesteps: int,
        callback: Any = None,
        tb_log_name: str = "TabularQ",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
        checkpoint: str | Path | None = None,
        checkpoint_every: int | None = None,
    ) -> TabularQAgent:
        """Run Q-learning for ``total_timesteps`` environment steps; SB3 callbacks are called
        after every step (returning False stops); ``rollout/ep_rew`` is logged per episode.

        With ``checkpoint``, the agent as it was when an episode began is written there every
        ``checkpoint_every`` steps (default 10,000) and when learning is interrupted
        (KeyboardInterrupt, or SIGTERM turned into one by ``vistask.cli.interrupt_on_sigterm``),
        with the random-generator states of the agent and the env. ``load(checkpoint, env)``
        followed by ``learn(total_timesteps - agent.num_timesteps, reset_num_timesteps=False)`` ends
        with the Q table of an uninterrupted ``learn(total_timesteps)``, bit for bit, on an
        env whose episodes depend only on its own generator and the actions.
        """
        if not isinstance(total_timesteps, int | np.integer) or total_timesteps < 0:
            raise ValueError(f"total_timesteps must be an integer >= 0, got {total_timesteps!r}")
        if checkpoint is None and checkpoint_every is not None:
            raise ValueError("checkpoint_every needs checkpoint: the file to write to")
        if checkpoint is not None and Path(checkpoint).is_dir():
            raise ValueError(f"checkpoint: {checkpoint} is a folder; name a file in it")
        checkpoint_every = 10_000 if checkpoint_every is None else checkpoint_every
        check_at_least(1, checkpoint_every=checkpoint_every)
        check_same_env(self.env_identity, self.env, learning=True)
        seeded = self._seeded  # the env is seeded once, at the agent's first step
        callback = self._start_learning(callback, tb_log_name, reset_num_timesteps)
        env, q, (first_state, first_action) = self.env, self.q, self.starts
        end = self.num_timesteps + total_timesteps
        if self._resume_env_rng is not None:  # the episode a checkpoint stopped in, again
            env.unwrapped.np_random.bit_generator.state = self._resume_env_rng
            self._resume_env_rng = None
        start = self._boundary() if checkpoint else None
        saved_at = self.num_timesteps
        obs, _ = env.reset(seed=None if seeded else self.seed)
        self._seeded = True
        episode_reward = 0.0
        try:
            for _ in tqdm(range(total_timesteps), disable=not progress_bar, desc="Q-learning"):
                if self.rng.random() < self.epsilon:
                    action = int(self.rng.integers(q.shape[1]))
                else:
                    action = self._greedy(obs)
                next_obs, reward, terminated, truncated, _ = env.step(action + first_action)
                row, next_row = obs - first_state, next_obs - first_state
                target = reward + (0.0 if terminated else self.gamma * q[next_row].max())
                q[row, action] += self.learning_rate * (target - q[row, action])
                self.num_timesteps += 1
                obs, episode_reward = next_obs, episode_reward + float(reward)
                if terminated or truncated:
                    self.logger.record("rollout/ep_rew", episode_reward)
                    self.logger.dump(step=self.num_timesteps)
                    if checkpoint and self.num_timesteps < end:
                        start = self._boundary()
                        if self.num_timesteps - saved_at >= checkpoint_every:
                            save_state(checkpoint, "TabularQAgent", start)
                            saved_at = self.num_timesteps
                    obs, _ = env.reset()
                    episode_reward = 0.0
                if not callback.on_step():
                    break
        except KeyboardInterrupt:
            if checkpoint:
                save_state(checkpoint, "TabularQAgent", start)
            raise
        self._end_learning(callback)
        return self

    def _boundary(self) -> dict:
        """The agent's state between two episodes, the env's generator included."""
        return {
            **self._state(),
            "q": torch.from_numpy(self.q.copy()),  # learning goes on in place
            "env_rng": self.env.unwrapped.np_random.bit_generator.state,
        }

    def _greedy(self, state: int) -> int:
        """The column of a greedy action in the env's ``state``."""
        row = self.q[state - self.starts[0]]
        # Random tie-breaking: with an all-equal row, argmax would always pick action 0.
        return int(self.rng.choice(np.flatnonzero(row == row.max())))

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """SB3's signature: returns (action or actions, None) for one state id or a batch."""
        states = np.asarray(observation)
        if not np.issubdtype(states.dtype, np.integer):
            raise TypeError(f"state ids must be integers, got {observation!r}")
        first_state, first_action = self.starts
        rows = states - first_state
        if rows.min(initial=0) < 0 or rows.max(initial=0) >= len(self.q):
            last = first_state + len(self.q) - 1
            raise ValueError(f"state ids must lie in {first_state}..{last}, got {observation}")
        actions = self.q[rows.reshape(-1)].argmax(axis=1)
        if not deterministic:
            explore = self.rng.random(len(actions)) < self.epsilon
            actions[explore] = self.rng.integers(self.q.shape[1], size=int(explore.sum()))
        return (actions.reshape(states.shape) + first_action, None)

    def _state(self) -> dict:
        return {
            "q": torch.from_numpy(self.q),
            "learning_rate": self.learning_rate,
            "gamma": self.gamma,
            "epsilon": self.epsilon,
            "seed": self.seed,
            "num_timesteps": self.num_timesteps,
            "rng": self.rng.bit_generator.state,
            "env_identity": self.env_identity,
            "starts": list(self.starts),
            "tensorboard_log": self._saved_tensorboard_log,
        }

    def save(self, path: str | Path) -> None:
        """Q, the settings, the step count and the random generator's state."""
        save_state(path, "TabularQAgent", self._state())

    @classmethod
    def load(cls, path: str | Path, env: gym.Env | None = None) -> TabularQAgent:
        """Load a saved agent; with ``env``, check that its spaces match. It logs to the
        ``tensorboard_log`` it was saved with (set ``agent.tensorboard_log = None`` to log no
        more)."""
        state = load_state(path, "TabularQAgent")
        q = state["q"].numpy()
        agent = cls(
            None,
            state["learning_rate"],
            state["gamma"],
            state["epsilon"],
            seed=state["seed"],
            n_states=q.shape[0],
            n_actions=q.shape[1],
        )
        discrete = env is not None and all(
            isinstance(space, gym.spaces.Discrete)
            for space in (env.observation_space, env.action_space)
        )
        starts = tuple(state.get("starts", (0, 0)))  # files without them counted from 0
        if env is not None and (
            not discrete
            or (env.observation_space.n, env.action_space.n) != q.shape
            or (env.observation_space.start, env.action_space.start) != starts
        ):
            raise ValueError(
                f"{path} holds Q for {q.shape[0]} states from id {starts[0]} and {q.shape[1]} "
                f"actions from id {starts[1]}; the env has "
                f"{env.observation_space} and {env.action_space}"
            )
        agent.env, agent.q, agent.num_timesteps = env, q, state["num_timesteps"]
        agent.starts = starts
        agent.env_identity = state.get("env_identity")
        agent.tensorboard_log = state.get("tensorboard_log")
        if env is not None:
            check_same_env(agent.env_identity, env, learning=False)
        agent._seeded = agent.num_timesteps > 0
        if "rng" in state:
            agent.rng.bit_generator.state = state["rng"]
        agent._resume_env_rng = state.get("env_rng")  # set by learn's checkpoints
        return agent
