"""Pinhole cameras and RGB-D views in the OpenCV convention.

Conventions (used by the whole of ``vistask.vision``):

- Images are stored row 0 at the top (OpenCV). Pixel coordinates are ``(u, v)`` =
  (column, row), float, with the *centre* of pixel ``[row, col]`` at ``(col, row)``.
- Camera frame: x right, y down, z forward (viewing direction); depth is the z coordinate
  in the camera frame (MuJoCo's depth buffer is z-depth, not ray length).
- ``cam_to_world`` (4, 4) maps camera-frame points to world points.

Everything here is pure torch: robosuite only fills these structures (``vistask.envs.scene``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from vistask.checks import check_at_least, check_positive, checked


def _check_camera(K: Tensor, cam_to_world: Tensor) -> None:
    if K.shape != (3, 3):
        raise ValueError(f"K must have shape (3, 3), got {tuple(K.shape)}")
    if cam_to_world.shape != (4, 4):
        raise ValueError(f"cam_to_world must have shape (4, 4), got {tuple(cam_to_world.shape)}")
    if not (torch.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(f"K must be finite with focal lengths K[0, 0], K[1, 1] > 0, got {K}")
    rotation = cam_to_world[:3, :3].double()
    rigid = torch.allclose(rotation.T @ rotation, torch.eye(3, dtype=torch.float64), atol=1e-4)
    if not (rigid and torch.isfinite(cam_to_world).all()):
        raise ValueError("cam_to_world must be a rigid transform (its 3x3 block a rotation)")


@checked
def backproject(pixels: Tensor, depth: Tensor, K: Tensor, cam_to_world: Tensor) -> Tensor:
    """Lift pixels with depth to world points.

    Args:
        pixels: (..., 2) pixel coordinates (u, v), OpenCV convention.
        depth: (...) z-depth in metres.
        K: (3, 3) intrinsics.
        cam_to_world: (4, 4) camera-to-world transform.

    Returns:
        (..., 3) world points.
    """
    _check_camera(K, cam_to_world)
    if pixels.shape[-1] != 2 or pixels.shape[:-1] != depth.shape:
        raise ValueError(
            f"pixels (..., 2) and depth (...) disagree: "
            f"{tuple(pixels.shape)} vs {tuple(depth.shape)}"
        )
    dtype = torch.promote_types(pixels.dtype, torch.float32)
    K = K.to(dtype)
    cam_to_world = cam_to_world.to(dtype)
    u, v = pixels[..., 0].to(dtype), pixels[..., 1].to(dtype)
    z = depth.to(dtype)
    x = (u - K[0, 2] - K[0, 1] * (v - K[1, 2]) / K[1, 1]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    cam = torch.stack([x, y, z], dim=-1)
    return cam @ cam_to_world[:3, :3].T + cam_to_world[:3, 3]


@checked
def project(points: Tensor, K: Tensor, cam_to_world: Tensor) -> tuple[Tensor, Tensor]:
    """Project world points into the image.

    Args:
        points: (..., 3) world points.
        K: (3, 3) intrinsics.
        cam_to_world: (4, 4) camera-to-world transform.

    Returns:
        pixels (..., 2) as (u, v) and depth (...) (z in the camera frame; <= 0 behind it).
    """
    _check_camera(K, cam_to_world)
    if points.shape[-1] != 3:
        raise ValueError(f"points must have shape (..., 3), got {tuple(points.shape)}")
    dtype = torch.promote_types(points.dtype, torch.float32)
    R = cam_to_world[:3, :3].to(dtype)
    t = cam_to_world[:3, 3].to(dtype)
    cam = (points.to(dtype) - t) @ R  # R^T (p - t), batched
    z = cam[..., 2]
    uvw = cam @ K.to(dtype).T
    return uvw[..., :2] / z.unsqueeze(-1), z


@checked
def intrinsics_from_fovy(fovy_deg: float, height: int, width: int) -> Tensor:
    """Intrinsics of a MuJoCo camera (square pixels, vertical field of view ``fovy_deg``).

    Same focal length as ``robosuite.utils.camera_utils.get_camera_intrinsic_matrix``; the
    principal point is shifted by half a pixel because robosuite's ``(W/2, H/2)`` is in
    pixel-corner coordinates, while ours put pixel centres on integers (OpenCV).

    Returns:
        (3, 3) float64 intrinsics.
    """
    check_at_least(1, height=height, width=width)
    if not 0 < fovy_deg < 180:
        raise ValueError(f"fovy_deg must be in (0, 180) degrees, got {fovy_deg}")
    f = 0.5 * height / math.tan(math.radians(fovy_deg) / 2)
    return torch.tensor(
        [[f, 0.0, width / 2 - 0.5], [0.0, f, height / 2 - 0.5], [0.0, 0.0, 1.0]],
        dtype=torch.float64,
    )


@checked
def look_at(eye: Tensor, target: Tensor, up: Tensor | None = None) -> Tensor:
    """Camera-to-world transform (OpenCV axes) of a camera at ``eye`` looking at ``target``.

    Args:
        eye: (3,) camera centre.
        target: (3,) point on the optical axis.
        up: (3,) world up direction (default +z); image rows grow against it.

    Returns:
        (4, 4) float64 camera-to-world transform.
    """
    eye = torch.as_tensor(eye, dtype=torch.float64)
    target = torch.as_tensor(target, dtype=torch.float64)
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64) if up is None else up.double()
    for name, vector in (("eye", eye), ("target", target), ("up", up)):
        if vector.shape != (3,):
            raise ValueError(f"{name} must have shape (3,), got {tuple(vector.shape)}")
    forward = target - eye
    if forward.norm() < 1e-9:
        raise ValueError("eye and target coincide")
    z = forward / forward.norm()
    x = torch.linalg.cross(z, up)
    if x.norm() < 1e-9:
        raise ValueError("viewing direction is parallel to up")
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    T = torch.eye(4, dtype=torch.float64)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, eye
    return T


@checked
def depth_buffer_to_metres(buffer: Tensor, near: float, far: float) -> Tensor:
    """Convert an OpenGL depth buffer in [0, 1] to z-depth in metres.

    Same formula as ``robosuite.utils.camera_utils.get_real_depth_map`` with
    ``near = model.vis.map.znear * model.stat.extent`` and ``far = model.vis.map.zfar * extent``.

    Args:
        buffer: (H, W) depth buffer values in [0, 1].
        near: distance of the near clipping plane, in metres.
        far: distance of the far clipping plane, in metres.

    Returns:
        (H, W) depth in metres; the far plane maps to ``far``.
    """
    if buffer.numel() and (buffer.min() < 0 or buffer.max() > 1):
        raise ValueError("depth buffer values must lie in [0, 1]")
    if not 0 < near < far:
        raise ValueError(f"near and far must satisfy 0 < near < far, got {near}, {far}")
    return near / (1.0 - buffer * (1.0 - near / far))


@checked
def pixel_grid(height: int, width: int, device: torch.device | str | None = None) -> Tensor:
    """(H, W, 2) pixel coordinates (u, v) of every pixel centre."""
    check_at_least(0, height=height, width=width)
    v, u = torch.meshgrid(
        torch.arange(height, dtype=torch.float32, device=device),
        torch.arange(width, dtype=torch.float32, device=device),
        indexing="ij",
    )
    return torch.stack([u, v], dim=-1)


@checked
@dataclass
class Camera:
    """A pinhole camera.

    Attributes:
        K: (3, 3) intrinsics (OpenCV: pixel centres on integers).
        cam_to_world: (4, 4) camera-to-world transform (x right, y down, z forward).
        height: image height in pixels.
        width: image width in pixels.
        name: camera name (e.g. the MuJoCo camera it came from).
    """

    K: Tensor
    cam_to_world: Tensor
    height: int
    width: int
    name: str = ""

    def __post_init__(self) -> None:
        _check_camera(self.K, self.cam_to_world)
        if self.height <= 0 or self.width <= 0:
            raise ValueError(f"image size must be positive, got {self.height}x{self.width}")

    @property
    def position(self) -> Tensor:
        """(3,) camera centre in the world."""
        return self.cam_to_world[:3, 3]

    def backproject(self, pixels: Tensor, depth: Tensor) -> Tensor:
        """(..., 2) pixels + (...) depth -> (..., 3) world points; see :func:`backproject`."""
        return backproject(pixels, depth, self.K, self.cam_to_world)

    def project(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """(..., 3) world points -> pixels (..., 2), depth (...); see :func:`project`."""
        return project(points, self.K, self.cam_to_world)


@checked
@dataclass
class RGBDView:
    """One rendered RGB-D image with its camera.

    Attributes:
        rgb: (H, W, 3) uint8 image, row 0 at the top.
        depth: (H, W) float32 z-depth in metres (inf or <= 0 where invalid).
        camera: the camera that took it.
        segmentation: (H, W) int64 instance labels (scene object index, -1 for anything
            else), or None.
    """

    rgb: Tensor
    depth: Tensor
    camera: Camera
    segmentation: Tensor | None = None

    def __post_init__(self) -> None:
        H, W = self.camera.height, self.camera.width
        if self.rgb.shape != (H, W, 3) or self.rgb.dtype != torch.uint8:
            raise ValueError(
                f"rgb must be uint8 ({H}, {W}, 3), got {self.rgb.dtype} {tuple(self.rgb.shape)}"
            )
        if self.depth.shape != (H, W):
            raise ValueError(f"depth must be ({H}, {W}), got {tuple(self.depth.shape)}")
        if self.segmentation is not None and self.segmentation.shape != (H, W):
            raise ValueError(
                f"segmentation must be ({H}, {W}), got {tuple(self.segmentation.shape)}"
            )

    def mask(self, label: int) -> Tensor:
        """(H, W) bool mask of the pixels of object ``label``."""
        if self.segmentation is None:
            raise ValueError("this view has no segmentation")
        return self.segmentation == label

    def point_cloud(
        self, mask: Tensor | None = None, max_depth: float = 10.0
    ) -> tuple[Tensor, Tensor]:
        """Back-project every valid pixel (optionally inside ``mask``).

        Args:
            mask: (H, W) bool, or None for the whole image.
            max_depth: pixels farther than this (background, far plane) are dropped.

        Returns:
            points (M, 3) world coordinates and colours (M, 3) float in [0, 1].

        Raises:
            ValueError: when no pixel has valid depth (inside the mask).
        """
        check_positive(max_depth=max_depth)
        valid = torch.isfinite(self.depth) & (self.depth > 0) & (self.depth < max_depth)
        if mask is not None:
            if mask.shape != self.depth.shape:
                raise ValueError(f"mask must be {tuple(self.depth.shape)}, got {tuple(mask.shape)}")
            if not mask.any():
                raise ValueError("empty mask: the object is not visible in this view")
            valid &= mask.bool()
        if not valid.any():
            raise ValueError("empty point cloud: no pixel with valid depth")
        pixels = pixel_grid(self.camera.height, self.camera.width)[valid]
        points = self.camera.backproject(pixels, self.depth[valid].float())
        return points.float(), self.rgb[valid].float() / 255.0

    def with_depth_noise(
        self,
        sigma: float,
        edge_dropout: float = 0.5,
        jump: float = 0.01,
        generator: torch.Generator | None = None,
    ) -> RGBDView:
        """This view as a depth sensor would give it: Gaussian noise of ``sigma`` metres on
        every depth, and pixels at depth edges (a step above ``jump`` to a 4-neighbour,
        where stereo and time-of-flight sensors fail) dropped (NaN) with probability
        ``edge_dropout``.

        Raises:
            ValueError: sigma negative, or edge_dropout outside [0, 1].
        """
        if sigma < 0 or not 0 <= edge_dropout <= 1:
            raise ValueError(
                f"need sigma >= 0 and edge_dropout in [0, 1], got {sigma}, {edge_dropout}"
            )
        depth = self.depth.float()
        far = torch.where(torch.isfinite(depth), depth, torch.full_like(depth, 1e6))
        step = torch.zeros_like(depth, dtype=torch.bool)
        dv = (far[1:] - far[:-1]).abs() > jump
        dh = (far[:, 1:] - far[:, :-1]).abs() > jump
        step[1:] |= dv
        step[:-1] |= dv
        step[:, 1:] |= dh
        step[:, :-1] |= dh
        noise = sigma * torch.randn(depth.shape, generator=generator)
        drop = step & (torch.rand(depth.shape, generator=generator) < edge_dropout)
        noisy = torch.where(drop, torch.full_like(depth, float("nan")), depth + noise)
        return RGBDView(self.rgb, noisy, self.camera, self.segmentation)
