"""Cameras: projection and back-projection against a known synthetic camera."""

import math

import pytest
import torch

from vistask.vision import (
    Camera,
    RGBDView,
    backproject,
    depth_buffer_to_metres,
    intrinsics_from_fovy,
    look_at,
    pixel_grid,
    project,
)

H, W = 48, 64


@pytest.fixture
def camera() -> Camera:
    # Camera 1 m above the origin looking straight down; image "up" is world +y.
    K = intrinsics_from_fovy(60.0, H, W)
    T = look_at(torch.tensor([0.0, 0.0, 1.0]), torch.zeros(3), up=torch.tensor([0.0, 1.0, 0.0]))
    return Camera(K, T, H, W, "test")


def test_known_point(camera: Camera) -> None:
    f = 0.5 * H / math.tan(math.radians(30.0))
    cx, cy = W / 2 - 0.5, H / 2 - 0.5
    # The optical axis hits the principal point; world +x is image right, +y image up.
    points = torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.05, 0.0], [0.0, 0.0, 0.5]], dtype=torch.float64)
    pixels, depth = camera.project(points)
    expected = torch.tensor(
        [[cx, cy], [cx + 0.1 * f, cy - 0.05 * f], [cx, cy]], dtype=torch.float64
    )
    torch.testing.assert_close(pixels, expected)
    torch.testing.assert_close(depth, torch.tensor([1.0, 1.0, 0.5], dtype=torch.float64))
    point = camera.backproject(torch.tensor([[cx + 0.1 * f, cy - 0.05 * f]]), torch.tensor([1.0]))
    torch.testing.assert_close(point, torch.tensor([[0.1, 0.05, 0.0]]), atol=1e-6, rtol=0)


def test_round_trip_from_oblique_camera() -> None:
    gen = torch.Generator().manual_seed(0)
    K = intrinsics_from_fovy(45.0, H, W)
    T = look_at(torch.tensor([0.6, -0.4, 1.3]), torch.tensor([0.0, 0.1, 0.8]))
    pixels = torch.rand(200, 2, generator=gen, dtype=torch.float64) * torch.tensor([W - 1, H - 1])
    depth = 0.3 + torch.rand(200, generator=gen, dtype=torch.float64)
    points = backproject(pixels, depth, K, T)
    pixels2, depth2 = project(points, K, T)
    torch.testing.assert_close(pixels2, pixels)
    torch.testing.assert_close(depth2, depth)
    # Camera-frame depth is the distance along the optical axis.
    axis = T[:3, 2]
    torch.testing.assert_close((points - T[:3, 3]) @ axis, depth)


def test_look_at_is_a_rotation_with_opencv_axes() -> None:
    T = look_at(torch.tensor([1.0, 0.0, 1.0]), torch.zeros(3))
    R = T[:3, :3]
    torch.testing.assert_close(R.T @ R, torch.eye(3, dtype=torch.float64))
    assert torch.det(R) == pytest.approx(1.0)
    torch.testing.assert_close(
        R[:, 2], torch.tensor([-1.0, 0.0, -1.0], dtype=torch.float64) / 2**0.5
    )
    assert R[2, 1] < 0  # image rows grow downwards in the world


def test_depth_buffer_conversion() -> None:
    near, far = 0.01, 50.0
    buffer = torch.tensor([0.0, 0.5, 1.0], dtype=torch.float64)
    depth = depth_buffer_to_metres(buffer, near, far)
    assert depth[0] == pytest.approx(near)
    assert depth[2] == pytest.approx(far)
    # OpenGL perspective depth: buffer = (1/near - 1/z) / (1/near - 1/far).
    assert (1 / near - 1 / depth[1]) / (1 / near - 1 / far) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="depth buffer"):
        depth_buffer_to_metres(torch.tensor([1.5]), near, far)


def test_point_cloud_and_errors(camera: Camera) -> None:
    rgb = torch.zeros(H, W, 3, dtype=torch.uint8)
    depth = torch.ones(H, W)
    depth[:, : W // 2] = float("inf")  # no surface on the left half
    view = RGBDView(rgb, depth, camera, segmentation=torch.full((H, W), -1))
    points, colors = view.point_cloud()
    assert points.shape == (H * W // 2, 3) and colors.shape == points.shape
    torch.testing.assert_close(points[:, 2], torch.zeros(len(points)), atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="empty mask"):
        view.point_cloud(view.mask(0))
    left = torch.zeros(H, W, dtype=torch.bool)
    left[:, :4] = True
    with pytest.raises(ValueError, match="empty point cloud"):
        view.point_cloud(left)
    with pytest.raises(ValueError, match="pixels"):
        backproject(torch.zeros(3, 2), torch.zeros(4), camera.K, camera.cam_to_world)
    with pytest.raises(ValueError, match="K must"):
        project(torch.zeros(3, 3), torch.eye(4), camera.cam_to_world)
    with pytest.raises(ValueError, match="rgb"):
        RGBDView(torch.zeros(H, W, 3), depth, camera)
    assert pixel_grid(2, 3)[1, 2].tolist() == [2.0, 1.0]


def test_depth_noise_is_gaussian_and_drops_only_edge_pixels(camera: Camera) -> None:
    H, W = camera.height, camera.width
    depth = torch.full((H, W), 1.0)
    depth[:, W // 2 :] = 0.7  # one vertical depth edge
    view = RGBDView(torch.zeros(H, W, 3, dtype=torch.uint8), depth, camera)
    same = view.with_depth_noise(0.0, edge_dropout=0.0)
    assert torch.equal(same.depth, depth)
    noisy = view.with_depth_noise(
        0.002, edge_dropout=1.0, generator=torch.Generator().manual_seed(0)
    )
    dropped = torch.isnan(noisy.depth)
    assert dropped[:, W // 2 - 1 : W // 2 + 1].all()  # both sides of the edge
    assert dropped.sum() == 2 * H
    residual = (noisy.depth - depth)[~dropped]
    assert abs(float(residual.std()) - 0.002) < 2e-4 and abs(float(residual.mean())) < 2e-4
    with pytest.raises(ValueError, match="sigma"):
        view.with_depth_noise(-1.0)
