"""Reproducible cluttered tabletop scenes rendered with robosuite (MuJoCo), with ground truth.

A scene is a robosuite ``TableArena`` with a target object at a random pose (x, y, yaw;
optionally tipped onto a side) plus 0-4 distractors of other kinds, settled by the physics,
then rendered by one or more cameras as RGB, depth (metres) and instance segmentation.

No robot: pose estimation needs none, and an arm would only occlude the table. One MuJoCo
model holds one instance of every object kind and is reused across scenes (compiling a
model and creating a GL context cost about 0.5 s); objects a scene does not use are parked
out of sight with collisions and gravity off.

Conventions: poses (..., 7) ``[tx, ty, tz, qx, qy, qz, qw]`` (roma XYZW), object frame ->
world (MuJoCo's WXYZ is converted here, at the boundary); images and cameras follow
``vistask.vision`` (OpenCV: row 0 at the top, camera x right, y down, z forward).
Segmentation labels are indices into ``Scene.objects`` (0 = target), -1 for everything else.

The table, the cameras and the rendering come from ``vistask.envs.scene`` (shared with the
grasp-trial environment). Rendering uses MUJOCO_GL (set to "egl" here when unset). robosuite's
``camera_utils`` needs h5py, which is not a dependency, so its three camera formulas are
re-done in ``vistask.vision.camera`` and checked against it in the tests when h5py exists.
"""

from __future__ import annotations

import functools
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco
import numpy as np
import roma
import torch
from robosuite.models.objects import (
    BoxObject,
    BreadObject,
    CanObject,
    CerealObject,
    HammerObject,
    MilkObject,
    MujocoObject,
)
from robosuite.models.tasks import ManipulationTask
from robosuite.utils.binding_utils import MjRenderContextOffscreen, MjSim
from torch import Tensor

from vistask.envs.scene import (
    CAMERAS,
    TABLE_TOP_Z,
    CameraSpec,
    add_cameras,
    body_bounds,
    render_view,
    sim_camera,
    table_arena,
    wxyz_to_xyzw,
    xyzw_to_wxyz,
)
from vistask.vision import (
    Camera,
    Patches,
    PatchExtractor,
    RGBDView,
    Symmetry,
    object_patch_set,
    view_patches,
)


@dataclass(frozen=True)
class ObjectSpec:
    """An object kind.

    Attributes:
        make: builds the robosuite object given its name.
        symmetry: rotational symmetry of its shape, in its body frame.
        rest: (4,) XYZW rotation that stands it in its natural rest pose on the table.
        can_tip: whether "tipped" scenes may lay it on a side (not round objects that roll).
    """

    make: Callable[[str], MujocoObject]
    symmetry: Symmetry
    rest: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    can_tip: bool = True


def _hammer(name: str) -> MujocoObject:
    # Fixed sizes and a seeded generator: HammerObject samples its geometry at random.
    return HammerObject(
        name,
        handle_radius=0.016,
        handle_length=0.16,
        handle_density=150.0,
        handle_friction=4.0,
        rng=np.random.default_rng(0),
    )


def _box(name: str) -> MujocoObject:
    return BoxObject(name, size=(0.045, 0.03, 0.02), rgba=(0.15, 0.45, 0.8, 1.0))


OBJECTS: dict[str, ObjectSpec] = {
    # Shape symmetries; textures (can label, cereal print) are ignored, as in the paper's
    # error measure.
    "can": ObjectSpec(CanObject, Symmetry.about_axis((0.0, 0.0, 1.0)), can_tip=False),
    "box": ObjectSpec(_box, Symmetry.box()),
    # Milk carton and cereal box render identically after half a turn about z (same print
    # front and back; checked on rendered images), so no method can tell those poses apart.
    "milk": ObjectSpec(MilkObject, Symmetry.about_axis((0.0, 0.0, 1.0), order=2)),
    "cereal": ObjectSpec(CerealObject, Symmetry.box()),
    "bread": ObjectSpec(BreadObject, Symmetry.none()),
    # robosuite builds the hammer standing on its handle; this lays it flat.
    "hammer": ObjectSpec(_hammer, Symmetry.none(), rest=(0.5, -0.5, 0.5, -0.5), can_tip=False),
}


def object_symmetry(kind: str) -> Symmetry:
    """The shape symmetry of an object kind (see ``OBJECTS``)."""
    return _spec(kind).symmetry


def _spec(kind: str) -> ObjectSpec:
    if kind not in OBJECTS:
        raise ValueError(f"unknown object {kind!r}; known: {sorted(OBJECTS)}")
    return OBJECTS[kind]


@dataclass
class Scene:
    """A rendered tabletop scene with ground truth.

    Attributes:
        seed: the seed it was generated from.
        objects: M object kinds; ``objects[0]`` is the target.
        poses: (M, 7) world poses after settling.
        bounds: (M, 2, 3) object-frame axis-aligned bounding boxes (min corner, max corner).
        views: camera name -> view; segmentation labels index ``objects``, -1 elsewhere.
    """

    seed: int
    objects: list[str]
    poses: Tensor
    bounds: Tensor
    views: dict[str, RGBDView]

    @property
    def target(self) -> str:
        return self.objects[0]

    @property
    def target_pose(self) -> Tensor:
        """(7,) world pose of the target."""
        return self.poses[0]

    def symmetry(self, index: int = 0) -> Symmetry:
        """Shape symmetry of object ``index``."""
        return object_symmetry(self.objects[index])


class TabletopWorld:
    """One MuJoCo model with a table, one instance of every object kind, and cameras.

    Args:
        extra_cameras: cameras added to ``CAMERAS`` and robosuite's four.
    """

    def __init__(self, extra_cameras: Sequence[CameraSpec] = ()) -> None:
        arena = table_arena()
        add_cameras(arena, (*CAMERAS.values(), *extra_cameras))
        self.kinds = list(OBJECTS)
        objects = [OBJECTS[k].make(k) for k in self.kinds]
        task = ManipulationTask(mujoco_arena=arena, mujoco_robots=[], mujoco_objects=objects)
        self.sim = MjSim.from_xml_string(task.get_xml())
        # No multisampling: with it, silhouette pixels mix object and background in colour
        # and depth but not in the segmentation, which then labels background depths.
        self.sim.model._model.vis.quality.offsamples = 0
        self._ctx = MjRenderContextOffscreen(self.sim, device_id=-1)
        # Visual geoms only (group 1); robosuite's collision twins (group 0) and mocap
        # markers (group 2) would otherwise be drawn, and sites are never wanted.
        self._ctx.vopt.geomgroup[:] = 0
        self._ctx.vopt.geomgroup[1] = 1
        self._ctx.vopt.sitegroup[:] = 0

        m = self.sim.model._model
        self._m, self._d = m, self.sim.data._data
        body = {k: m.body(o.root_body).id for k, o in zip(self.kinds, objects, strict=True)}
        joint = {k: m.joint(o.joints[0]) for k, o in zip(self.kinds, objects, strict=True)}
        self._qadr = {k: int(joint[k].qposadr[0]) for k in self.kinds}
        self._vadr = {k: int(joint[k].dofadr[0]) for k in self.kinds}
        self._body = body
        root_of_geom = m.body_rootid[m.geom_bodyid]
        self._geoms = {k: np.nonzero(root_of_geom == body[k])[0] for k in self.kinds}
        self._contype = m.geom_contype.copy()
        self._conaffinity = m.geom_conaffinity.copy()
        self._group = m.geom_group.copy()
        self.bounds = {k: self._object_bounds(k) for k in self.kinds}

    # -- model state --------------------------------------------------------------------

    def _object_bounds(self, kind: str) -> Tensor:
        """(2, 3) object-frame AABB of the object's visual geoms (from MuJoCo's geom AABBs)."""
        visual = [g for g in self._geoms[kind] if self._group[g] == 1]
        bounds = body_bounds(self._m, self._d, self._body[kind], visual)
        return torch.tensor(bounds, dtype=torch.float32)

    def arrange(self, kinds: Sequence[str], poses: Tensor, max_steps: int = 1500) -> Tensor:
        """Put objects at ``poses`` (others parked out of sight) and let them settle.

        Args:
            kinds: M distinct object kinds.
            poses: (M, 7) initial world poses.
            max_steps: physics steps at most (2 ms each); stops earlier once at rest.

        Returns:
            (M, 7) settled world poses.
        """
        if len(set(kinds)) != len(kinds):
            raise ValueError(f"object kinds must be distinct, got {list(kinds)}")
        for k in kinds:
            _spec(k)
        if poses.shape != (len(kinds), 7):
            raise ValueError(f"poses must have shape ({len(kinds)}, 7), got {tuple(poses.shape)}")
        m, d = self._m, self._d
        mujoco.mj_resetData(m, d)
        for i, k in enumerate(self.kinds):
            used = k in kinds
            g = self._geoms[k]
            m.geom_contype[g] = self._contype[g] if used else 0
            m.geom_conaffinity[g] = self._conaffinity[g] if used else 0
            m.geom_group[g] = self._group[g] if used else 3  # group 3 is not rendered
            m.body_gravcomp[self._body[k]] = 0.0 if used else 1.0
            if used:
                pose = poses[list(kinds).index(k)].double().numpy()
                qpos = np.r_[pose[:3], xyzw_to_wxyz(pose[3:])]
            else:  # parked: floating below the floor, no contacts, no gravity, invisible
                qpos = np.r_[0.0, 5.0 + i, -1.0, 1.0, 0.0, 0.0, 0.0]
            d.qpos[self._qadr[k] : self._qadr[k] + 7] = qpos
        mujoco.mj_forward(m, d)
        dofs = np.concatenate([np.arange(self._vadr[k], self._vadr[k] + 6) for k in kinds])
        for step in range(max_steps):
            mujoco.mj_step(m, d)
            if step >= 100 and step % 50 == 0 and np.abs(d.qvel[dofs]).max() < 1e-3:
                break
        mujoco.mj_forward(m, d)
        return torch.stack([self.pose(k) for k in kinds])

    def pose(self, kind: str) -> Tensor:
        """(7,) current world pose of ``kind``'s body (XYZW)."""
        _spec(kind)
        b = self._body[kind]
        q = wxyz_to_xyzw(self._d.xquat[b])
        return torch.tensor(np.r_[self._d.xpos[b], q], dtype=torch.float32)

    # -- rendering ----------------------------------------------------------------------

    def camera(self, name: str, height: int = 256, width: int = 256) -> Camera:
        """The camera ``name`` (OpenCV convention) for images of ``height`` x ``width``."""
        return sim_camera(self._m, self._d, name, height, width)

    def render(
        self, name: str, kinds: Sequence[str], height: int = 256, width: int = 256
    ) -> RGBDView:
        """Render camera ``name``; segmentation labels are indices into ``kinds``.

        Args:
            name: camera name.
            kinds: the objects in the scene, in label order.
            height, width: image size in pixels.
        """
        if height <= 0 or width <= 0 or height > 2048 or width > 2048:
            raise ValueError(f"image size must be in 1..2048, got {height}x{width}")
        return render_view(self.sim, name, height, width, [self._body[k] for k in kinds])

    # -- scenes -------------------------------------------------------------------------

    def generate(
        self,
        seed: int,
        target: str = "cereal",
        n_distractors: int | None = None,
        cameras: Sequence[str] = ("front",),
        image_size: int | tuple[int, int] = 256,
        tipped: bool = False,
        target_range: float = 0.08,
        distractor_range: float = 0.2,
    ) -> Scene:
        """Sample, settle and render a scene; the same arguments give the same scene.

        Args:
            seed: non-negative integer seed.
            target: target object kind.
            n_distractors: number of distractors (distinct kinds, not the target), 0-4;
                None draws it uniformly from 0-4 (at most the number of other kinds).
            cameras: camera names to render.
            image_size: H (square) or (H, W).
            tipped: lay objects that allow it (``ObjectSpec.can_tip``) on a random side.
            target_range: the target's x and y are uniform in +-this (metres).
            distractor_range: distractors' x and y are uniform in +-this (metres).
        """
        if not isinstance(seed, int | np.integer) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        _spec(target)
        H, W = (image_size, image_size) if isinstance(image_size, int) else image_size
        others = [k for k in self.kinds if k != target]
        rng = np.random.default_rng(seed)
        most = min(4, len(others))
        n = int(rng.integers(0, most + 1)) if n_distractors is None else n_distractors
        if not 0 <= n <= most:
            raise ValueError(f"n_distractors must be in 0..{most}, got {n}")
        kinds = [target, *(others[i] for i in rng.choice(len(others), n, replace=False))]
        poses = self._sample_poses(rng, kinds, tipped, target_range, distractor_range)
        poses = self.arrange(kinds, poses)
        views = {c: self.render(c, kinds, H, W) for c in cameras}
        bounds = torch.stack([self.bounds[k] for k in kinds])
        return Scene(int(seed), kinds, poses, bounds, views)

    def _sample_poses(
        self,
        rng: np.random.Generator,
        kinds: Sequence[str],
        tipped: bool,
        target_range: float,
        distractor_range: float,
    ) -> Tensor:
        """(M, 7) collision-free initial poses just above the table."""
        placed: list[tuple[np.ndarray, float]] = []
        poses = []
        for i, k in enumerate(kinds):
            rot = self._rest_rotation(k, rng if tipped else None)
            yaw = torch.tensor([0.0, 0.0, rng.uniform(0.0, 2 * math.pi)], dtype=torch.float64)
            rot = roma.rotvec_to_rotmat(yaw) @ rot
            radius = self._footprint_radius(k, rot)
            span = target_range if i == 0 else distractor_range
            for _ in range(500):
                xy = rng.uniform(-span, span, size=2)
                if all(np.linalg.norm(xy - c) > radius + r + 0.01 for c, r in placed):
                    break
            else:
                raise RuntimeError(f"could not place {k!r} without overlap; widen distractor_range")
            placed.append((xy, radius))
            poses.append(self._drop_pose(k, rot, xy))
        return torch.stack(poses)

    def _rest_rotation(self, kind: str, rng: np.random.Generator | None) -> Tensor:
        """(3, 3) rest orientation; with ``rng`` (and a kind that may tip), laid on a random
        side: +-90 degrees about its x or y axis."""
        spec = OBJECTS[kind]
        rot = roma.unitquat_to_rotmat(torch.tensor(spec.rest, dtype=torch.float64))
        if rng is not None and spec.can_tip:
            axis = np.eye(3)[rng.integers(0, 2)] * rng.choice([-1.0, 1.0]) * (math.pi / 2)
            rot = rot @ roma.rotvec_to_rotmat(torch.from_numpy(axis))
        return rot

    def _corners(self, kind: str, rot: Tensor) -> Tensor:
        """(8, 3) bounding-box corners of ``kind`` rotated by ``rot``, about its origin."""
        lo, hi = self.bounds[kind].double()
        grid = torch.meshgrid(*torch.stack([lo, hi], dim=1), indexing="ij")
        return torch.stack(grid, -1).reshape(-1, 3) @ rot.T

    def _footprint_radius(self, kind: str, rot: Tensor) -> float:
        return float(self._corners(kind, rot)[:, :2].norm(dim=-1).max())

    def _drop_pose(self, kind: str, rot: Tensor, xy: np.ndarray) -> Tensor:
        """(7,) pose at ``xy`` with orientation ``rot``, its lowest corner 3 mm above the table."""
        z = TABLE_TOP_Z + 0.003 - float(self._corners(kind, rot)[:, 2].min())
        t = torch.tensor([float(xy[0]), float(xy[1]), z], dtype=torch.float64)
        return torch.cat([t, roma.rotmat_to_unitquat(rot)]).float()


@functools.cache
def tabletop_world(extra_cameras: tuple[CameraSpec, ...] = ()) -> TabletopWorld:
    """The shared world for these extra cameras (built once per process)."""
    return TabletopWorld(extra_cameras)


def make_scene(
    seed: int,
    target: str = "cereal",
    n_distractors: int | None = None,
    cameras: Sequence[str | CameraSpec] = ("front",),
    image_size: int | tuple[int, int] = 256,
    tipped: bool = False,
) -> Scene:
    """Generate a tabletop scene (see ``TabletopWorld.generate``); reproducible from ``seed``.

    ``cameras`` may name built-in cameras (``vistask.envs.scene.CAMERAS`` and
    ``ROBOSUITE_CAMERAS``) or give ``CameraSpec`` objects.
    """
    extra = tuple(c for c in cameras if isinstance(c, CameraSpec))
    names = [c.name if isinstance(c, CameraSpec) else c for c in cameras]
    world = tabletop_world(extra)
    return world.generate(seed, target, n_distractors, names, image_size, tipped)


def object_views(
    kind: str,
    n_rotations: int = 4,
    cameras: Sequence[str] = ("front", "left", "back", "right", "top"),
    image_size: int = 256,
    tipped: bool = False,
) -> tuple[list[RGBDView], Tensor]:
    """Views of one object alone on the table, for learning its model.

    The object stands at the table centre, turned by ``n_rotations`` yaws evenly spaced
    over a full turn (and laid on its side when ``tipped``); each pose is shot by every camera.

    Returns:
        V = n_rotations * len(cameras) views (label 0 = the object) and (V, 7) object poses.
    """
    _spec(kind)
    if n_rotations < 1:
        raise ValueError(f"n_rotations must be >= 1, got {n_rotations}")
    world = tabletop_world()
    views: list[RGBDView] = []
    poses: list[Tensor] = []
    for j in range(n_rotations):
        side = np.random.default_rng(j) if tipped else None
        yaw = torch.tensor([0.0, 0.0, 2 * math.pi * j / n_rotations], dtype=torch.float64)
        rot = roma.rotvec_to_rotmat(yaw) @ world._rest_rotation(kind, side)
        settled = world.arrange([kind], world._drop_pose(kind, rot, np.zeros(2))[None])[0]
        for c in cameras:
            views.append(world.render(c, [kind], image_size, image_size))
            poses.append(settled)
    return views, torch.stack(poses)


def object_patches(
    kind: str,
    n_rotations: int = 4,
    cameras: Sequence[str] = ("front", "left", "back", "right", "top"),
    image_size: int = 256,
    tipped: bool = False,
    extractor: PatchExtractor | None = None,
    voxel: float | None = None,
) -> Patches:
    """The object-frame patch set of ``kind`` merged from ``object_views`` (see there), by
    ``extractor`` (default ``PatchExtractor()``), one patch per ``voxel`` when given."""
    views, poses = object_views(kind, n_rotations, cameras, image_size, tipped)
    return object_patch_set(views, poses, label=0, extractor=extractor, voxel=voxel)


def benchmark_scenes(
    seeds: Sequence[int],
    target: str = "cereal",
    n_distractors: int | None = None,
    cameras: Sequence[str] = ("front",),
    image_size: int = 256,
    extractor: PatchExtractor | None = None,
) -> dict[str, float]:
    """Time scene generation (sample + settle + render) and patch extraction per scene
    (``extractor``, default ``PatchExtractor()``).

    The first call in a process also builds the world (model, GL context); that one-off cost
    is reported separately as ``setup_seconds``.

    Returns:
        ``setup_seconds``, ``scene_seconds`` and ``patch_seconds`` (means per scene),
        ``total_seconds_per_scene``, ``patches_per_view`` and ``target_patches_per_view``.
    """
    if not seeds:
        raise ValueError("need at least one seed")
    start = time.perf_counter()
    make_scene(seeds[0], target, 0, cameras[:1], 16)  # builds the world, uploads textures
    setup = time.perf_counter() - start
    scene_s, patch_s, counts, target_counts = [], [], [], []
    for seed in seeds:
        start = time.perf_counter()
        scene = make_scene(seed, target, n_distractors, cameras, image_size)
        mid = time.perf_counter()
        for view in scene.views.values():
            patches = view_patches(view, extractor=extractor)
            counts.append(len(patches))
            target_counts.append(len(patches.in_mask(view.mask(0))))
        patch_s.append(time.perf_counter() - mid)
        scene_s.append(mid - start)
    return {
        "setup_seconds": setup,
        "scene_seconds": float(np.mean(scene_s)),
        "patch_seconds": float(np.mean(patch_s)),
        "total_seconds_per_scene": float(np.mean(scene_s) + np.mean(patch_s)),
        "patches_per_view": float(np.mean(counts)),
        "target_patches_per_view": float(np.mean(target_counts)),
    }
