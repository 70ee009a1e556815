"""Copies of an env that the databases run side by side: a batch its class steps itself, or
copies made again with ``gym.make`` (or deep-copied) in a ``SyncVectorEnv`` whose views are
checked against the observation space."""

from __future__ import annotations

import copy
import inspect
import numbers

import gymnasium as gym
import numpy as np

from vistask.checks import checked, warn


@checked
def vector_copies(env: gym.Env, n_envs: int) -> gym.vector.VectorEnv:
    """``n_envs`` copies of ``env`` as one vector env without autoreset.

    An env whose unwrapped class steps copies of itself as one batch (defines ``vector_copies``,
    as the visual maze does) gets those, with ``gym.make``'s time limit, unless other wrappers
    surround it or it is a subclass (their changes would be lost); any other env is copied
    into a ``SyncVectorEnv`` (``copy_env``).
    """
    inner = env.unwrapped
    if steps_own_copies(env):
        limit = None if env is inner else env.spec.max_episode_steps  # a wrapper has a spec
        return inner.vector_copies(n_envs, limit)
    copies = [_CheckedViews(env)] + [_CheckedViews(copy_env(env)) for _ in range(n_envs - 1)]
    return gym.vector.SyncVectorEnv(
        [lambda e=e: e for e in copies], autoreset_mode=gym.vector.AutoresetMode.DISABLED
    )


class _CheckedViews(gym.Wrapper):
    """Refuses, naming the env, a view that its observation space does not hold: the vector
    env would otherwise fail deep inside its stacking."""

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        return self._checked(obs), info

    def step(self, action):
        obs, *rest = self.env.step(action)
        return self._checked(obs), *rest

    def _checked(self, obs):
        space = self.observation_space
        if not isinstance(obs, np.ndarray) or obs.shape != space.shape or obs.dtype != space.dtype:
            got = f"{np.shape(obs)} {getattr(obs, 'dtype', type(obs).__name__)}"
            raise ValueError(
                f"{self.env.unwrapped} returned a view of shape {got}, but its observation "
                f"space is {space}: views must fit the space (gymnasium.utils.env_checker."
                "check_env finds such bugs)"
            )
        return obs


def steps_own_copies(env: gym.Env) -> bool:
    """Whether ``vector_copies`` takes the batch of copies that ``env``'s class steps itself."""
    inner, spec = env.unwrapped, env.spec
    only_make_wrappers = env is inner or (spec is not None and not spec.additional_wrappers)
    return only_make_wrappers and "vector_copies" in vars(type(inner))


def copy_env(env: gym.Env) -> gym.Env:
    """A fresh env like ``env``: made again from its spec (wrappers included) where it has
    one, since renderers (pygame, MuJoCo) do not deep-copy; else a deep copy. Settings changed
    on ``env`` after ``gym.make`` do not reach a copy made from the spec.

    Raises:
        TypeError: naming the env, where neither works.
    """
    if env.spec is not None:
        try:
            return gym.make(env.spec)
        except Exception:  # a wrapper that does not record its arguments, say
            pass
    try:
        return copy.deepcopy(env)
    except Exception as error:
        raise TypeError(
            f"episodes run side by side on copies of {env.unwrapped}, which cannot be "
            f"deep-copied ({type(error).__name__}: {error}) nor made again with gym.make from "
            "a spec: pass n_envs=1, register the env (gymnasium.register) and make it with "
            "gym.make, or let it deep-copy"
        ) from error


def warn_unmade_settings(env: gym.Env, made: gym.Env) -> None:
    """Warn where ``made``, a copy of ``env`` made again from its spec, differs from ``env`` in
    a setting: an attribute of the unwrapped env named like an argument of its class, a number
    or a string, changed on ``env`` after ``gym.make`` (which the copies do not see)."""
    if env.spec is None or made.unwrapped is env.unwrapped:
        return
    ours, theirs = vars(env.unwrapped), vars(made.unwrapped)
    changed = [
        f"{name} {ours[name]!r} (copies: {theirs[name]!r})"
        for name in inspect.signature(type(env.unwrapped).__init__).parameters
        if isinstance(ours.get(name), numbers.Number | str)
        and type(ours[name]) is type(theirs.get(name))
        and ours[name] != theirs[name]
    ]
    if changed:
        warn(
            f"the env's {', '.join(changed)}: the episodes side by side run on copies made "
            "again by gym.make from its spec, which do not see settings changed after it: "
            "pass them to gym.make, or n_envs=1"
        )
