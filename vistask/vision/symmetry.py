"""Object symmetries and pose errors measured modulo them.

Poses are (..., 7) ``[tx, ty, tz, qx, qy, qz, qw]`` (roma XYZW), object frame -> world.
A symmetry is a set of object-frame rotations about the object's origin that leave the
object unchanged; two poses that differ by one of them are the same physical pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import roma
import torch
import torch.nn.functional as F
from torch import Tensor

from vistask.checks import checked

_IDENTITY = torch.tensor([[0.0, 0.0, 0.0, 1.0]])


@checked
@dataclass(frozen=True)
class Symmetry:
    """Rotational symmetry of an object about its frame origin.

    Attributes:
        rotations: (K, 4) XYZW unit quaternions: the finite symmetry group, identity included.
        axis: (3,) unit axis of a continuous symmetry (any angle about it), or None. Combined
            with ``rotations`` (e.g. a flip that maps the axis to its opposite).
    """

    rotations: Tensor = field(default_factory=lambda: _IDENTITY.clone())
    axis: Tensor | None = None

    def __post_init__(self) -> None:
        if self.rotations.dim() != 2 or self.rotations.shape[-1] != 4 or len(self.rotations) == 0:
            raise ValueError(f"rotations must have shape (K, 4), got {tuple(self.rotations.shape)}")
        if self.axis is not None and self.axis.shape != (3,):
            raise ValueError(f"axis must have shape (3,), got {tuple(self.axis.shape)}")

    @staticmethod
    def none() -> Symmetry:
        """No symmetry."""
        return Symmetry()

    @staticmethod
    def about_axis(
        axis: tuple[float, float, float] = (0.0, 0.0, 1.0), order: int | None = None
    ) -> Symmetry:
        """Symmetry about ``axis``: continuous when ``order`` is None, else ``order``-fold."""
        a = torch.tensor(axis, dtype=torch.float32)
        if not a.norm() > 0:
            raise ValueError(f"axis must be a non-zero vector, got {axis}")
        a = F.normalize(a, dim=0)
        if order is None:
            return Symmetry(axis=a)
        if order < 1:
            raise ValueError(f"order must be >= 1, got {order}")
        angles = torch.arange(order, dtype=torch.float32) * (2 * math.pi / order)
        return Symmetry(rotations=roma.rotvec_to_unitquat(angles[:, None] * a))

    @staticmethod
    def box() -> Symmetry:
        """A box with distinct side lengths and uniform appearance: 180 degrees about each axis."""
        half_turns = math.pi * torch.eye(3)
        return Symmetry(rotations=torch.cat([_IDENTITY, roma.rotvec_to_unitquat(half_turns)]))

    def to_dict(self) -> dict[str, list]:
        """JSON-friendly description."""
        return {
            "rotations": self.rotations.tolist(),
            "axis": None if self.axis is None else self.axis.tolist(),
        }


@checked
def pose_error(
    est: Tensor, true: Tensor, symmetry: Symmetry | None = None
) -> tuple[Tensor, Tensor]:
    """Translation and rotation error between poses, modulo the object's symmetry.

    Args:
        est: (..., 7) estimated poses.
        true: (..., 7) ground-truth poses (broadcastable with ``est``).
        symmetry: the object's symmetry (default: none).

    Returns:
        translation error (...) in the poses' length unit, and rotation error (...) in degrees:
        the smallest angle between ``est`` and any pose equivalent to ``true``. With a continuous
        axis, only the angle between the two poses' axes counts.
    """
    if est.shape[-1] != 7 or true.shape[-1] != 7:
        raise ValueError(
            f"poses must have shape (..., 7), got {tuple(est.shape)} and {tuple(true.shape)}"
        )
    sym = symmetry or Symmetry.none()
    dtype = torch.promote_types(est.dtype, torch.float32)
    est, true = est.to(dtype), true.to(dtype)
    t_err = (est[..., :3] - true[..., :3]).norm(dim=-1)
    R_est = roma.unitquat_to_rotmat(F.normalize(est[..., 3:], dim=-1))[..., None, :, :]
    G = roma.unitquat_to_rotmat(sym.rotations.to(device=est.device, dtype=dtype))  # (K, 3, 3)
    R_true = roma.unitquat_to_rotmat(F.normalize(true[..., 3:], dim=-1))[..., None, :, :] @ G
    if sym.axis is None:
        angle = roma.rotmat_geodesic_distance(R_est, R_true)
    else:
        a = sym.axis.to(device=est.device, dtype=dtype)
        cos = ((R_est @ a) * (R_true @ a)).sum(-1)
        angle = torch.acos(cos.clamp(-1.0, 1.0))
    return t_err, torch.rad2deg(angle.min(dim=-1).values)
