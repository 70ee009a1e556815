"""The robosuite table, its fixed cameras and RGB-D rendering, shared by the tabletop scenes
(``vistask.envs.tabletop``) and the grasp-trial environment (``vistask.envs.grasp_trial``).

Conventions: images and cameras follow ``vistask.vision`` (OpenCV: row 0 at the top, camera x
right, y down, z forward); quaternions are XYZW (roma) except at the MuJoCo boundary, where
``wxyz_to_xyzw`` / ``xyzw_to_wxyz`` convert NumPy arrays. Segmentation labels: label i for the
geoms of the i-th labelled body (its whole subtree), -1 for everything else.

Rendering uses MUJOCO_GL (set to "egl" here when unset).
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco
import numpy as np
import roma
import torch

from vistask.vision import Camera, RGBDView, depth_buffer_to_metres, intrinsics_from_fovy, look_at

TABLE_TOP_Z = 0.8
TABLE_SIZE = (0.8, 0.8, 0.05)
TABLE_CENTRE = (0.0, 0.0, TABLE_TOP_Z)
# MuJoCo cameras look along their -z with y up; OpenCV cameras along +z with y down.
MJ_TO_CV = np.diag([1.0, -1.0, -1.0])


def wxyz_to_xyzw(q: np.ndarray) -> np.ndarray:
    """(..., 4) MuJoCo WXYZ quaternions -> XYZW."""
    return np.asarray(q)[..., [1, 2, 3, 0]]


def xyzw_to_wxyz(q: np.ndarray) -> np.ndarray:
    """(..., 4) XYZW quaternions -> MuJoCo WXYZ."""
    return np.asarray(q)[..., [3, 0, 1, 2]]


@dataclass(frozen=True)
class CameraSpec:
    """A fixed camera at ``eye`` looking at ``target``.

    Attributes:
        name: MuJoCo camera name.
        eye: (3,) position in the world.
        target: (3,) point on the optical axis.
        fovy: vertical field of view in degrees.
        up: world direction that appears up in the image.
    """

    name: str
    eye: tuple[float, float, float]
    target: tuple[float, float, float] = (0.0, 0.0, TABLE_TOP_Z + 0.05)
    fovy: float = 45.0
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)


def _ring(
    name: str, azimuth_deg: float, distance: float = 0.6, elevation_deg: float = 45.0
) -> CameraSpec:
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    target = (0.0, 0.0, TABLE_TOP_Z + 0.05)
    eye = (
        distance * math.cos(e) * math.cos(a),
        distance * math.cos(e) * math.sin(a),
        target[2] + distance * math.sin(e),
    )
    return CameraSpec(name, eye, target)


# Close-up cameras around the table centre (robosuite's own "frontview", "birdview",
# "agentview" and "sideview" are also available, but see the table from farther away).
CAMERAS: dict[str, CameraSpec] = {
    spec.name: spec
    for spec in (
        _ring("front", 0.0),
        _ring("left", 90.0),
        _ring("back", 180.0),
        _ring("right", 270.0),
        CameraSpec("top", (0.0, 0.0, TABLE_TOP_Z + 0.65), up=(1.0, 0.0, 0.0)),
        # Test viewpoints: object models are learned from the five above, never from these.
        _ring("front_left_low", 35.0, distance=0.65, elevation_deg=30.0),
        _ring("back_right_high", 215.0, distance=0.55, elevation_deg=60.0),
    )
}
LEARNING_CAMERAS = ("front", "left", "back", "right", "top")
TEST_CAMERAS = ("front_left_low", "back_right_high")
ROBOSUITE_CAMERAS = ("frontview", "birdview", "agentview", "sideview")


def table_arena():
    """Robosuite's table arena with the table top at ``TABLE_TOP_Z`` over the world origin,
    its rolling friction in force."""
    from robosuite.models.arenas import TableArena  # importing robosuite takes seconds

    arena = TableArena(table_full_size=TABLE_SIZE, table_offset=TABLE_CENTRE)
    # robosuite gives the table a rolling friction but MuJoCo's default 3 contact dimensions,
    # which ignore it: a round object then rocks and rolls for seconds after it is placed,
    # away from the pose the robot saw (docs/results/grasps.md, "Objects at rest").
    arena.table_collision.set("condim", "6")
    return arena


def add_cameras(arena, specs: Iterable[CameraSpec]) -> None:
    """Add fixed cameras to a robosuite arena (before its model is compiled)."""
    for spec in specs:
        cv = look_at(torch.tensor(spec.eye), torch.tensor(spec.target), torch.tensor(spec.up))
        R_mj = cv[:3, :3].numpy() @ MJ_TO_CV
        quat = xyzw_to_wxyz(roma.rotmat_to_unitquat(torch.from_numpy(R_mj)).numpy())
        arena.set_camera(spec.name, spec.eye, quat, camera_attribs={"fovy": str(spec.fovy)})


def sim_camera(
    model: mujoco.MjModel, data: mujoco.MjData, name: str, height: int, width: int
) -> Camera:
    """The MuJoCo camera ``name`` as a ``vistask.vision.Camera`` for ``height`` x ``width``
    images (OpenCV axes, at its current pose).

    Raises:
        ValueError: no camera of that name.
    """
    cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
    if cam_id < 0:
        names = [model.camera(i).name for i in range(model.ncam)]
        raise ValueError(f"unknown camera {name!r}; known: {names}")
    T = np.eye(4)
    T[:3, :3] = data.cam_xmat[cam_id].reshape(3, 3) @ MJ_TO_CV
    T[:3, 3] = data.cam_xpos[cam_id]
    K = intrinsics_from_fovy(float(model.cam_fovy[cam_id]), height, width)
    return Camera(K, torch.from_numpy(T), height, width, name)


def render_view(
    sim, name: str, height: int, width: int, labelled_bodies: Sequence[int]
) -> RGBDView:
    """Render camera ``name`` of a robosuite ``MjSim``: RGB, depth in metres, segmentation.

    Args:
        sim: the simulation (its ``render`` draws offscreen).
        name: camera name.
        height, width: image size in pixels.
        labelled_bodies: body ids; the geoms under ``labelled_bodies[i]`` get label i.
    """
    m, d = sim.model._model, sim.data._data
    camera = sim_camera(m, d, name, height, width)
    # robosuite renders into whichever GL context is current; with several simulations in
    # one process (a tabletop world and a robot, or two worlds) that may be another's.
    context = sim._render_context_offscreen
    if context is not None:
        context.gl_ctx.make_current()
    rgb, buffer = sim.render(width=width, height=height, camera_name=name, depth=True)
    seg = sim.render(width=width, height=height, camera_name=name, segmentation=True)
    label_of_body = np.full(m.nbody, -1, dtype=np.int64)
    for label, body in enumerate(labelled_bodies):
        label_of_body[body] = label
    geom_label = np.r_[label_of_body[m.body_rootid[m.geom_bodyid]], -1]  # last: "no geom"
    is_geom = seg[..., 0] == int(mujoco.mjtObj.mjOBJ_GEOM)
    labels = geom_label[np.where(is_geom, seg[..., 1], -1)]
    extent = m.stat.extent
    depth = depth_buffer_to_metres(
        torch.from_numpy(buffer[::-1].copy()), m.vis.map.znear * extent, m.vis.map.zfar * extent
    )
    return RGBDView(
        rgb=torch.from_numpy(rgb[::-1].copy()),
        depth=depth.float(),
        camera=camera,
        segmentation=torch.from_numpy(labels[::-1].copy()),
    )


def body_bounds(
    model: mujoco.MjModel, data: mujoco.MjData, body: int, geoms: Iterable[int]
) -> np.ndarray:
    """(2, 3) axis-aligned box (min corner, max corner) of ``geoms`` in the frame of ``body``,
    from MuJoCo's geom AABBs at the current state."""
    mujoco.mj_forward(model, data)
    corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
    points = []
    for g in geoms:
        local = model.geom_aabb[g, :3] + corners * model.geom_aabb[g, 3:]  # geom frame
        points.append(geom_to_body(data, g, body, local))
    pts = np.concatenate(points)
    return np.stack([pts.min(0), pts.max(0)])


def geom_to_body(data: mujoco.MjData, geom: int, body: int, points: np.ndarray) -> np.ndarray:
    """(N, 3) ``points`` given in the frame of ``geom``, in the frame of ``body``, at the
    state of ``data`` (after ``mj_forward``)."""
    world = points @ data.geom_xmat[geom].reshape(3, 3).T + data.geom_xpos[geom]
    return (world - data.xpos[body]) @ data.xmat[body].reshape(3, 3)


def subtree_geoms(model: mujoco.MjModel, body: int) -> np.ndarray:
    """(G,) ids of the geoms of ``body`` and of every body below it (``body`` a child of the
    world, as an object's root body is): a lid on a hinge or a handle is part of the object."""
    return np.nonzero(model.body_rootid[model.geom_bodyid] == body)[0]


def free_joint(model: mujoco.MjModel, obj) -> mujoco._structs._MjModelJointViews:
    """The free joint of the robosuite object ``obj`` (listed among its own joints, such as
    a lid's hinge, in any order).

    Raises:
        ValueError: the object has no free joint, so it cannot be placed.
    """
    for name in obj.joints:
        joint = model.joint(name)
        if joint.type[0] == mujoco.mjtJoint.mjJNT_FREE:
            return joint
    raise ValueError(
        f"object {obj.name!r} has no free joint among its joints {list(obj.joints)}: an "
        "object on the table must move freely"
    )
