"""Poses that grasp trials estimate for themselves: NBP on a learned object model, from the
trial scene's cameras, at every reset (``EstimatedPose``)."""

from __future__ import annotations

import os
import time
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import numpy as np
import torch

from vistask.envs.grasp_trial import observation_views
from vistask.envs.objects import (
    object_spec,
)
from vistask.envs.scene import (
    TABLE_TOP_Z,
)
from vistask.objects import NBP, DepthCheck, ObjectModel
from vistask.vision import (
    pose_error,
)

SCENE_BOX = ((-0.4, -0.4, TABLE_TOP_Z + 0.005), (0.4, 0.4, TABLE_TOP_Z + 0.5))
"""World box (min, max corner) of the patches pose estimation looks at: above the table
plane, below and beside nothing else of the arena."""

ESTIMATION_CAMERAS = ("front", "left", "right")
"""Cameras that see grasp trials for pose estimation (none of them the arm's view)."""


class EstimatedPose(gym.Wrapper):
    """Estimates the target's pose from the cameras at every reset, with NBP on a learned
    object model: the pose a robot that sees for itself acts on.

    ``info["estimated_pose"]`` (7,) is the estimate. The true pose stays in
    ``info["object_pose"]`` and only scores it: ``pose_error_m`` and ``pose_error_deg``
    (modulo the object's symmetry), and ``estimate_seconds`` (patches and NBP). NBP looks at
    every patch above the table (``SCENE_BOX``), not at the segmentation: it finds the
    target among the distractors itself, and checks its hypotheses against the depth images
    (``DepthCheck``). If it finds nothing, ``estimate_failed`` is True
    and the estimate is the table centre, upright.

    Example:
        >>> env = GraspTrialEnv("can", cameras=ESTIMATION_CAMERAS, image_size=256)
        >>> env = EstimatedPose(env, ObjectModel.load("can_model.pt"))
        >>> obs, info = env.reset(seed=0)
        >>> info["estimated_pose"], info["pose_error_m"]

    Args:
        env: a ``GraspTrialEnv`` with cameras.
        model: the target's learned object model (``vistask.objects.ObjectModel``).
        nbp: the estimator (default ``NBP()``).
    """

    def __init__(self, env: gym.Env, model: ObjectModel, nbp: NBP | None = None) -> None:
        super().__init__(env)
        if not env.unwrapped.cameras:
            raise ValueError("pose estimation needs cameras: give GraspTrialEnv some")
        self.model = model
        self.nbp = nbp or NBP()
        self.symmetry = object_spec(env.unwrapped.object_kind).symmetry

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Reset the trial and estimate the target's pose: ``info["estimated_pose"]`` (7,), with
        its errors against the true pose."""
        obs, info = self.env.reset(seed=seed, options=options)
        start = time.perf_counter()
        lo, hi = (torch.tensor(c) for c in SCENE_BOX)
        try:
            env = self.env.unwrapped
            scene = env.patches(obs, label=None).in_box(lo, hi)
            views = observation_views(obs, env.cameras).values()
            depth = DepthCheck(views, floor_z=TABLE_TOP_Z)
            pose = self.nbp.infer(self.model, scene, seed=seed or 0, depth=depth).pose.double()
            failed = False
        except ValueError:  # nothing in view matches the model
            pose = torch.tensor([0.0, 0.0, TABLE_TOP_Z, 0.0, 0.0, 0.0, 1.0], dtype=torch.float64)
            failed = True
        truth = torch.as_tensor(info["object_pose"], dtype=torch.float64)
        err_t, err_r = pose_error(pose.float(), truth.float(), self.symmetry)
        info.update(
            estimated_pose=pose.numpy(),
            estimate_failed=failed,
            pose_error_m=float(err_t),
            pose_error_deg=float(err_r),
            estimate_seconds=time.perf_counter() - start,
        )
        return obs, info
