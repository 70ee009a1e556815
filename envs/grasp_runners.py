"""Grasp trials side by side: in worker processes (``VectorGraspTrials``) or on a Ray cluster
(``RayGraspTrials``), each a ``vistask.grasp.TrialRunner`` for ``GraspLearner.run_cycle``."""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Sequence
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import numpy as np
import torch

from vistask.envs.estimated_pose import ESTIMATION_CAMERAS, EstimatedPose
from vistask.envs.grasp_trial import GraspTrialEnv
from vistask.grasp.reach import Workspace
from vistask.objects import ObjectModel
from vistask.parallel import one_thread, ray_session, worker_threads


def make_trial_env(
    object_kind: str, model: ObjectModel | None = None, **env_kwargs: Any
) -> gym.Env:
    """A ``GraspTrialEnv``, wrapped in ``EstimatedPose`` when an object ``model`` is given
    (its cameras default to ``ESTIMATION_CAMERAS`` at 256 pixels; without a model they
    default to none: nothing is rendered)."""
    if model is None:
        env_kwargs.setdefault("cameras", ())
        return GraspTrialEnv(object_kind, **env_kwargs)
    env_kwargs.setdefault("cameras", ESTIMATION_CAMERAS)
    env_kwargs.setdefault("image_size", 256)
    return EstimatedPose(GraspTrialEnv(object_kind, **env_kwargs), model)


def _worker_env(object_kind: str, model: ObjectModel | None, env_kwargs: dict) -> gym.Env:
    # One thread per simulator process: the processes already fill the cores.
    one_thread()
    return make_trial_env(object_kind, model, **env_kwargs)


def acting_poses(info: dict[str, Any]) -> torch.Tensor:
    """(B, 7) poses a batch of trials acts on: the estimates if there are, else the truth."""
    key = "estimated_pose" if "estimated_pose" in info else "object_pose"
    return torch.as_tensor(np.asarray(info[key]), dtype=torch.float32)


class VectorGraspTrials:
    """Parallel grasp trials in ``num_envs`` processes (a single one in this process): a
    ``vistask.grasp.TrialRunner``.

    Each call to ``reset`` starts one episode per environment and ``execute`` ends them
    (one grasp each), so gymnasium's autoreset never comes into play. With an object
    ``model``, every trial estimates the object's pose from its cameras (``EstimatedPose``)
    and ``reset`` returns the estimates; without, it returns the true poses.

    Args:
        object_kind: the target object.
        num_envs: parallel environments.
        model: the target's object model, for poses the trials estimate themselves.
        asynchronous: processes (``AsyncVectorEnv``) or this process (default: processes when
            ``num_envs`` > 1; one environment gains nothing from a process of its own and would
            pay for starting it). In this process the trials run on one thread, as a worker's
            do, so that their results are the same.
        **env_kwargs: passed to ``GraspTrialEnv`` (see ``make_trial_env``).
    """

    def __init__(
        self,
        object_kind: str,
        num_envs: int = 2,
        model: ObjectModel | None = None,
        asynchronous: bool | None = None,
        **env_kwargs: Any,
    ) -> None:
        if asynchronous is None:
            asynchronous = num_envs > 1
        if asynchronous:
            fns = [functools.partial(_worker_env, object_kind, model, env_kwargs)] * num_envs
            self.env: gym.vector.VectorEnv = gym.vector.AsyncVectorEnv(fns, context="spawn")
        else:
            fns = [functools.partial(make_trial_env, object_kind, model, **env_kwargs)] * num_envs
            self.env = gym.vector.SyncVectorEnv(fns)
        self._threads = contextlib.nullcontext if asynchronous else worker_threads
        self.num_envs = num_envs
        self.workspace: Workspace = self.env.get_attr("workspace")[0]
        self.object_bounds: np.ndarray = self.env.get_attr("object_bounds")[0]
        self.last_reset_info: dict[str, Any] = {}
        self.last_info: dict[str, Any] = {}

    def reset(self, seeds: Sequence[int]) -> torch.Tensor:
        """Place the objects with one seed per environment; returns the (B, 7) object poses
        to act on (estimated with a model, else true)."""
        if len(seeds) != self.num_envs:
            raise ValueError(f"need {self.num_envs} seeds, got {len(seeds)}")
        with self._threads():
            _, info = self.env.reset(seed=[int(s) for s in seeds])
        self.last_reset_info = info
        return acting_poses(info)

    def execute(self, grasps: torch.Tensor) -> tuple[torch.Tensor, dict[str, Any]]:
        """Execute (B, 7) world grasps; returns (B,) bool successes and the step infos."""
        grasps = np.asarray(torch.as_tensor(grasps, dtype=torch.float64).cpu())
        with self._threads():
            _, reward, _, _, info = self.env.step(grasps)
        self.last_info = info
        return torch.as_tensor(reward > 0.5), info

    def close(self) -> None:
        """Close its simulators and worker processes."""
        self.env.close()


class _TrialActor:
    """One ``GraspTrialEnv`` inside a Ray actor."""

    def __init__(
        self, object_kind: str, model: ObjectModel | None, env_kwargs: dict[str, Any]
    ) -> None:
        self.env = _worker_env(object_kind, model, env_kwargs)

    def describe(self) -> tuple[Workspace, np.ndarray]:
        return self.env.unwrapped.workspace, self.env.unwrapped.object_bounds

    def reset(self, seed: int) -> dict[str, Any]:
        return self.env.reset(seed=seed)[1]

    def execute(self, grasp: np.ndarray) -> tuple[float, dict[str, Any]]:
        _, reward, _, _, info = self.env.step(grasp)
        return reward, info


class RayGraspTrials:
    """Parallel grasp trials on Ray actors, each holding one ``GraspTrialEnv``: a
    ``vistask.grasp.TrialRunner`` that runs on this machine's cores or on a Ray cluster.

    Example:
        >>> runner = RayGraspTrials("can", num_envs=8, address="ray://head:10001")
        >>> poses = runner.reset(range(8)); success, info = runner.execute(grasps)
        >>> runner.close()

    Args:
        object_kind: the target object.
        num_envs: actors (one CPU each).
        address: Ray cluster (default ``RAY_ADDRESS``; None: a local Ray with ``num_envs``
            CPUs).
        model: the target's object model, for poses the trials estimate themselves (as in
            ``VectorGraspTrials``).
        **env_kwargs: passed to ``GraspTrialEnv`` (see ``make_trial_env``).
    """

    def __init__(
        self,
        object_kind: str,
        num_envs: int = 2,
        address: str | None = None,
        model: ObjectModel | None = None,
        **env_kwargs: Any,
    ) -> None:
        self._stack = contextlib.ExitStack()
        ray = self._ray = self._stack.enter_context(ray_session(num_envs, address))
        actor = ray.remote(num_cpus=1)(_TrialActor)
        self.actors = [actor.remote(object_kind, model, env_kwargs) for _ in range(num_envs)]
        self.num_envs = num_envs
        self.workspace, bounds = ray.get(self.actors[0].describe.remote())
        self.object_bounds = np.array(bounds)  # writable, unlike Ray's zero-copy arrays
        self.last_reset_info: dict[str, Any] = {}
        self.last_info: dict[str, Any] = {}

    def reset(self, seeds: Sequence[int]) -> torch.Tensor:
        """Place the objects with one seed per actor; returns the (B, 7) object poses to act
        on (estimated with a model, else true)."""
        if len(seeds) != self.num_envs:
            raise ValueError(f"need {self.num_envs} seeds, got {len(seeds)}")
        infos = self._ray.get(
            [a.reset.remote(int(s)) for a, s in zip(self.actors, seeds, strict=True)]
        )
        self.last_reset_info = _stacked(infos)
        return acting_poses(self.last_reset_info)

    def execute(self, grasps: torch.Tensor) -> tuple[torch.Tensor, dict[str, Any]]:
        """Execute (B, 7) world grasps; returns (B,) bool successes and the infos as arrays
        (as ``VectorGraspTrials`` gives them)."""
        grasps = np.asarray(torch.as_tensor(grasps, dtype=torch.float64).cpu())
        done = self._ray.get(
            [a.execute.remote(g) for a, g in zip(self.actors, grasps, strict=True)]
        )
        rewards = np.array([reward for reward, _ in done])
        self.last_info = _stacked([info for _, info in done])
        return torch.as_tensor(rewards > 0.5), self.last_info

    def close(self) -> None:
        """Close its simulators and worker processes."""
        for actor in self.actors:
            self._ray.kill(actor)
        self._stack.close()


def _stacked(infos: Sequence[dict[str, Any]]) -> dict[str, np.ndarray]:
    """One info per environment -> arrays per key (as gymnasium's vector envs give them)."""
    return {key: np.array([info[key] for info in infos]) for key in infos[0]}
