"""The scenes and models of the pose benchmark: test conditions, lookalike distractors,
scene patches and clouds, object models learned from views, and pictures of an estimate."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from vistask.envs.objects import DEFAULT_DISTRACTORS, object_name, object_spec
from vistask.envs.scene import LEARNING_CAMERAS, TABLE_TOP_Z, TEST_CAMERAS
from vistask.objects import ObjectModel
from vistask.objects.registration import view_cloud
from vistask.vision import (
    Patches,
    PatchExtractor,
    RGBDView,
    object_patch_set,
    object_surface,
    view_patches,
)

DEFAULT_OBJECTS = ("cereal", "milk", "bread", "hammer", "can", "box")
METHODS = ("nbp", "open3d", "open3d_dense")
SUCCESS_TRANSLATION_M = 0.02
SUCCESS_ROTATION_DEG = 15.0
TABLE_MARGIN_M = 0.004
"""Points lower than this above the table top belong to the table plane."""
SCENE_HALF_WIDTH_M = 0.4
"""Dense clouds keep the points above the table within this of its centre."""
LOOKALIKE_POOL = (*DEFAULT_DISTRACTORS, "lemon", "bottle", "cube", "round_nut", "square_nut")
"""Objects that lookalike distractors are chosen from (nearest in mean colour)."""
MIN_VISIBLE = 0.15
"""An occluded target still shows at least this fraction in some camera: a target hidden
entirely is not a pose problem."""


@dataclass(frozen=True)
class Condition:
    """How test scenes are made.

    Attributes:
        cameras: the test cameras (none of them used for learning).
        distractors: distractor objects on the table.
        lookalikes: draw the distractors from the ``distractors`` objects of
            ``LOOKALIKE_POOL`` nearest to the target in mean colour.
        occluders: stand the two tallest distractors between the target and the first
            camera (``vistask.envs.objects.place_occluders``).
        max_visible: draw scenes (seeds derived from the scene's) until the target shows
            at most this fraction of its pixels in every camera (and at least
            ``MIN_VISIBLE`` in one); None takes the first draw.
        depth_noise: standard deviation of the depth noise (metres); pixels at depth
            edges drop out with probability 0.5.
        relight: change the lighting at random.
        tip_probability: chance that an object that may tip lies on a side.
        distractor_range: the other distractors' x and y are uniform in +-this (metres)
            around the table centre; the target's in +-0.08.
        max_tries: draws at most; then the most occluded draw is kept.
    """

    cameras: tuple[str, ...] = TEST_CAMERAS[:1]
    distractors: int = 0
    lookalikes: bool = False
    occluders: bool = False
    max_visible: float | None = None
    depth_noise: float = 0.0
    relight: bool = False
    tip_probability: float = 0.0
    distractor_range: float = 0.12
    max_tries: int = 60


CONDITIONS: dict[str, Condition] = {
    "two_cameras": Condition(cameras=TEST_CAMERAS),
    "one_camera": Condition(),
    "depth_noise": Condition(depth_noise=0.002),
    "lighting": Condition(relight=True),
    "tipped": Condition(tip_probability=1.0),
    "clutter": Condition(
        distractors=4,
        lookalikes=True,
        occluders=True,
        max_visible=0.5,
        depth_noise=0.002,
        distractor_range=0.15,
    ),
}


def visible_fraction(scene, world) -> list[float]:
    """Per camera, the target's pixels seen in ``scene`` over those seen with the
    distractors removed (1: not occluded). Re-renders the target alone at its pose in
    ``world`` (the ``TabletopWorld`` the scene came from)."""
    if len(scene.objects) == 1:
        return [1.0] * len(scene.views)
    world.arrange([scene.target], scene.target_pose[None], max_steps=0)
    fractions = []
    for name, view in scene.views.items():
        cam = view.camera
        alone = world.render(name, [scene.target], cam.height, cam.width).mask(0).sum()
        fractions.append(float(view.mask(0).sum()) / max(int(alone), 1))
    return fractions


def lookalikes(world, target: str, k: int) -> list[str]:
    """The ``k`` objects of ``LOOKALIKE_POOL`` (other than ``target``) nearest to it in mean
    colour, each rendered alone, upright, by the top and front cameras."""
    colours = _mean_colours(world)
    name = object_name(target)
    others = [o for o in colours if o != name]
    distance = {o: float(np.linalg.norm(colours[o] - colours[name])) for o in others}
    return sorted(others, key=distance.get)[:k]


@functools.cache
def _mean_colours(world) -> dict[str, np.ndarray]:
    """Mean RGB in [0, 1] of every object of ``world``, rendered alone (once per world)."""
    from vistask.envs.objects import drop_pose, rest_rotation

    colours = {}
    for kind in world.kinds:
        rot = rest_rotation(world.specs[kind])
        upright = drop_pose(world.bounds[kind], rot, (0.0, 0.0), TABLE_TOP_Z)
        world.arrange([kind], upright[None].float())
        pixels = [
            view.rgb[view.mask(0)].float()
            for view in (world.render(c, [kind], 64, 64) for c in ("top", "front"))
        ]
        colours[kind] = torch.cat(pixels).mean(0).numpy() / 255.0
    return colours


def scene_patches(scene, extractor: PatchExtractor | None = None) -> Patches:
    """World-frame patches of every view of a ``Scene``, without the table plane."""
    patches = Patches.cat([view_patches(v, extractor=extractor) for v in scene.views.values()])
    return patches.select(patches.positions[:, 2] > TABLE_TOP_Z + TABLE_MARGIN_M)


def scene_cloud(views: Sequence[RGBDView], voxel: float) -> tuple[torch.Tensor, ...]:
    """Every valid depth pixel of ``views`` above the table (within ``SCENE_HALF_WIDTH_M``
    of its centre), per view down-sampled to ``voxel`` with normals turned towards its
    camera (``view_cloud``): (N, 3) world points, normals and colours in [0, 1]."""
    parts = []
    for view in views:
        p, c = view.point_cloud()
        keep = (p[:, 2] > TABLE_TOP_Z + TABLE_MARGIN_M) & (p[:, :2].abs() < SCENE_HALF_WIDTH_M).all(
            1
        )
        if keep.sum() >= 3:
            parts.append(view_cloud(p[keep], c[keep], view.camera.cam_to_world[:3, 3], voxel))
    if not parts:
        raise ValueError("no depth pixel above the table")
    return tuple(torch.cat(column) for column in zip(*parts, strict=True))


def draw_estimate(view, model: ObjectModel, pose: torch.Tensor, scale: int = 2) -> np.ndarray:
    """The model's patches back-projected into ``view`` at ``pose`` (7,) (paper Fig. 14).

    Returns:
        (scale * H, scale * W, 3) uint8 RGB picture.
    """
    from vistask.vision.draw import draw_patches

    world = model.patches.transform(pose.float().cpu())
    return draw_patches(view.rgb, view.camera, world, length=0.008, scale=scale)


def learn_object_model(
    kind: str,
    tipped: bool = True,
    n_rotations: int = 4,
    image_size: int = 256,
    voxel: float = 0.004,
    extractor: PatchExtractor | None = None,
) -> ObjectModel:
    """The object model of ``kind`` from its own views by the learning cameras: upright at
    ``n_rotations`` yaws, and laid on its sides too when ``tipped`` (and it may tip), one
    patch per ``voxel``, with its surface's colours from the same views."""
    from vistask.envs.tabletop import object_views

    patches, surfaces = [], []
    for side in _rest_sides(kind, tipped):
        views, poses = object_views(kind, n_rotations, LEARNING_CAMERAS, image_size, side)
        patches.append(object_patch_set(views, poses, 0, extractor, voxel))
        surfaces.append(object_surface(views, poses, 0, voxel))
    return ObjectModel.learn(Patches.cat(patches), object_name(kind), surface=torch.cat(surfaces))


def _rest_sides(kind: str, tipped: bool) -> tuple[bool, ...]:
    """The ``tipped`` flags of the views an object is learned from: upright, and lying too
    when ``tipped`` and it may tip."""
    return (False, True) if tipped and object_spec(kind).can_tip else (False,)


def model_cloud(kind: str, n_rotations: int, image_size: int, voxel: float) -> tuple:
    """The dense object-frame cloud of the views ``learn_object_model`` learns from: per
    view, the object's pixels down-sampled to ``voxel`` with normals turned towards the
    camera (``view_cloud``), then moved into the object's frame.

    Returns:
        (N, 3) object-frame points, normals and colours.
    """
    import roma

    from vistask.envs.tabletop import object_views

    parts = []
    for side in _rest_sides(kind, True):
        views, poses = object_views(kind, n_rotations, LEARNING_CAMERAS, image_size, side)
        for view, pose in zip(views, poses, strict=True):
            if view.mask(0).sum() < 3:
                continue
            points, colours = view.point_cloud(view.mask(0))
            eye = view.camera.cam_to_world[:3, 3]
            p, n, c = view_cloud(points, colours, eye, voxel)
            R = roma.unitquat_to_rotmat(pose[3:])
            parts.append(((p - pose[:3]) @ R, n @ R, c))
    return tuple(torch.cat(column) for column in zip(*parts, strict=True))
