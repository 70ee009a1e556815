"""Patch extraction on synthetic RGB-D images (no simulator) and the Patches container."""

import math
from pathlib import Path

import pytest
import roma
import torch

from vistask.vision import (
    Camera,
    Patches,
    PatchExtractor,
    intrinsics_from_fovy,
    look_at,
    pixel_grid,
)

H, W = 96, 128
DARK = torch.tensor([20, 40, 160], dtype=torch.uint8)
BRIGHT = torch.tensor([220, 200, 60], dtype=torch.uint8)
extract = PatchExtractor()


def _camera(eye=(0.0, 0.0, 1.0), target=(0.0, 0.0, 0.0)) -> Camera:
    K = intrinsics_from_fovy(50.0, H, W)
    T = look_at(torch.tensor(eye), torch.tensor(target), up=torch.tensor([0.0, 1.0, 0.0]))
    return Camera(K, T, H, W)


def _plane_depth(camera: Camera, normal: torch.Tensor, offset: float) -> torch.Tensor:
    """(H, W) depth of the world plane normal . x = offset seen by ``camera``."""
    rays = torch.cat([pixel_grid(H, W).double(), torch.ones(H, W, 1, dtype=torch.float64)], -1)
    rays_cam = rays @ torch.linalg.inv(camera.K.double()).T  # z component 1: t is the depth
    rays_world = rays_cam @ camera.cam_to_world[:3, :3].T
    n = normal.double()
    return ((offset - n @ camera.position) / (rays_world @ n)).float()


def _step_image(column: int) -> torch.Tensor:
    rgb = torch.empty(H, W, 3, dtype=torch.uint8)
    rgb[:, :column] = DARK
    rgb[:, column:] = BRIGHT
    return rgb


def test_straight_edge_on_a_fronto_parallel_plane() -> None:
    camera = _camera()
    depth = torch.ones(H, W)
    patches = extract(_step_image(W // 2), depth, camera)
    assert len(patches) >= H // extract.spacing - 4
    torch.testing.assert_close(patches.directions.norm(dim=-1), torch.ones(len(patches)))
    # The edge is the world line x = 0 on z = 0; one consistent direction along +-y.
    torch.testing.assert_close(
        patches.positions[:, 2], torch.zeros(len(patches)), atol=1e-5, rtol=0
    )
    assert patches.positions[:, 0].abs().max() < 0.01  # within a pixel (~ 8 mm) of the edge
    expected = patches.directions[0].sign() * torch.tensor([0.0, 1.0, 0.0])
    torch.testing.assert_close(
        patches.directions, expected.expand_as(patches.directions), atol=1e-4, rtol=0
    )
    # Bright side on the left of the direction seen from the camera: the camera looks along
    # -z, so (direction x to_bright) points at the camera (+z).
    to_bright = torch.tensor([1.0, 0.0, 0.0])  # bright columns are world +x here
    assert (
        torch.linalg.cross(patches.directions, to_bright.expand_as(patches.directions))[:, 2].min()
        > 0.99
    )
    # Colours: darker side first, read off the two flat regions.
    torch.testing.assert_close(
        patches.colors[:, 0], (DARK / 255.0).expand(len(patches), 3), atol=0.02, rtol=0
    )
    torch.testing.assert_close(
        patches.colors[:, 1], (BRIGHT / 255.0).expand(len(patches), 3), atol=0.02, rtol=0
    )
    torch.testing.assert_close(
        patches.normals, torch.tensor([0.0, 0.0, 1.0]).expand(len(patches), 3), atol=1e-4, rtol=0
    )


def test_direction_follows_a_tilted_plane() -> None:
    camera = _camera(eye=(0.2, -0.1, 1.0), target=(0.0, 0.0, 0.0))
    normal = torch.nn.functional.normalize(torch.tensor([-0.4, 0.2, 1.0]), dim=0)
    depth = _plane_depth(camera, normal, 0.0)
    patches = extract(_step_image(70), depth, camera)
    # The 3-D edge is where the plane meets the plane through the camera and image column 70.
    top = camera.backproject(torch.tensor([[69.5, 0.0]]), torch.ones(1))[0] - camera.position
    bottom = camera.backproject(torch.tensor([[69.5, H - 1.0]]), torch.ones(1))[0] - camera.position
    line = torch.nn.functional.normalize(
        torch.linalg.cross(torch.linalg.cross(top, bottom), normal.double()), dim=0
    )
    cos = (patches.directions.double() @ line).abs()
    assert torch.rad2deg(torch.acos(cos.clamp(max=1))).max() < 2.0
    assert (patches.positions.double() @ normal.double()).abs().max() < 1e-4  # on the plane
    assert torch.rad2deg(torch.acos((patches.normals @ normal).clamp(max=1))).max() < 1.0
    # Signs agree along the edge (no random flips).
    assert (patches.directions @ patches.directions[0] > 0.99).all()


def test_occluding_contour_takes_the_near_surface() -> None:
    camera = _camera()
    depth = torch.full((H, W), 1.2)
    depth[30:70, 40:90] = 0.8  # a same-coloured square floating in front of a far plane
    rgb = torch.full((H, W, 3), 128, dtype=torch.uint8)
    patches = extract(rgb, depth, camera)
    assert len(patches) > 20  # found from depth alone
    torch.testing.assert_close(
        patches.positions[:, 2], torch.full((len(patches),), 0.2), atol=1e-5, rtol=0
    )
    masked = extract(rgb, depth, camera, mask=depth < 1.0)
    assert len(masked) == len(patches)


def test_clear_errors() -> None:
    camera = _camera()
    rgb = _step_image(W // 2)
    with pytest.raises(ValueError, match="empty mask"):
        extract(rgb, torch.ones(H, W), camera, mask=torch.zeros(H, W, dtype=torch.bool))
    with pytest.raises(ValueError, match="no pixel with valid depth"):
        extract(rgb, torch.full((H, W), float("nan")), camera)
    with pytest.raises(ValueError, match="no patches"):
        extract(torch.full((H, W, 3), 90, dtype=torch.uint8), torch.ones(H, W), camera)
    with pytest.raises(ValueError, match="rgb must"):
        extract(rgb[:10], torch.ones(H, W), camera)
    with pytest.raises(ValueError, match="spacing"):
        PatchExtractor(spacing=0)
    with pytest.raises(ValueError, match="tangent_radius must be >= 1"):
        PatchExtractor(tangent_radius=0)
    with pytest.raises(ValueError, match="max_depth must be positive, got -1"):
        PatchExtractor(max_depth=-1)


@pytest.fixture
def patches() -> Patches:
    return extract(_step_image(W // 2), torch.ones(H, W), _camera())


def test_transform_round_trip_and_frames(patches: Patches) -> None:
    pose = torch.cat(
        [torch.tensor([0.1, -0.2, 0.3]), roma.rotvec_to_unitquat(torch.tensor([0.3, -1.0, 0.5]))]
    )
    moved = patches.transform(pose)
    torch.testing.assert_close(moved.to_frame(pose).positions, patches.positions, atol=1e-6, rtol=0)
    torch.testing.assert_close(moved.directions.norm(dim=-1), torch.ones(len(patches)))
    R = roma.unitquat_to_rotmat(moved.frames()[:, 3:])
    torch.testing.assert_close(R[..., 0], moved.directions, atol=1e-5, rtol=0)
    torch.testing.assert_close(R[..., 2], moved.normals, atol=1e-5, rtol=0)
    torch.testing.assert_close(moved.frames()[:, :3], moved.positions)


def test_select_mask_cat_save(patches: Patches, tmp_path: Path) -> None:
    top = torch.zeros(H, W, dtype=torch.bool)
    top[: H // 2] = True
    upper = patches.in_mask(top)
    assert 0 < len(upper) < len(patches)
    assert (upper.pixels[:, 1] < H // 2).all()
    both = Patches.cat([patches, upper])
    assert len(both) == len(patches) + len(upper) and both.pixels is None
    far = patches.transform(torch.tensor([5.0, 5.0, 5.0, 0.0, 0.0, 0.0, 1.0]))
    assert len(far.voxel_downsample(10.0)) == 1
    assert len(patches.voxel_downsample(1e-4)) == len(patches)
    half = patches.in_box(torch.tensor([-1.0, 0.0, -1.0]), torch.ones(3))
    assert 0 < len(half) < len(patches) and (half.positions[:, 1] >= 0).all()
    patches.save(tmp_path / "p.pt")
    loaded = Patches.load(tmp_path / "p.pt")
    for name in ("positions", "directions", "colors", "normals", "pixels"):
        torch.testing.assert_close(getattr(loaded, name), getattr(patches, name))
    with pytest.raises(ValueError, match="no source pixels"):
        both.in_mask(top)
    with pytest.raises(ValueError, match="directions"):
        Patches(torch.zeros(3, 3), torch.zeros(2, 3), torch.zeros(3, 2, 3))
    assert math.isclose(float(patches.colors.max()), 220 / 255, abs_tol=0.02)
