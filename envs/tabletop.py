"""Reproducible cluttered tabletop scenes rendered with robosuite (MuJoCo), with ground truth.

A scene is a robosuite ``TableArena`` with a target object at a random pose (x, y, yaw;
optionally tipped onto a side) plus 0-4 distractors of other kinds, settled by the physics,
then rendered by one or more cameras as RGB, depth (metres) and instance segmentation.
Objects are named as ``vistask.envs.objects`` resolves them (robosuite classes, presets,
MJCF files).

No robot: pose estimation needs none, and an arm would only occlude the table. One MuJoCo
model holds one instance of each object kind it may show and is reused across scenes (compiling a
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
from collections.abc import Sequence
from dataclasses import dataclass

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco
import numpy as np
import torch
from robosuite.models.tasks import ManipulationTask
from robosuite.utils.binding_utils import MjRenderContextOffscreen, MjSim
from torch import Tensor

from vistask.envs.objects import (
    DEFAULT_DISTRACTORS,
    ObjectSpec,
    distinct_object_specs,
    drop_pose,
    footprint_radius,
    object_spec,
    place_apart,
    place_occluders,
    rest_rotation,
    yaw_rotation,
)
from vistask.envs.scene import (
    CAMERAS,
    LEARNING_CAMERAS,
    TABLE_CENTRE,
    TABLE_TOP_Z,
    CameraSpec,
    add_cameras,
    body_bounds,
    free_joint,
    render_view,
    sim_camera,
    subtree_geoms,
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


def object_symmetry(kind: str) -> Symmetry:
    """The shape symmetry of an object kind (``vistask.envs.objects.object_spec``)."""
    return object_spec(kind).symmetry


@dataclass
class Scene:
    """A rendered tabletop scene with ground truth.

    Attributes:
        seed: the seed it was generated from.
        objects: M object kinds; ``objects[0]`` is the target.
        poses: (M, 7) world poses after settling.
        bounds: (M, 2, 3) object-frame axis-aligned bounding boxes (min corner, max corner).
        views: camera name -> view; segmentation labels index ``objects``, -1 elsewhere.
        symmetries: M shape symmetries.
    """

    seed: int
    objects: list[str]
    poses: Tensor
    bounds: Tensor
    views: dict[str, RGBDView]
    symmetries: list[Symmetry]

    @property
    def target(self) -> str:
        """The target object (the first of ``objects``)."""
        return self.objects[0]

    @property
    def target_pose(self) -> Tensor:
        """(7,) world pose of the target."""
        return self.poses[0]

    def symmetry(self, index: int = 0) -> Symmetry:
        """Shape symmetry of object ``index``."""
        return self.symmetries[index]


class TabletopWorld:
    """One MuJoCo model with a table, one instance of each object kind, and cameras.

    Args:
        kinds: the objects scenes may hold (names for ``vistask.envs.objects.object_spec``);
            kinds of one name and source ("MilkObject", "milk") are one object.
        extra_cameras: cameras added to ``CAMERAS`` and robosuite's four.
    """

    def __init__(
        self, kinds: Sequence[str] = DEFAULT_DISTRACTORS, extra_cameras: Sequence[CameraSpec] = ()
    ) -> None:
        self.specs: dict[str, ObjectSpec] = distinct_object_specs("kinds", kinds)
        self.kinds = list(self.specs)
        arena = table_arena()
        add_cameras(arena, (*CAMERAS.values(), *extra_cameras))
        objects = [spec.make(name) for name, spec in self.specs.items()]
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
        joint = {k: free_joint(m, o) for k, o in zip(self.kinds, objects, strict=True)}
        self._qadr = {k: int(joint[k].qposadr[0]) for k in self.kinds}
        self._vadr = {k: int(joint[k].dofadr[0]) for k in self.kinds}
        self._body = body
        self._geoms = {k: subtree_geoms(m, body[k]) for k in self.kinds}
        self._contype = m.geom_contype.copy()
        self._conaffinity = m.geom_conaffinity.copy()
        self._group = m.geom_group.copy()
        self._lights = (m.light_diffuse.copy(), m.light_pos.copy(), m.light_dir.copy())
        self._headlight = m.vis.headlight.diffuse.copy()
        self.bounds = {k: self._object_bounds(k) for k in self.kinds}

    def _check(self, kind: str) -> str:
        """The world's name of ``kind`` (a name, class or file ``object_spec`` resolves)."""
        name = kind if kind in self.specs else object_spec(kind).name
        if name not in self.specs:
            raise ValueError(f"object {kind!r} is not in this world; it holds {self.kinds}")
        return name

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
        kinds = [self._check(k) for k in kinds]
        if len(set(kinds)) != len(kinds):
            raise ValueError(f"object kinds must be distinct, got {list(kinds)}")
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
                pose = poses[kinds.index(k)].double().numpy()
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
        b = self._body[self._check(kind)]
        q = wxyz_to_xyzw(self._d.xquat[b])
        return torch.tensor(np.r_[self._d.xpos[b], q], dtype=torch.float32)

    def relight(self, rng: np.random.Generator | None = None) -> None:
        """Change the lighting at random (``rng``) or restore the default (None): the lamp's
        brightness (x0.35-1.4) and colour cast (x0.8-1.2 per channel), its position
        (+-0.8 m sideways) and the headlight's brightness (x0.3-1.5)."""
        m = self._m
        diffuse, pos, direction = (a.copy() for a in self._lights)
        headlight = self._headlight.copy()
        if rng is not None:
            diffuse *= rng.uniform(0.35, 1.4) * rng.uniform(0.8, 1.2, size=3)
            pos[:, :2] += rng.uniform(-0.8, 0.8, size=2)
            direction = np.asarray(TABLE_CENTRE) - pos
            direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
            headlight *= rng.uniform(0.3, 1.5)
        m.light_diffuse[:], m.light_pos[:], m.light_dir[:] = diffuse, pos, direction
        m.vis.headlight.diffuse[:] = headlight
        # The renderer reads the lamp's world position and direction from the data, which
        # mj_forward updates: without it a scene showed the previous scene's lamp.
        mujoco.mj_forward(m, self._d)

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
        bodies = [self._body[self._check(k)] for k in kinds]
        return render_view(self.sim, name, height, width, bodies)

    # -- scenes -------------------------------------------------------------------------

    def generate(
        self,
        seed: int,
        target: str = "cereal",
        n_distractors: int | None = None,
        cameras: Sequence[str] = ("front",),
        image_size: int | tuple[int, int] = 256,
        tip_probability: float = 0.0,
        target_range: float = 0.08,
        distractor_range: float = 0.2,
        distractors: Sequence[str] | None = None,
        relight: bool = False,
        occlude_from: Sequence[float] | None = None,
    ) -> Scene:
        """Sample, settle and render a scene; the same arguments give the same scene.

        Args:
            seed: non-negative integer seed.
            target: target object kind.
            n_distractors: number of distractors (distinct kinds, not the target), 0-4;
                None draws it uniformly from 0-4 (at most the number of other kinds).
            cameras: camera names to render.
            image_size: H (square) or (H, W).
            tip_probability: chance that an object that may tip (``ObjectSpec.can_tip``) is
                laid on a random side.
            target_range: the target's x and y are uniform in +-this (metres).
            distractor_range: distractors' x and y are uniform in +-this (metres).
            distractors: the kinds distractors are drawn from (default: every other kind of
                the world, in its order).
            relight: change the lighting at random (``relight``); else the default light.
            occlude_from: a camera position (3,): two distractors stand between the target
                and it (``place_occluders``), the others anywhere.
        """
        if not isinstance(seed, int | np.integer) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        if not 0.0 <= tip_probability <= 1.0:
            raise ValueError(f"tip_probability must be in [0, 1], got {tip_probability}")
        target = self._check(target)
        H, W = (image_size, image_size) if isinstance(image_size, int) else image_size
        pool = self.kinds if distractors is None else [self._check(k) for k in distractors]
        others = [k for k in pool if k != target]
        rng = np.random.default_rng(seed)
        most = min(4, len(others))
        n = int(rng.integers(0, most + 1)) if n_distractors is None else n_distractors
        if not 0 <= n <= most:
            raise ValueError(f"n_distractors must be in 0..{most}, got {n}")
        kinds = [target, *(others[i] for i in rng.choice(len(others), n, replace=False))]
        if occlude_from is not None:  # the tallest hide the most: they go in front
            kinds[1:] = sorted(kinds[1:], key=lambda k: -float(np.ptp(self.bounds[k][:, 2])))
        rots = [
            yaw_rotation(rng.uniform(0.0, 2 * math.pi))
            @ rest_rotation(self.specs[k], rng, tip_probability)
            for k in kinds
        ]
        radii = [footprint_radius(self.bounds[k], r) for k, r in zip(kinds, rots, strict=True)]
        target_xy = place_apart(rng, radii[:1], [target_range], gap=0.01)[0]
        target = (target_xy, radii[0])
        # Two distractors in front of the target (as many as fit in its shadow), if asked.
        front = [] if occlude_from is None else radii[1:3]
        placed = place_occluders(rng, front, 0.01, target, occlude_from[:2]) if front else []
        rest = radii[1 + len(front) :]
        taken = [target, *zip(placed, front, strict=True)]
        others = placed + place_apart(rng, rest, [distractor_range] * len(rest), 0.01, taken)
        xys = [target_xy, *others]
        initial = [
            drop_pose(self.bounds[k], r, xy, TABLE_TOP_Z)
            for k, r, xy in zip(kinds, rots, xys, strict=True)
        ]
        poses = self.arrange(kinds, torch.stack(initial).float())
        self.relight(rng if relight else None)
        views = {c: self.render(c, kinds, H, W) for c in cameras}
        bounds = torch.stack([self.bounds[k] for k in kinds])
        symmetries = [self.specs[k].symmetry for k in kinds]
        return Scene(int(seed), kinds, poses, bounds, views, symmetries)


@functools.cache
def _world(kinds: tuple[str, ...], extra_cameras: tuple[CameraSpec, ...]) -> TabletopWorld:
    return TabletopWorld(kinds, extra_cameras)


def tabletop_world(
    kinds: Sequence[str] = DEFAULT_DISTRACTORS, extra_cameras: tuple[CameraSpec, ...] = ()
) -> TabletopWorld:
    """The shared world holding ``kinds`` with these extra cameras (built once per process
    for each set of kinds)."""
    return _world(tuple(sorted(set(map(str, kinds)))), tuple(extra_cameras))


def make_scene(
    seed: int,
    target: str = "cereal",
    n_distractors: int | None = None,
    cameras: Sequence[str | CameraSpec] = ("front",),
    image_size: int | tuple[int, int] = 256,
    tip_probability: float = 0.0,
    distractors: Sequence[str] = DEFAULT_DISTRACTORS,
) -> Scene:
    """Generate a tabletop scene (see ``TabletopWorld.generate``); reproducible from ``seed``.

    ``cameras`` may name built-in cameras (``vistask.envs.scene.CAMERAS`` and
    ``ROBOSUITE_CAMERAS``) or give ``CameraSpec`` objects.
    """
    extra = tuple(c for c in cameras if isinstance(c, CameraSpec))
    names = [c.name if isinstance(c, CameraSpec) else c for c in cameras]
    world = tabletop_world([target, *distractors], extra)
    return world.generate(
        seed, target, n_distractors, names, image_size, tip_probability, distractors=distractors
    )


def object_views(
    kind: str,
    n_rotations: int = 4,
    cameras: Sequence[str] = LEARNING_CAMERAS,
    image_size: int = 256,
    tipped: bool = False,
) -> tuple[list[RGBDView], Tensor]:
    """Views of one object alone on the table, for learning its model.

    The object stands at the table centre, turned by ``n_rotations`` yaws evenly spaced
    over a full turn (and laid on a side, drawn per yaw, when ``tipped``); each pose is shot
    by every camera.

    Returns:
        V = n_rotations * len(cameras) views (label 0 = the object) and (V, 7) object poses.
    """
    if n_rotations < 1:
        raise ValueError(f"n_rotations must be >= 1, got {n_rotations}")
    world = tabletop_world([kind])
    name = world._check(kind)
    spec, bounds = world.specs[name], world.bounds[name]
    views: list[RGBDView] = []
    poses: list[Tensor] = []
    for j in range(n_rotations):
        rest = rest_rotation(spec, np.random.default_rng(j), float(tipped))
        rot = yaw_rotation(2 * math.pi * j / n_rotations) @ rest
        settled = world.arrange([name], drop_pose(bounds, rot, (0.0, 0.0), TABLE_TOP_Z)[None])[0]
        for c in cameras:
            views.append(world.render(c, [name], image_size, image_size))
            poses.append(settled)
    return views, torch.stack(poses)


def object_patches(
    kind: str,
    n_rotations: int = 4,
    cameras: Sequence[str] = LEARNING_CAMERAS,
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
