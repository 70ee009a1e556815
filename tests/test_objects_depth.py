"""Pose hypotheses against depth images: a box and an ellipsoid on a table, ray-cast exactly."""

import math

import pytest
import roma
import torch

from vistask.objects import NBP, DepthCheck, ObjectModel
from vistask.objects.model import SURFACE_POINTS
from vistask.objects.nbp import turn_about
from vistask.se3 import apply
from vistask.vision import (
    Camera,
    Patches,
    RGBDView,
    Symmetry,
    intrinsics_from_fovy,
    look_at,
    object_surface,
    pose_error,
)
from vistask.vision.camera import pixel_grid

HALF = torch.tensor([0.05, 0.03, 0.04])  # the box: [-hx, hx] x [-hy, hy] x [0, 2 hz]
TRUTH = torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])


def _rays(eye: tuple[float, float, float], target_z: float, size: int) -> tuple:
    """A camera at ``eye`` looking at (0, 0, ``target_z``), its (3,) position, the (size,
    size, 3) rays of its pixels scaled so that a ray's parameter is the z-depth, and the
    (size, size) z-depth of the plane z = 0 along each."""
    camera = Camera(
        intrinsics_from_fovy(50.0, size, size),
        look_at(torch.tensor(eye), torch.tensor([0.0, 0.0, target_z])),
        size,
        size,
    )
    eye_t = camera.position.float()
    # Points at z-depth 1 minus the eye: along each ray, the parameter is the z-depth.
    rays = camera.backproject(pixel_grid(size, size), torch.ones(size, size)).float() - eye_t
    return camera, eye_t, rays, -eye_t[2] / rays[..., 2]


def _view(eye: tuple[float, float, float], size: int = 96) -> RGBDView:
    """Exact z-depth of the box on the plane z = 0, by slab ray casting."""
    camera, eye_t, rays, plane = _rays(eye, 0.03, size)
    lo = torch.tensor([-HALF[0], -HALF[1], 0.0])
    hi = torch.tensor([HALF[0], HALF[1], 2 * HALF[2]])
    t1, t2 = (lo - eye_t) / rays, (hi - eye_t) / rays
    near = torch.minimum(t1, t2).amax(-1)
    far = torch.maximum(t1, t2).amin(-1)
    depth = torch.where((far >= near) & (near > 0), near, plane)
    return RGBDView(torch.zeros(size, size, 3, dtype=torch.uint8), depth, camera)


def _painted_view(eye: tuple[float, float, float]) -> RGBDView:
    """``_view`` with the box's half x < 0 red and x > 0 blue on a grey table, and the box
    segmented as label 0."""
    view = _view(eye)
    points = view.camera.backproject(pixel_grid(*view.depth.shape), view.depth).float()
    on_box = (points[..., 2] > 1e-4) & (points[..., :2].abs() <= HALF[:2] + 1e-4).all(-1)
    rgb = torch.full((*view.depth.shape, 3), 128, dtype=torch.uint8)
    rgb[on_box & (points[..., 0] < 0)] = torch.tensor([200, 40, 40], dtype=torch.uint8)
    rgb[on_box & (points[..., 0] >= 0)] = torch.tensor([40, 40, 200], dtype=torch.uint8)
    return RGBDView(rgb, view.depth, view.camera, torch.where(on_box, 0, 1))


def _box_points(step: float = 0.008) -> torch.Tensor:
    """(N, 3) points on the box's top and four sides, in its frame."""

    def grid(a: float, b: float) -> tuple[torch.Tensor, torch.Tensor]:
        u = torch.arange(-a, a + 1e-9, step)
        v = torch.arange(-b, b + 1e-9, step)
        return torch.meshgrid(u, v, indexing="ij")

    hx, hy, hz = HALF.tolist()
    faces = []
    x, y = grid(hx, hy)
    faces.append(torch.stack([x, y, torch.full_like(x, 2 * hz)], -1))
    for sign in (-1.0, 1.0):
        x, z = grid(hx, hz)
        faces.append(torch.stack([x, torch.full_like(x, sign * hy), z + hz], -1))
        y, z = grid(hy, hz)
        faces.append(torch.stack([torch.full_like(y, sign * hx), y, z + hz], -1))
    return torch.cat([f.reshape(-1, 3) for f in faces])


def _box_patches() -> Patches:
    """Patches on the box's top and sides, each face with its normal and a colour pair of
    its own (points on an edge count for the first face they lie on)."""
    points = _box_points()
    hx, hy, hz = HALF.tolist()
    on_face = [
        (points[:, 2] > 2 * hz - 1e-6, (0.0, 0.0, 1.0)),
        (points[:, 0] < -hx + 1e-6, (-1.0, 0.0, 0.0)),
        (points[:, 0] > hx - 1e-6, (1.0, 0.0, 0.0)),
        (points[:, 1] < -hy + 1e-6, (0.0, -1.0, 0.0)),
        (points[:, 1] > hy - 1e-6, (0.0, 1.0, 0.0)),
    ]
    face = torch.full((len(points),), -1)
    for k, (mask, _) in reversed(list(enumerate(on_face))):
        face[mask] = k
    normals = torch.tensor([n for _, n in on_face])[face]
    directions = torch.linalg.cross(normals, torch.tensor([0.6, 0.8, 0.0]).expand_as(normals))
    directions[face == 0] = torch.tensor([1.0, 0.0, 0.0])
    pairs = torch.rand(len(on_face), 2, 3, generator=torch.Generator().manual_seed(0))
    return Patches(points, directions, pairs[face], normals)


def _relit_with_strays(box: Patches) -> Patches:
    """The box's patches with colours of no class (another light), and four stray patches
    25-32 cm away that look like its top."""
    relit = Patches(box.positions, box.directions, torch.full_like(box.colors, 0.5), box.normals)
    strays = box.select(box.normals[:, 2] > 0.5).select(torch.arange(4))
    strays = Patches(
        strays.positions + torch.tensor([0.25, 0.2, 0.0]),
        strays.directions,
        strays.colors,
        strays.normals,
    )
    return Patches.cat([relit, strays])


@pytest.fixture(scope="module")
def check() -> DepthCheck:
    return DepthCheck([_view((0.35, -0.3, 0.35)), _view((-0.3, -0.35, 0.3))], floor_z=0.0)


def _moved(dx: float, dy: float, dz: float, yaw_deg: float = 0.0) -> torch.Tensor:
    q = roma.rotvec_to_unitquat(torch.tensor([0.0, 0.0, math.radians(yaw_deg)]))
    return torch.cat([torch.tensor([dx, dy, dz]), q])


def test_the_true_pose_outweighs_floating_sunk_and_shifted_ones(check: DepthCheck) -> None:
    points = _box_points()
    poses = torch.stack(
        [TRUTH, _moved(0, 0, 0.05), _moved(0, 0, -0.03), _moved(0.04, 0, 0), _moved(0, 0, 0, 30)]
    )
    weights = check.weights(poses, points)
    assert weights[0] > 0.9  # the box's points in sight lie on the observed surfaces
    assert weights[1] == 0  # in free space
    assert (weights[2:4] < 0.6 * weights[0]).all()  # sunk into the table, 4 cm aside
    assert weights[4] < weights[0]  # turned 30 degrees
    # A box 5 cm above the table hangs in space both cameras see through.
    floating = check.match(points + torch.tensor([0.0, 0.0, 0.05]))
    free = sum(f.sum() for *_, f, _ in floating) / sum(i.sum() for _, _, i, *_ in floating)
    assert free > 0.3


def test_refinement_pulls_nearby_poses_onto_the_surfaces(check: DepthCheck) -> None:
    points = _box_points()
    starts = torch.stack([_moved(0.01, -0.008, 0.005, 6.0), _moved(-0.006, 0.01, -0.004, -5.0)])
    refined = check.refine(starts, points)
    for pose in refined:
        err_t, err_r = pose_error(pose, TRUTH)
        assert err_t < 0.002 and err_r < 1.5
    # Poses are refined independently of the batch they come in.
    alone = check.refine(starts[1:], points)
    assert torch.allclose(alone[0], refined[1], atol=1e-5)


def test_views_without_depth_leave_poses_unrefined_and_weigh_nothing() -> None:
    view = _view((0.35, -0.3, 0.35))
    blind = DepthCheck([RGBDView(view.rgb, torch.full_like(view.depth, math.nan), view.camera)])
    points, poses = _box_points(), torch.stack([TRUTH, _moved(0.01, 0, 0)])
    assert torch.equal(blind.refine(poses, points), poses)
    assert torch.equal(blind.weights(poses, points), torch.zeros(2))


def test_nbp_finds_by_depth_an_object_whose_appearance_misleads(check: DepthCheck) -> None:
    # The box's own patches show colours of no class (another light); four stray patches
    # elsewhere look like its top. NBP's votes point at the strays; poses voted by patch
    # pairs and screened against the depth, which alone scores so few matches, find the box.
    box = _box_patches()
    model = ObjectModel.learn(box, "box", n_classes=5)
    scene = _relit_with_strays(box)
    assert (model.classify(scene.colors, radius_scale=2.0) >= 0).sum() == 4
    # Without appearance the box fits the depth as well turned by a half turn about any of
    # its axes through its centre (upside down, it fills the same space).
    turns = Symmetry.box().rotations
    centre = torch.tensor([0.0, 0.0, float(HALF[2])])
    shifts = centre - roma.quat_action(turns, centre.expand(len(turns), 3), is_normalized=True)
    fits = torch.cat([shifts, turns], dim=1)
    for pair_references, found in ((0, False), (20, True)):
        nbp = NBP(n_particles=400, mode_starts=24, pair_references=pair_references)
        pose = nbp.infer(model, scene, depth=check).pose
        err_t, err_r = pose_error(pose.expand(len(fits), 7), fits)
        assert bool(((err_t < 0.005) & (err_r < 3.0)).any()) == found


def test_bad_arguments_are_named_in_the_error() -> None:
    view = _view((0.35, -0.3, 0.35))
    with pytest.raises(ValueError, match="at least one view"):
        DepthCheck([])
    with pytest.raises(ValueError, match="tolerance"):
        DepthCheck([view], tolerance=0.0)
    with pytest.raises(ValueError, match="window"):
        DepthCheck([view], window=-1)


def test_points_hidden_behind_other_surfaces_are_not_held_against_a_pose() -> None:
    # A wall in front of the box hides the upper half of its image: the true pose is
    # scored by what can be seen of it, as in the open, and a pose 4 cm aside stays below.
    points, view = _box_points(), _view((0.35, -0.3, 0.35))
    uv, z = view.camera.project(points)
    depth = view.depth.clone()
    depth[: int(uv[:, 1].min() + 0.5 * (uv[:, 1].max() - uv[:, 1].min()))] = 0.7 * z.min()
    walled = DepthCheck([RGBDView(view.rgb, depth, view.camera)], floor_z=0.0)
    poses = torch.stack([TRUTH, _moved(0.04, 0, 0)])
    weights = walled.weights(poses, points)
    assert weights[0] > 0.9 and weights[1] < 0.5 * weights[0]
    ((_, dist, inside, _, hidden),) = walled.match(points)
    assert (dist < walled.tolerance).sum() < 0.4 * inside.sum()  # most of its points are hidden
    assert hidden.sum() > 0.5 * inside.sum()


def test_a_target_showing_a_few_patches_beside_lookalikes_is_found_by_its_region(
    check: DepthCheck,
) -> None:
    # Six patches of the box's corner show; two whole lookalikes stand on the table where
    # the depth images see nothing. Their patches outvote the corner's in the scene's
    # belief; searched on its own, the corner's region gives the box's pose.
    box = _box_patches()
    model = ObjectModel.learn(box, "box", n_classes=5)
    corner = torch.tensor([HALF[0], -HALF[1], 2 * HALF[2]])
    seen = box.select(torch.argsort((box.positions - corner).norm(dim=1))[:6])
    lookalikes = [
        Patches(box.positions + shift, box.directions, box.colors, box.normals)
        for shift in (torch.tensor([0.25, 0.2, 0.0]), torch.tensor([-0.25, 0.2, 0.0]))
    ]
    scene = Patches.cat([seen, *lookalikes])
    for regions, found in ((0, False), (6, True)):
        nbp = NBP(n_particles=400, mode_starts=24, regions=regions)
        for seed in range(3):
            pose = nbp.infer(model, scene, seed=seed, depth=check).pose
            err_t, err_r = pose_error(pose, TRUTH)
            assert bool(err_t < 0.005 and err_r < 3.0) == found


def test_colours_under_the_surface_tell_apart_a_turn_that_the_shape_allows() -> None:
    # The box turned half a turn fills the same space; only its two colours tell the turns.
    views = [_painted_view((0.35, -0.3, 0.35)), _painted_view((-0.3, -0.35, 0.3))]
    check = DepthCheck(views, floor_z=0.0)
    surface = object_surface(views, TRUTH.expand(2, 7))
    assert surface.shape[1] == 6 and (surface[:, 2] > 0).all()  # the box's points, not the table's
    left = surface[:, 0] < -0.01
    assert (surface[left, 3] > 0.7).all() and (
        surface[~left & (surface[:, 0] > 0.01), 5] > 0.7
    ).all()
    poses = torch.stack([TRUTH, _moved(0, 0, 0, 180.0), _moved(0, 0, 0, 90.0)])
    fit = check.weights(poses[:2], _box_points())
    assert fit[0] > 0.9 and torch.isclose(fit[0], fit[1], atol=0.02)  # the depth cannot tell
    agreement = check.colour_agreement(poses, surface, sigma=0.015)
    assert agreement[0] > 0.9 and agreement[1] < 0.1 and agreement[0] > agreement[2]
    # Points that the depth does not explain do not count: a box 5 cm aside scores nothing.
    assert check.colour_agreement(_moved(0.2, 0.2, 0.0)[None], surface, 0.015) == 0


def test_a_model_keeps_its_surface_through_save_and_load(tmp_path) -> None:
    view = _painted_view((0.35, -0.3, 0.35))
    surface = object_surface([view], TRUTH[None])
    model = ObjectModel.learn(_box_patches(), "box", surface=surface)
    assert len(model.surface) == min(len(surface), SURFACE_POINTS)
    model.save(tmp_path / "box.pt")
    assert torch.equal(ObjectModel.load(tmp_path / "box.pt").surface, model.surface)
    with pytest.raises(ValueError, match=r"\(S, 6\)"):
        ObjectModel.learn(_box_patches(), "box", surface=surface[:, :3])


def test_nbp_takes_the_turn_that_its_surface_colours_tell() -> None:
    # The box's patches show colours of no class (another light), as above, so the depth
    # finds it up to its half turns, and patch directions lead to the true turn. Its
    # surface's colours learned from the box turned half a turn (red at x > 0) lead NBP to
    # that turn instead: the colours decide.
    views = [_painted_view((0.35, -0.3, 0.35)), _painted_view((-0.3, -0.35, 0.3))]
    check = DepthCheck(views, floor_z=0.0)
    box = _box_patches()
    scene = _relit_with_strays(box)
    turned = _moved(0.0, 0.0, 0.0, 180.0)
    nbp = NBP(n_particles=400, mode_starts=24)
    for surface, expected in ((None, TRUTH), (object_surface(views, turned.expand(2, 7)), turned)):
        model = ObjectModel.learn(box, "box", n_classes=5, surface=surface)
        for seed in range(2):
            err_t, err_r = pose_error(
                nbp.infer(model, scene, seed=seed, depth=check).pose, expected
            )
            assert err_t < 0.005 and err_r < 3.0


def test_turned_poses_keep_the_centre_and_turn_by_quarter_and_half_turns() -> None:
    poses = torch.stack([TRUTH, _moved(0.1, -0.2, 0.05, 30.0)])
    centre = torch.tensor([0.01, -0.02, 0.04])
    turned = turn_about(poses, centre)
    assert turned.shape == (18, 7)
    same = poses.repeat_interleave(9, dim=0)
    assert torch.allclose(apply(turned, centre), apply(same, centre), atol=1e-6)
    _, angles = pose_error(turned, same)
    assert torch.allclose(angles, torch.tensor([90.0, 180.0, 90.0] * 6), atol=0.1)


def test_nbp_tries_the_turn_that_no_patch_votes_for() -> None:
    # The box's patches are where the box turned half a turn would put them, so every
    # vote points at that turn, which fills the same space; its surface's colours, learned
    # from the true box, tell the truth, which only the tried turns propose.
    views = [_painted_view((0.35, -0.3, 0.35)), _painted_view((-0.3, -0.35, 0.3))]
    check = DepthCheck(views, floor_z=0.0)
    box = _box_patches()
    surface = object_surface(views, TRUTH.expand(2, 7))
    model = ObjectModel.learn(box, "box", n_classes=5, surface=surface)
    half = roma.rotvec_to_unitquat(torch.tensor([0.0, 0.0, math.pi])).expand(len(box), 4)

    def turn(x: torch.Tensor) -> torch.Tensor:
        return roma.quat_action(half, x, is_normalized=True)

    scene = Patches(turn(box.positions), turn(box.directions), box.colors, turn(box.normals))
    for turns in (0, 2):
        nbp = NBP(n_particles=400, mode_starts=24, pair_references=0, regions=0, turns=turns)
        for seed in range(2):
            err_t, err_r = pose_error(nbp.infer(model, scene, seed=seed, depth=check).pose, TRUTH)
            assert (err_t < 0.005 and err_r < 3.0) if turns else err_r > 170.0


AXES = torch.tensor([0.035, 0.02, 0.02])  # an ellipsoid (a lemon) lying on the table along x


def _ellipsoid_view(eye: tuple[float, float, float], size: int = 96) -> RGBDView:
    """Exact z-depth of the ellipsoid resting on the plane z = 0, by ray casting."""
    camera, eye_t, rays, plane = _rays(eye, float(AXES[2]), size)
    # In coordinates scaled by the axes the ellipsoid is the unit sphere: |o + t d| = 1.
    o = (eye_t - torch.tensor([0.0, 0.0, float(AXES[2])])) / AXES
    d = rays / AXES
    a, b, c = d.square().sum(-1), 2 * (d * o).sum(-1), o.square().sum() - 1
    disc = b.square() - 4 * a * c
    near = (-b - disc.clamp_min(0).sqrt()) / (2 * a)
    depth = torch.where((disc >= 0) & (near > 0), near, plane)
    return RGBDView(torch.zeros(size, size, 3, dtype=torch.uint8), depth, camera)


def _ellipsoid_points(n: int = 400) -> tuple[torch.Tensor, torch.Tensor]:
    """(n, 3) points evenly spread over the ellipsoid, in its frame (centred), and (n, 3)
    their outward unit normals."""
    k = torch.arange(n, dtype=torch.float32) + 0.5
    z = 1 - 2 * k / n
    angle = math.pi * (1 + 5**0.5) * k
    sphere = torch.stack([(1 - z**2).sqrt() * angle.cos(), (1 - z**2).sqrt() * angle.sin(), z], -1)
    return sphere * AXES, torch.nn.functional.normalize(sphere / AXES, dim=-1)


ELLIPSOID = torch.tensor([0.0, 0.0, float(AXES[2]), 0.0, 0.0, 0.0, 1.0])  # its true pose


def _axis_error_deg(poses: torch.Tensor) -> torch.Tensor:
    """(H, 7) poses -> (H,) degrees between their long axis and the true one (either way)."""
    axis = roma.quat_action(poses[:, 3:], torch.tensor([1.0, 0.0, 0.0]).expand(len(poses), 3))
    return torch.rad2deg(torch.acos(axis[:, 0].abs().clamp(max=1.0)))


def _ring(elevation_deg: float, n: int = 8) -> list[tuple[float, float, float]]:
    """``n`` camera positions 0.5 m from the ellipsoid, evenly around it."""
    e = math.radians(elevation_deg)
    return [
        (0.5 * math.cos(e) * math.cos(a), 0.5 * math.cos(e) * math.sin(a), 0.5 * math.sin(e))
        for a in torch.arange(n) * 2 * math.pi / n
    ]


def test_refinement_matches_only_the_points_that_face_the_camera() -> None:
    # One camera sees the near side of a smooth ellipsoid. Its far side's points project
    # onto the same pixels; matched there, they tilt the pose off the true one.
    points, normals = _ellipsoid_points()
    truth = ELLIPSOID[None]
    culled, plain = [], []
    for eye in _ring(35.0):
        check = DepthCheck([_ellipsoid_view(eye)], floor_z=0.0)
        culled.append(check.refine(truth, points, normals=normals))
        plain.append(check.refine(truth, points))
    culled, plain = torch.cat(culled), torch.cat(plain)
    assert _axis_error_deg(culled).mean() < 2.5 and _axis_error_deg(plain).mean() > 4.0
    err_t, _ = pose_error(culled, truth.expand_as(culled))
    assert (err_t < 0.002).all()
