"""What the batched vector envs of the maze and the car share: copies of one env stepped as one
array, each copy with its own generator seeded as the single env's ``reset(seed=...)`` would
seed it, no autoreset, and gymnasium's ``TimeLimit`` truncation."""

from __future__ import annotations

from typing import ClassVar

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space


class BatchedCopies(VectorEnv):
    """Base of a vector env stepping ``num_envs`` copies of ``env`` as one batch.

    A subclass keeps the copies' states in arrays, draws a reset copy's start from
    ``self.rngs[i]`` after ``_reset_copies``, and steps them all at once after
    ``_check_actions``; ``_count_step`` gives the truncation flags. Reset ended copies with
    ``reset(options={"reset_mask": mask})``.
    """

    metadata: ClassVar[dict] = {"autoreset_mode": AutoresetMode.DISABLED}

    def _attach(self, env: gym.Env, num_envs: int, max_episode_steps: int | None) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.num_envs, self.max_episode_steps = num_envs, max_episode_steps
        self.single_observation_space = env.observation_space
        self.single_action_space = env.action_space
        self.observation_space = batch_space(env.observation_space, num_envs)
        self.action_space = batch_space(env.action_space, num_envs)
        self.steps = np.zeros(num_envs, dtype=int)
        self.rngs: list[np.random.Generator | None] = [None] * num_envs

    def _reset_copies(self, seed: int | list[int | None] | None, options: dict) -> np.ndarray:
        """Reseed the copies to reset (``options["reset_mask"]``, default all) as
        ``reset(seed=seed + i)`` would, zero their step counts; returns the (num_envs,) mask."""
        mask = options.get("reset_mask", np.ones(self.num_envs, dtype=bool))
        if not (
            isinstance(mask, np.ndarray) and mask.dtype == bool and mask.shape == (self.num_envs,)
        ):
            raise ValueError(f"reset_mask must be a ({self.num_envs},) bool array, got {mask!r}")
        if seed is None or isinstance(seed, int | np.integer):
            seeds = [None if seed is None else int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
        if len(seeds) != self.num_envs:
            raise ValueError(f"need {self.num_envs} seeds, got {len(seeds)}")
        for i in np.flatnonzero(mask):
            if seeds[i] is not None or self.rngs[i] is None:
                self.rngs[i] = seeding.np_random(seeds[i])[0]
        self.steps[mask] = 0
        return mask

    def _check_actions(self, actions) -> np.ndarray:
        """The batch's actions checked against the single action space, after a reset.

        ``Discrete``: (num_envs,) integers in 0..n-1, returned as they are. ``Box``:
        (num_envs, *shape) finite reals within its bounds, or (num_envs,) for a box of shape
        (1,); returned as a float64 (num_envs, *shape) array.
        """
        actions = np.asarray(actions)
        space = self.single_action_space
        if isinstance(space, gym.spaces.Box):
            actions = self._check_box_actions(actions, space)
        else:
            n_actions = int(space.n)
            if (
                actions.shape != (self.num_envs,)
                or not np.issubdtype(actions.dtype, np.integer)
                or actions.min() < 0
                or actions.max() >= n_actions
            ):
                raise ValueError(
                    f"expected {self.num_envs} integer actions in 0..{n_actions - 1}, got {actions}"
                )
        if any(rng is None for rng in self.rngs):
            raise RuntimeError("call reset() before step()")
        return actions

    def _check_box_actions(self, actions: np.ndarray, space: gym.spaces.Box) -> np.ndarray:
        shape = (self.num_envs, *space.shape)
        if space.shape == (1,) and actions.shape == (self.num_envs,):
            actions = actions.reshape(shape)
        # Compare in float64 against the box's float32 bounds, so that a float64 action equal
        # to a bound before rounding (np.pi for a float32 box up to π) is inside.
        if (
            actions.shape != shape
            or actions.dtype.kind not in "iuf"
            or not np.all(np.isfinite(actions))
            or np.any(actions < space.low)
            or np.any(actions > space.high)
        ):
            also = f" (or ({self.num_envs},))" if space.shape == (1,) else ""
            one = space.low.size == 1
            low, high = (space.low.item(), space.high.item()) if one else (space.low, space.high)
            raise ValueError(
                f"expected {self.num_envs} actions as a {shape}{also} array of finite reals"
                f" within [{low}, {high}], got {actions}"
            )
        return actions.astype(np.float64)

    def _count_step(self) -> np.ndarray:
        """Count one step of every copy; (num_envs,) truncation flags, as ``TimeLimit``."""
        self.steps += 1
        if self.max_episode_steps is None:
            return np.zeros(self.num_envs, bool)
        return self.steps >= self.max_episode_steps
