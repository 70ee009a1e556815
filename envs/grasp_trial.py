"""One grasp attempt per episode with a robosuite Panda arm (``vistask/GraspTrial-v0``).

``reset`` puts one object (optionally with distractors) at a random pose on the table (any
yaw, anywhere in a square of the table, laid on a side at random when it may tip), lets it
settle, and returns the scene as seen by RGB-D cameras; ``step(grasp)`` executes one
parallel-jaw grasp at a 6-DoF gripper pose through robosuite's operational-space controller
(OSC_POSE, absolute targets in the world frame) and ends the episode: open, go to the
pre-grasp pose backed off along the approach axis, approach, close, lift, hold. Reward 1 if
the object ends at least ``lift_threshold`` above where it lay while both fingers still
touch it.

Conventions (see ``vistask.se3``): a grasp is a (7,) pose [tx, ty, tz, qx, qy, qz, qw]
(roma XYZW) of the gripper frame in the world. The gripper frame is robosuite's Panda
``grip_site``: origin midway between the fingertip pads, +z the approach direction (from
the palm towards the fingertips), +x the axis along which the fingers close. The two fingers
are interchangeable, so a grasp and the grasp turned by 180 degrees about its approach axis
are the same; the arm executes whichever of the two needs less wrist rotation. Object poses
are the object body's pose in the world; MuJoCo's WXYZ is converted here, at the boundary.

Observations are a Dict of fixed-shape arrays per camera ``c``: ``c_rgb`` (H, W, 3) uint8,
``c_depth`` (H, W) float32 z-depth in metres, ``c_segmentation`` (H, W) int32 (0 the
target, 1.. distractors, -1 anything else, robot included), ``c_intrinsics`` (3, 3) and
``c_extrinsics`` (4, 4) camera-to-world (OpenCV axes), plus ``eef_pose`` (7,). The 3-D
patches of the front end vary in number, so they are not part of the Dict space:
``GraspTrialEnv.patches(obs)`` (or ``observation_views`` + ``vistask.vision``) computes
them on demand. The object's ground-truth pose is in ``info["object_pose"]`` only.
``EstimatedPose`` adds the pose a robot would see for itself (NBP on a learned object
model). With ``cameras=()`` no image is rendered, which is what trial-and-error learning with
ground-truth poses (the ablation) uses: rendering costs more than a grasp.
"""

from __future__ import annotations

import importlib
import logging
import math
import os
import time
from collections.abc import Sequence
from typing import Any, ClassVar

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import mujoco
import numpy as np
import torch
from gymnasium import spaces
from robosuite.controllers import load_composite_controller_config
from robosuite.environments.manipulation.manipulation_env import ManipulationEnv
from robosuite.models.tasks import ManipulationTask
from scipy.spatial.transform import Rotation, Slerp

from vistask.checks import check_at_least, check_positive, checked
from vistask.envs.objects import (
    DEFAULT_DISTRACTORS,
    MAX_DISTRACTORS,
    NoRoomError,
    drop_pose,
    footprint_radius,
    named_object_spec,
    object_spec,
    place_apart,
    rest_rotation,
    yaw_rotation,
)
from vistask.envs.scene import (
    CAMERAS,
    TABLE_SIZE,
    TABLE_TOP_Z,
    add_cameras,
    body_bounds,
    free_joint,
    render_view,
    subtree_geoms,
    table_arena,
    wxyz_to_xyzw,
    xyzw_to_wxyz,
)
from vistask.grasp.reach import Workspace
from vistask.vision import (
    Camera,
    Patches,
    PatchExtractor,
    RGBDView,
    view_patches,
)

# robosuite logs every controller-config load at INFO level; one line per trial env is noise.
logging.getLogger("robosuite_logs").setLevel(logging.WARNING)

PANDA_MAX_OPENING = 0.08  # metres between the fingertip pads, fully open
PLACEMENT_DRAWS = 20
"""Draws of distractors, turns and positions a reset makes before it gives up on room."""


def check_grasp(grasp: Any, tolerance: float = 1e-3) -> np.ndarray:
    """Validate one grasp pose and return it as a float64 array with a renormalised quaternion.

    Args:
        grasp: (7,) [tx, ty, tz, qx, qy, qz, qw] array-like.
        tolerance: allowed deviation of the quaternion norm from 1.

    Raises:
        ValueError: wrong shape, non-finite entries, or a quaternion that is not unit length.
    """
    g = np.asarray(grasp.detach().cpu() if isinstance(grasp, torch.Tensor) else grasp)
    if g.shape != (7,):
        raise ValueError(f"a grasp must have shape (7,) [t, qx, qy, qz, qw], got {g.shape}")
    if not np.issubdtype(g.dtype, np.number):
        raise ValueError(f"a grasp must be numeric, got dtype {g.dtype}")
    g = g.astype(np.float64)
    if not np.isfinite(g).all():
        raise ValueError(f"a grasp must be finite, got {g}")
    norm = np.linalg.norm(g[3:])
    if abs(norm - 1.0) > tolerance:
        raise ValueError(f"the grasp quaternion must have unit norm, got norm {norm:.6f}")
    g[3:] /= norm
    return g


class _GraspScene(ManipulationEnv):
    """A Panda at the table with one instance of each object kind in ``kinds`` (names
    ``vistask.envs.objects.object_spec`` resolves).

    Objects are placed by ``GraspTrialEnv`` after robosuite's reset; extra cameras come from
    ``vistask.envs.scene.CAMERAS``.
    """

    def __init__(self, kinds: Sequence[str], cameras: Sequence[str], **kwargs: Any) -> None:
        self.kinds = list(kinds)
        self.specs = [object_spec(k) for k in self.kinds]
        self.extra_cameras = list(cameras)
        super().__init__(**kwargs)

    def _load_model(self) -> None:
        super()._load_model()
        robot = self.robots[0].robot_model
        robot.set_base_xpos(robot.base_xpos_offset["table"](TABLE_SIZE[0]))
        arena = table_arena()
        arena.set_origin([0, 0, 0])
        add_cameras(arena, [CAMERAS[name] for name in self.extra_cameras])
        self.objects = [spec.make(spec.name) for spec in self.specs]
        self.model = ManipulationTask(
            mujoco_arena=arena,
            mujoco_robots=[r.robot_model for r in self.robots],
            mujoco_objects=self.objects,
        )

    def _setup_references(self) -> None:
        super()._setup_references()
        m = self.sim.model._model
        self.body_ids = [m.body(o.root_body).id for o in self.objects]
        joints = [free_joint(m, o) for o in self.objects]
        self.qpos_addr = [int(joint.qposadr[0]) for joint in joints]
        self.qvel_addr = [int(joint.dofadr[0]) for joint in joints]

    def reward(self, action: Any = None) -> float:
        return 0.0

    def _check_success(self) -> bool:
        return False


@checked
class GraspTrialEnv(gym.Env):
    """One grasp trial per episode (see the module docstring).

    Args:
        object_kind: the target object: a preset, a robosuite object class or an MJCF file
            (``vistask.envs.objects.object_spec``).
        n_distractors: other objects placed around the target (0-4).
        distractors: the kinds distractors are drawn from (the target's kind is left out).
        cameras: camera names from ``vistask.envs.scene.CAMERAS``; () renders nothing.
        image_size: square image side in pixels.
        placement_range: the target's x and y are uniform in +-this (metres, table centre).
        tip_probability: chance that an object that may tip is laid on a random side.
        control_freq: controller rate (Hz); every phase is a fixed number of control steps.
        pregrasp_distance: back-off along the approach axis before the approach (metres).
        lift_height: how far the gripper lifts after closing (metres).
        lift_threshold: minimum object rise for success (metres).
        reach_tolerance: (metres, radians) pre-grasp error beyond which the trial stops as
            unreachable; within it the approach goes on and the grasp decides. Where the
            arm misses the pre-grasp pose it mostly stops 2-4 cm short, and about half of
            those grasps still lift the object: with 2 cm and 0.2 rad, 9-14 of 200 trials an
            object stopped as unreachable, and learned densities succeeded 0.025-0.045 less
            often than with the default (box, bottle, can, bread).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 20}

    # Control steps per phase (at control_freq = 20 Hz: 0.05 s each).
    PHASES: ClassVar[dict[str, int]] = {
        "open": 8,  # the objects settle meanwhile
        "pregrasp": 24,
        "approach": 12,
        "close": 8,
        "lift": 12,
    }
    # Holding still lets the controller close its lag before the next phase. With 6 and 4
    # steps the hand began its approach up to 2 cm off the pre-grasp pose and a finger
    # landed on the object: the box's learned density, its 200 held-out grasps executed
    # again with 16 and 8, succeeded in 198 instead of 179 (the bottle's 174 instead of 161).
    SETTLE: ClassVar[dict[str, int]] = {"pregrasp": 16, "approach": 8, "hold": 8}

    def __init__(
        self,
        object_kind: str = "box",
        n_distractors: int = 2,
        distractors: Sequence[str] = DEFAULT_DISTRACTORS,
        cameras: Sequence[str] = ("front",),
        image_size: int = 128,
        placement_range: float = 0.15,
        tip_probability: float = 0.3,
        control_freq: int = 20,
        pregrasp_distance: float = 0.08,
        lift_height: float = 0.12,
        lift_threshold: float = 0.05,
        reach_tolerance: tuple[float, float] = (0.05, 0.4),
        render_mode: str | None = None,
    ) -> None:
        target = named_object_spec("object_kind", object_kind)
        if isinstance(distractors, str):
            raise TypeError(f"distractors must be a list of object names, got {distractors!r}")
        others = [k for k in distractors if named_object_spec("distractors", k).name != target.name]
        others = list(dict.fromkeys(others))
        if not 0 <= n_distractors <= min(MAX_DISTRACTORS, len(others)):
            raise ValueError(
                f"n_distractors must be in 0..{min(MAX_DISTRACTORS, len(others))} for distractors "
                f"{others}, got {n_distractors}"
            )
        if not 0.0 <= tip_probability <= 1.0:
            raise ValueError(f"tip_probability must be in [0, 1], got {tip_probability}")
        if isinstance(cameras, str):
            raise TypeError(f"cameras must be a list of camera names, got {cameras!r}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        check_at_least(1, image_size=image_size, control_freq=control_freq)
        if not 0 <= placement_range <= TABLE_SIZE[0] / 2:
            raise ValueError(
                f"placement_range must be in [0, {TABLE_SIZE[0] / 2}] metres (the table's half "
                f"width), got {placement_range}"
            )
        check_positive(pregrasp_distance=pregrasp_distance, lift_height=lift_height)
        if not 0 < lift_threshold < lift_height:
            raise ValueError(
                f"lift_threshold must be in (0, lift_height={lift_height}) metres, got "
                f"{lift_threshold}"
            )
        check_positive(**{f"reach_tolerance[{i}]": v for i, v in enumerate(reach_tolerance)})
        unknown = [c for c in cameras if c not in CAMERAS]
        if unknown:
            raise ValueError(f"cameras: unknown {unknown}; known: {sorted(CAMERAS)}")
        self.object_kind = object_kind
        self.n_distractors = n_distractors
        self.cameras = tuple(cameras)
        self.image_size = image_size
        self.placement_range = placement_range
        self.tip_probability = tip_probability
        self.pregrasp_distance = pregrasp_distance
        self.lift_height = lift_height
        self.lift_threshold = lift_threshold
        self.reach_tolerance = reach_tolerance
        self.render_mode = render_mode

        config = load_composite_controller_config(robot="Panda")
        arm = config["body_parts"]["right"]
        # Absolute world-frame targets; the limits only clip, so open them wide.
        arm.update(input_type="absolute", input_ref_frame="world", input_max=10, input_min=-10)
        arm.update(output_max=10, output_min=-10)
        self._scene = _GraspScene(
            [object_kind, *others] if n_distractors else [object_kind],
            self.cameras,
            robots="Panda",
            controller_configs=config,
            initialization_noise=None,
            use_camera_obs=False,
            has_renderer=False,
            has_offscreen_renderer=bool(self.cameras) or render_mode == "rgb_array",
            control_freq=control_freq,
            horizon=10**9,
            ignore_done=True,
            hard_reset=False,
        )
        if self._scene.action_dim != 7:
            raise RuntimeError(f"expected a 7-D OSC_POSE action, got {self._scene.action_dim}")
        self._sim = self._scene.sim
        self._gripper = self._scene.robots[0].gripper["right"]
        self._site = self._sim.model.site_name2id(self._gripper.important_sites["grip_site"])
        self._bounds = [self._collision_bounds(b) for b in self._scene.body_ids]
        self._active: list[int] = []
        self._object_geoms = self._scene.objects
        self._parking = np.array([[2.0 + i, 2.0, 0.1] for i in range(len(self._scene.kinds))])

        self.action_space = spaces.Box(-np.inf, np.inf, shape=(7,), dtype=np.float64)
        obs: dict[str, spaces.Space] = {
            "eef_pose": spaces.Box(-np.inf, np.inf, shape=(7,), dtype=np.float64)
        }
        H = W = image_size
        for c in self.cameras:
            obs[f"{c}_rgb"] = spaces.Box(0, 255, shape=(H, W, 3), dtype=np.uint8)
            obs[f"{c}_depth"] = spaces.Box(0.0, np.inf, shape=(H, W), dtype=np.float32)
            obs[f"{c}_segmentation"] = spaces.Box(-1, 4, shape=(H, W), dtype=np.int32)
            obs[f"{c}_intrinsics"] = spaces.Box(-np.inf, np.inf, shape=(3, 3), dtype=np.float64)
            obs[f"{c}_extrinsics"] = spaces.Box(-np.inf, np.inf, shape=(4, 4), dtype=np.float64)
        self.observation_space = spaces.Dict(obs)
        self._object_pose0: np.ndarray | None = None
        self._done = True

    # -- geometry -----------------------------------------------------------------------

    def _collision_bounds(self, body: int) -> np.ndarray:
        """(2, 3) body-frame AABB of all geoms of the object whose root body is ``body``, its
        other bodies included (collision geoms decide the rest)."""
        m, d = self._sim.model._model, self._sim.data._data
        return body_bounds(m, d, body, subtree_geoms(m, body))

    @property
    def workspace(self) -> Workspace:
        """The geometric reachability filter for this arm and table (``vistask.grasp``)."""
        m, d = self._sim.model._model, self._sim.data._data
        base = d.xpos[m.body(self._scene.robots[0].robot_model.root_body).id]
        # The Panda does not reach pre-grasp poses of approaches flatter than 30 degrees below
        # horizontal this close to the table: 310 of 367 such trials failed as unreachable,
        # against 17 of 333 steeper ones (box, 700 trials over the table's +-15 cm). Between
        # 30 and 44 degrees it fails to reach 83 of 319, and 110 succeed, against 186 and
        # 3045 of 3881 steeper ones (six objects, 4200 trials). Nor does it reach those
        # pointing away from its base: with a horizontal component of 0.4 or more outwards,
        # 54 of 83 trials failed as unreachable, against 37 of 483 others (the six objects'
        # hypothesis densities, 100 trials each on the true poses). A grasp whose open
        # fingers reach below the table top stops with a finger on the table: of the
        # lemon's 700 trials on its estimated poses, those with a fingertip 5 mm or more
        # below the top failed in 0.54, those 5-20 mm above it in 0.10.
        return Workspace(
            floor_z=TABLE_TOP_Z,
            base=tuple(float(v) for v in base),
            max_approach_up=-0.7,
            max_approach_out=0.4,
            pregrasp_distance=self.pregrasp_distance,
            opening=PANDA_MAX_OPENING,
        )

    @property
    def object_bounds(self) -> np.ndarray:
        """(2, 3) object-frame bounding box of the target (collision geometry)."""
        return self._bounds[0].copy()

    def _set_object(self, i: int, pos: np.ndarray, quat_xyzw: np.ndarray) -> None:
        d = self._sim.data._data
        a = self._scene.qpos_addr[i]
        d.qpos[a : a + 7] = np.r_[pos, xyzw_to_wxyz(quat_xyzw)]
        v = self._scene.qvel_addr[i]
        d.qvel[v : v + 6] = 0.0

    def _draw_placement(self) -> tuple[list[int], list, list[np.ndarray]]:
        """The objects on the table (the target first), their rotations and (x, y)
        positions, apart from each other; NoRoomError where they find no room."""
        rng = self.np_random
        active = [0]
        if self.n_distractors:
            pool = rng.choice(len(self._scene.kinds) - 1, self.n_distractors, replace=False)
            active += [1 + int(i) for i in pool]
        rots = [
            yaw_rotation(rng.uniform(0.0, 2 * math.pi))
            @ rest_rotation(self._scene.specs[i], rng, self.tip_probability)
            for i in active
        ]
        radii = [footprint_radius(self._bounds[i], r) for i, r in zip(active, rots, strict=True)]
        spans = [self.placement_range] + [0.25] * (len(active) - 1)
        return active, rots, place_apart(rng, radii, spans, gap=0.03)

    def _place_objects(self) -> None:
        # Other distractors, turned otherwise, may find room where the first drawn did not.
        for attempt in range(PLACEMENT_DRAWS):
            try:
                active, rots, xys = self._draw_placement()
                break
            except NoRoomError as error:
                if attempt == PLACEMENT_DRAWS - 1:
                    raise NoRoomError(
                        f"{self.object_kind} and {self.n_distractors} distractors found no "
                        f"room on the table in {PLACEMENT_DRAWS} draws ({error}); lower "
                        "n_distractors (--distractors) or make the object smaller"
                    ) from None
        for i in range(len(self._scene.kinds)):
            if i not in active:
                self._set_object(i, self._parking[i], np.array([0.0, 0.0, 0.0, 1.0]))
        for i, rot, xy in zip(active, rots, xys, strict=True):
            pose = drop_pose(self._bounds[i], rot, xy, TABLE_TOP_Z).numpy()
            self._set_object(i, pose[:3], pose[3:])
        self._active = active
        self._sim.forward()

    # -- state --------------------------------------------------------------------------

    def object_pose(self, index: int = 0) -> np.ndarray:
        """(7,) world pose (XYZW) of the target (index 0) or of active distractor ``index``."""
        d = self._sim.data._data
        b = self._scene.body_ids[self._active[index]]
        return np.r_[d.xpos[b], wxyz_to_xyzw(d.xquat[b])]

    def eef_pose(self) -> np.ndarray:
        """(7,) world pose (XYZW) of the gripper frame."""
        d = self._sim.data._data
        quat = Rotation.from_matrix(d.site_xmat[self._site].reshape(3, 3)).as_quat()
        return np.r_[d.site_xpos[self._site], quat]

    # -- gymnasium API ------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Home the arm, place the objects at random, open the gripper and observe.

        Returns:
            the observation Dict and ``info`` with ``object_pose`` (7,), ``object_kind``,
            ``object_bounds`` (2, 3) (object frame) and ``distractor_poses`` (K, 7).
        """
        super().reset(seed=seed)
        self._scene.reset()
        self._place_objects()
        home = self.eef_pose()
        for _ in range(self.PHASES["open"]):
            self._act(home[:3], Rotation.from_quat(home[3:]), -1.0)
        self._object_pose0 = self.object_pose()
        self._done = False
        info = {
            "object_pose": self._object_pose0.copy(),
            "object_kind": self.object_kind,
            "object_bounds": self.object_bounds,
            "distractor_poses": np.array(
                [self.object_pose(k) for k in range(1, len(self._active))]
            ).reshape(-1, 7),
        }
        return self._observe(), info

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        """Execute one grasp at ``action`` (7,) (world frame) and end the episode.

        Returns:
            observation, reward (1.0 success / 0.0), terminated=True, truncated=False, and
            ``info``: ``success``, ``reason`` ("success", "unreachable", "missed", "dropped",
            or "simulator" when the simulation failed: ``error`` says how; "" otherwise),
            ``pregrasp_error_t`` / ``_r`` and ``grasp_error_t`` / ``_r`` (reached pose error at
            the pre-grasp and grasp poses: metres, radians; NaN if not reached), ``contact``
            (the gripper touches the object after closing), ``grasped`` (it still does at the
            end), ``lift_height`` (object rise, m), ``sim_seconds``,
            ``wall_seconds``.
        """
        if self._done:
            raise RuntimeError("call reset() before step(): one grasp per episode")
        grasp = check_grasp(action)
        start = time.perf_counter()
        self._done = True
        unstable_before = self._instabilities()
        try:
            info = self._execute(grasp)
            if self._instabilities() > unstable_before:
                # MuJoCo resets a diverging simulation itself and counts a warning.
                raise FloatingPointError("MuJoCo reset a simulation gone NaN or unbounded")
        except Exception as error:  # a simulator failure ends this trial, not the run
            info = self._failed_trial(f"{type(error).__name__}: {error}")
        info["wall_seconds"] = time.perf_counter() - start
        reward = 1.0 if info["success"] else 0.0
        return self._observe(), reward, True, False, info

    def render(self) -> np.ndarray | None:
        """The front camera's RGB image with ``render_mode="rgb_array"`` (None otherwise)."""
        if self.render_mode != "rgb_array":
            return None
        name = self.cameras[0] if self.cameras else "frontview"
        rgb = self._sim.render(width=256, height=256, camera_name=name)
        return rgb[::-1].copy()

    def close(self) -> None:
        """Close the robosuite simulation."""
        self._scene.close()

    # -- the grasp ----------------------------------------------------------------------

    def _act(self, pos: np.ndarray, rot: Rotation, gripper: float) -> None:
        self._scene.step(np.r_[pos, rot.as_rotvec(), gripper])

    def _move(self, pos: np.ndarray, rot: Rotation, steps: int, settle: int, gripper: float):
        """Track a straight line (slerp in orientation) to (pos, rot), then hold there."""
        now = self.eef_pose()
        slerp = Slerp([0.0, 1.0], Rotation.from_quat([now[3:], rot.as_quat()]))
        for k in range(1, steps + 1):
            a = k / steps
            self._act((1 - a) * now[:3] + a * pos, slerp(a), gripper)
        for _ in range(settle):
            self._act(pos, rot, gripper)

    def _pose_error(self, pos: np.ndarray, rot: Rotation) -> tuple[float, float]:
        now = self.eef_pose()
        angle = (Rotation.from_quat(now[3:]).inv() * rot).magnitude()
        return float(np.linalg.norm(now[:3] - pos)), float(angle)

    def _touching(self) -> bool:
        """Whether any gripper geom touches the target."""
        return bool(self._scene.check_contact(self._gripper, self._object_geoms[self._active[0]]))

    def _closer_equivalent(self, rot: Rotation) -> Rotation:
        """``rot`` or ``rot`` turned by pi about its z, whichever is nearer the gripper now."""
        now = Rotation.from_quat(self.eef_pose()[3:])
        flipped = rot * Rotation.from_rotvec([0.0, 0.0, math.pi])
        return flipped if (now.inv() * flipped).magnitude() < (now.inv() * rot).magnitude() else rot

    def _execute(self, grasp: np.ndarray) -> dict[str, Any]:
        pos, rot = grasp[:3], self._closer_equivalent(Rotation.from_quat(grasp[3:]))
        pre = pos - self.pregrasp_distance * rot.apply([0.0, 0.0, 1.0])
        steps0 = self._scene.timestep
        z0 = self._object_pose0[2]
        info: dict[str, Any] = {"success": False, "contact": False, "grasped": False, "error": ""}

        self._move(pre, rot, self.PHASES["pregrasp"], self.SETTLE["pregrasp"], -1.0)
        error_t, error_r = self._pose_error(pre, rot)
        info.update(pregrasp_error_t=error_t, pregrasp_error_r=error_r)
        info.update(grasp_error_t=math.nan, grasp_error_r=math.nan)
        if error_t > self.reach_tolerance[0] or error_r > self.reach_tolerance[1]:
            info.update(reason="unreachable", lift_height=float(self.object_pose()[2] - z0))
        else:
            self._move(pos, rot, self.PHASES["approach"], self.SETTLE["approach"], -1.0)
            info["grasp_error_t"], info["grasp_error_r"] = self._pose_error(pos, rot)
            for _ in range(self.PHASES["close"]):
                self._act(pos, rot, 1.0)
            info["contact"] = self._touching()
            up = pos + np.array([0.0, 0.0, self.lift_height])
            self._move(up, rot, self.PHASES["lift"], self.SETTLE["hold"], 1.0)
            info["lift_height"] = float(self.object_pose()[2] - z0)
            info["grasped"] = self._touching()
            info["success"] = bool(info["lift_height"] >= self.lift_threshold and info["grasped"])
            if info["success"]:
                info["reason"] = "success"
            else:
                info["reason"] = "dropped" if info["contact"] else "missed"
        info["sim_seconds"] = float(self._scene.timestep - steps0) * self._scene.control_timestep
        return info

    def _instabilities(self) -> int:
        """MuJoCo's count of bad (NaN or huge) positions, velocities and accelerations."""
        warnings = self._sim.data._data.warning
        bad = (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL)
        return sum(int(warnings[w].number) for w in (*bad, mujoco.mjtWarning.mjWARN_BADQACC))

    def _failed_trial(self, error: str) -> dict[str, Any]:
        """The info of a trial the simulator could not finish (the next ``reset`` restores a
        sound state): a failure whose ``reason`` is "simulator", with the error."""
        nan = math.nan
        return {
            "success": False,
            "contact": False,
            "grasped": False,
            "reason": "simulator",
            "error": error,
            "pregrasp_error_t": nan,
            "pregrasp_error_r": nan,
            "grasp_error_t": nan,
            "grasp_error_r": nan,
            "lift_height": nan,
            "sim_seconds": nan,
        }

    # -- observations -------------------------------------------------------------------

    def _observe(self) -> dict[str, np.ndarray]:
        obs: dict[str, np.ndarray] = {"eef_pose": self.eef_pose()}
        for c in self.cameras:
            view = self._render_view(c)
            obs[f"{c}_rgb"] = view.rgb.numpy()
            obs[f"{c}_depth"] = view.depth.numpy().astype(np.float32)
            obs[f"{c}_segmentation"] = view.segmentation.numpy().astype(np.int32)
            obs[f"{c}_intrinsics"] = view.camera.K.numpy()
            obs[f"{c}_extrinsics"] = view.camera.cam_to_world.numpy()
        return obs

    def _render_view(self, name: str) -> RGBDView:
        bodies = [self._scene.body_ids[i] for i in self._active]
        return render_view(self._sim, name, self.image_size, self.image_size, bodies)

    def patches(
        self,
        obs: dict[str, np.ndarray],
        label: int | None = 0,
        extractor: PatchExtractor | None = None,
    ) -> Patches:
        """World-frame 3-D patches of object ``label`` (None: whole images) from all cameras,
        by ``extractor`` (default ``PatchExtractor()``)."""
        parts = []
        for view in observation_views(obs, self.cameras).values():
            try:
                parts.append(view_patches(view, label, extractor))
            except ValueError:
                continue  # not visible from this camera
        if not parts:
            raise ValueError(f"object {label} yields no patch in cameras {self.cameras}")
        return Patches.cat(parts)


def observation_views(obs: dict[str, np.ndarray], cameras: Sequence[str]) -> dict[str, RGBDView]:
    """Rebuild ``vistask.vision`` views from an observation Dict (one env, not batched)."""
    views = {}
    for c in cameras:
        rgb = obs[f"{c}_rgb"]
        camera = Camera(
            torch.from_numpy(np.asarray(obs[f"{c}_intrinsics"])),
            torch.from_numpy(np.asarray(obs[f"{c}_extrinsics"])),
            rgb.shape[0],
            rgb.shape[1],
            c,
        )
        views[c] = RGBDView(
            rgb=torch.from_numpy(np.asarray(rgb)),
            depth=torch.from_numpy(np.asarray(obs[f"{c}_depth"])),
            camera=camera,
            segmentation=torch.from_numpy(np.asarray(obs[f"{c}_segmentation"]).astype(np.int64)),
        )
    return views


def top_down_grasp(object_pose: np.ndarray, bounds: np.ndarray, depth: float = 0.02) -> np.ndarray:
    """A scripted top-down grasp of an upright object (for tests and demonstrations).

    The fingers close across the narrower horizontal side of the object's bounding box, the
    fingertips ``depth`` below its top face.

    Args:
        object_pose: (7,) world pose of the object.
        bounds: (2, 3) object-frame bounding box.
        depth: how far below the top face the fingertips go, in metres.

    Returns:
        (7,) world grasp pose.
    """
    lo, hi = bounds
    centre = (lo + hi) / 2
    top = np.r_[centre[:2], hi[2] - depth]
    # Gripper z down (object -z); x (the closing axis) across the narrower horizontal extent.
    x = np.array([1.0, 0.0, 0.0]) if (hi - lo)[0] < (hi - lo)[1] else np.array([0.0, 1.0, 0.0])
    z = np.array([0.0, 0.0, -1.0])
    R_local = np.stack([x, np.cross(z, x), z], axis=1)
    R_obj = Rotation.from_quat(object_pose[3:])
    rot = R_obj * Rotation.from_matrix(R_local)
    return np.r_[R_obj.apply(top) + object_pose[:3], rot.as_quat()]


# Classes that moved to their own modules, which import this one: imported on first use.
_MOVED = {
    "EstimatedPose": "vistask.envs.estimated_pose",
    "VectorGraspTrials": "vistask.envs.grasp_runners",
    "RayGraspTrials": "vistask.envs.grasp_runners",
}


def __getattr__(name: str) -> Any:
    """``EstimatedPose``, ``VectorGraspTrials`` and ``RayGraspTrials`` from their modules."""
    if name in _MOVED:
        return getattr(importlib.import_module(_MOVED[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
