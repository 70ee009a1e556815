"""Batched rigid-body poses as (..., 7) tensors [tx, ty, tz, qx, qy, qz, qw].

All rotation math goes through roma (XYZW quaternions). Quaternions q and -q denote the same
rotation; nothing here canonicalises the sign except where stated.
"""

from __future__ import annotations

import math

import roma
import torch

from vistask.checks import check_at_least, check_integers, checked

UNIT_TOLERANCE = 1e-3
"""Largest accepted deviation of a quaternion's norm from 1 before a ValueError is raised."""


def check_unit(u: torch.Tensor, name: str, tolerance: float = UNIT_TOLERANCE) -> torch.Tensor:
    """Check that the vectors along the last axis are unit length and renormalise them.

    Args:
        u: (..., D) vectors (quaternions or directions).
        name: name used in the error message.
        tolerance: accepted deviation of the norm from 1.

    Returns:
        (..., D) the same vectors divided by their norms.
    """
    return u / _unit_norms(u, name, tolerance)


def _unit_norms(u: torch.Tensor, name: str, tolerance: float = UNIT_TOLERANCE) -> torch.Tensor:
    """(..., 1) norms of the vectors along the last axis; ValueError naming ``name`` unless
    each is within ``tolerance`` of 1."""
    norms = u.norm(dim=-1, keepdim=True)
    # One read of the worst deviation (NaN when a value is not finite) checks both.
    worst = (norms - 1.0).abs().max().item() if u.numel() else 0.0
    if not worst <= tolerance:
        if not torch.isfinite(u).all():
            raise ValueError(f"{name} contains NaN or infinite values")
        raise ValueError(
            f"{name} must be unit vectors (norm within {tolerance} of 1); the worst norm is off by "
            f"{worst:.3g}"
        )
    return norms


@checked
def check_poses(poses: torch.Tensor, name: str = "poses", batched: bool = False) -> torch.Tensor:
    """Validate poses and return them as a floating tensor with renormalised quaternions.

    Args:
        poses: (..., 7) poses, or (N, 7) when ``batched``.
        name: name used in error messages.
        batched: require exactly two dimensions (N, 7).

    Returns:
        (..., 7) validated poses.
    """
    return check_points(poses, name, 7, "[t, qx, qy, qz, qw]", batched)


def check_points(
    points: torch.Tensor, name: str, width: int, layout: str, batched: bool
) -> torch.Tensor:
    """Validate (..., width) points [t, u] laid out as ``layout`` (for messages): a float32 or
    float64 tensor (integers are read as float32), finite translations small enough that
    squared distances cannot overflow, unit directions u (renormalised)."""
    if not isinstance(points, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(points).__name__}")
    if points.shape[-1:] != (width,) or (batched and points.dim() != 2):
        want = f"(N, {width})" if batched else f"(..., {width})"
        raise ValueError(f"{name} must have shape {want} {layout}, got {tuple(points.shape)}")
    if points.dtype in (torch.bool, torch.complex64, torch.complex128) or (
        points.is_floating_point() and points.dtype not in (torch.float32, torch.float64)
    ):
        raise TypeError(f"{name} must be float32 or float64, got {points.dtype}")
    if not points.is_floating_point():
        points = points.float()
    translations = points[..., :3]
    if not torch.isfinite(translations).all():
        raise ValueError(f"{name} contains NaN or infinite translations")
    limit = torch.finfo(points.dtype).max ** 0.5 * 1e-6
    if translations.numel() and translations.abs().max() > limit:
        raise ValueError(
            f"{name} has a translation of {translations.abs().max().item():.3g}: beyond "
            f"{limit:.3g} squared distances overflow {points.dtype} (use smaller units)"
        )
    direction = "quaternions" if width == 7 else "directions"
    return torch.cat([translations, check_unit(points[..., 3:], f"{name} {direction}")], dim=-1)


def _pose_args(**poses: torch.Tensor) -> None:
    """Raise unless each is a (..., 7) pose tensor with unit quaternions (to UNIT_TOLERANCE);
    unlike ``check_poses`` nothing is renormalised, for the operations' hot paths."""
    for name, pose in poses.items():
        if pose.shape[-1:] != (7,):
            raise ValueError(
                f"{name} must have shape (..., 7) [t, qx, qy, qz, qw], got {tuple(pose.shape)}"
            )
        _unit_norms(pose[..., 3:], f"{name} quaternions")


@checked
def make_poses(translation: torch.Tensor, quaternion: torch.Tensor) -> torch.Tensor:
    """Stack (..., 3) translations and (..., 4) XYZW quaternions into (..., 7) poses."""
    if translation.shape[-1:] != (3,) or quaternion.shape[-1:] != (4,):
        raise ValueError(
            f"translation must have shape (..., 3) and quaternion (..., 4), got "
            f"{tuple(translation.shape)} and {tuple(quaternion.shape)}"
        )
    return torch.cat(_broadcast_batch(translation, quaternion), dim=-1)


def _broadcast_batch(*tensors: torch.Tensor) -> list[torch.Tensor]:
    """Broadcast the batch dimensions (all but the last) of tensors, keeping their last dims."""
    shape = torch.broadcast_shapes(*(t.shape[:-1] for t in tensors))
    return [t.expand(*shape, t.shape[-1]) for t in tensors]


@checked
def identity_poses(*batch: int, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """Identity poses of shape ``(*batch, 7)``."""
    check_integers(**{f"batch[{i}]": size for i, size in enumerate(batch)})
    check_at_least(0, **{f"batch[{i}]": size for i, size in enumerate(batch)})
    out = torch.zeros(*batch, 7, dtype=dtype, device=device)
    out[..., 6] = 1.0
    return out


@checked
def random_poses(
    n: int,
    translation_scale: float = 1.0,
    generator: torch.Generator | None = None,
    dtype: torch.dtype = torch.float32,
    device=None,
) -> torch.Tensor:
    """(n, 7) poses with Gaussian translations (std ``translation_scale``) and uniform rotations."""
    check_at_least(0, n=n, translation_scale=translation_scale)
    if not dtype.is_floating_point:
        raise TypeError(f"dtype must be a float dtype, got {dtype}")
    t = translation_scale * torch.randn(n, 3, generator=generator, dtype=dtype, device=device)
    q = roma.random_unitquat(n, dtype=dtype, device=device, generator=generator)
    return torch.cat([t, q], dim=-1)


@checked
def compose(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Pose composition a ∘ b (apply b, then a): (..., 7) x (..., 7) -> (..., 7), broadcast."""
    _pose_args(a=a, b=b)
    a, b = _broadcast_batch(a, b)
    return torch.cat([apply(a, b[..., :3]), roma.quat_product(a[..., 3:], b[..., 3:])], dim=-1)


@checked
def inverse(a: torch.Tensor) -> torch.Tensor:
    """The inverse of each (..., 7) pose: composed with the pose, it gives the identity."""
    _pose_args(a=a)
    rotation = roma.unitquat_to_rotmat(a[..., 3:])
    t = -torch.einsum("...ji,...j->...i", rotation, a[..., :3])  # -R^T t
    return torch.cat([t, roma.quat_conjugation(a[..., 3:])], dim=-1)


@checked
def relative(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Pose of b expressed in the frame of a, inverse(a) ∘ b: (..., 7) x (..., 7) -> (..., 7)."""
    return compose(inverse(a), b)


@checked
def apply(pose: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Transform points by poses, R p + t: (..., 7) x (..., 3) -> (..., 3), broadcast."""
    _pose_args(pose=pose)
    if points.shape[-1:] != (3,):
        raise ValueError(f"points must have shape (..., 3), got {tuple(points.shape)}")
    # Through rotation matrices: a pose that moves many points is turned into one once,
    # where quaternion products would be taken for every point (1.6-6 times faster).
    rotation = roma.unitquat_to_rotmat(pose[..., 3:])
    return pose[..., :3] + torch.einsum("...ij,...j->...i", rotation, points)


@checked
def rigid_refit(
    poses: torch.Tensor,
    source: torch.Tensor,
    target: torch.Tensor,
    weights: torch.Tensor,
    min_points: int,
) -> tuple[torch.Tensor, bool]:
    """Refit poses so that their frame's points land on matched world points (weighted Kabsch).

    Args:
        poses: (H, 7) current poses.
        source: (H, N, 3) points in each pose's frame.
        target: (H, N, 3) world points they are matched to (anything where the weight is 0).
        weights: (H, N) match weights, 0 for unmatched points.
        min_points: a pose with fewer matched points than this stays as it is.

    Returns:
        (H, 7) poses, and whether any of them was refitted.
    """
    matched = weights > 0
    enough = matched.sum(dim=-1) >= min_points
    if not enough.any():
        return poses, False
    target = torch.where(matched[..., None], target, source)  # keep NaN out of the fit
    R, t = roma.rigid_points_registration(source, target, weights=weights)
    fitted = torch.cat([t, roma.rotmat_to_unitquat(R)], dim=-1)
    return torch.where(enough[:, None], fitted, poses), True


@checked
def translation_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Euclidean distance between translations: (..., 7) x (..., 7) -> (...)."""
    _pose_args(a=a, b=b)
    return (a[..., :3] - b[..., :3]).norm(dim=-1)


@checked
def rotation_distance(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Rotation angle in [0, pi] between the rotations of a and b (q and -q alike): -> (...)."""
    _pose_args(a=a, b=b)
    a, b = _broadcast_batch(a, b)
    return roma.unitquat_geodesic_distance(a[..., 3:], b[..., 3:])


@checked
def pose_wxyz_to_xyzw(poses: torch.Tensor) -> torch.Tensor:
    """MuJoCo/robosuite boundary: [t, qw, qx, qy, qz] -> [t, qx, qy, qz, qw], (..., 7)."""
    _pose_args(poses=poses)
    return torch.cat([poses[..., :3], roma.quat_wxyz_to_xyzw(poses[..., 3:])], dim=-1)


@checked
def pose_xyzw_to_wxyz(poses: torch.Tensor) -> torch.Tensor:
    """[t, qx, qy, qz, qw] -> [t, qw, qx, qy, qz] for MuJoCo/robosuite, (..., 7)."""
    _pose_args(poses=poses)
    return torch.cat([poses[..., :3], roma.quat_xyzw_to_wxyz(poses[..., 3:])], dim=-1)


wxyz_to_xyzw = roma.quat_wxyz_to_xyzw
xyzw_to_wxyz = roma.quat_xyzw_to_wxyz

ROTATION_VOLUME = math.pi**2
"""Volume of SO(3) = S^3 / {q ~ -q} under the unit-quaternion metric used for normalisation."""
