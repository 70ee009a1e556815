"""Kernel densities on R^3 x S^2 with axial directions (v ~ -v), e.g. edge observations whose
roll about the edge is undetermined, and the projection SE(3) -> R^3 x S^2.
"""

from __future__ import annotations

import roma
import torch

from vistask.checks import checked
from vistask.se3 import kernels
from vistask.se3.kde import SE3KDE, KernelDensity
from vistask.se3.poses import check_points, check_poses


@checked
def check_r3s2(points: torch.Tensor, name: str = "points", batched: bool = False) -> torch.Tensor:
    """Validate (..., 6) points [t, v] (v a unit direction) and renormalise v."""
    return check_points(points, name, 6, "[t, vx, vy, vz]", batched)


@checked
def project_se3_to_r3s2(poses: torch.Tensor, axis: int = 2) -> torch.Tensor:
    """(..., 7) poses -> (..., 6) [t, R e_axis]: position and one axis of the rotation."""
    if axis not in (0, 1, 2):
        raise ValueError(f"axis must be 0, 1 or 2, got {axis}")
    poses = check_poses(poses)
    basis = torch.zeros(3, dtype=poses.dtype, device=poses.device)
    basis[axis] = 1.0
    quat = poses[..., 3:]
    direction = roma.quat_action(quat, basis.expand(*quat.shape[:-1], 3), is_normalized=True)
    return torch.cat([poses[..., :3], direction], dim=-1)


@checked
class R3S2KDE(KernelDensity):
    """Kernel density on R^3 x S^2 with axial directions: particles are (N, 6) [t, v].

    Kernel: position (Gaussian or triangular) times ``exp(kappa (|v . v_i| - 1))`` with
    kappa = 1 / (1 - cos sigma_r); normalised over R^3 x S^2 / {v ~ -v} (area 2 pi). Sampling
    uses Wood's algorithm on S^2 with a random sign. See ``KernelDensity`` for the arguments.
    """

    dir_dim = 3
    point_name = "points"

    @classmethod
    def check_points(cls, points: torch.Tensor, name: str, batched: bool = False) -> torch.Tensor:
        """Validate (..., 3 + D) points and renormalise their direction part."""
        return check_r3s2(points, name, batched=batched)

    @staticmethod
    def kappa_from_sigma(sigma_r: float) -> float:
        """The direction kernel's concentration for the bandwidth ``sigma_r`` (radians)."""
        return kernels.direction_kappa(sigma_r)

    @staticmethod
    def log_direction_normalizer(kappa: float) -> float:
        """Log of the direction kernel's normalising constant at ``kappa``."""
        return kernels.log_direction_normalizer(kappa)

    @staticmethod
    def direction_angle(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Angle between directions (..., D) x (..., D) -> (...), with u ~ -u."""
        return torch.acos((u * v).sum(-1).abs().clamp(max=1.0))

    @classmethod
    def from_se3(cls, density: SE3KDE, axis: int = 2, sigma_r: float | None = None) -> R3S2KDE:
        """The R^3 x S^2 density of (position, rotated ``axis``) of an SE(3) density's particles.

        Args:
            density: the SE(3) density.
            axis: which column of the rotation matrix (0: x, 1: y, 2: z).
            sigma_r: direction bandwidth of the result (default: the density's sigma_r).

        Returns:
            an ``R3S2KDE`` with the same weights, position bandwidth and kernel.
        """
        return cls(
            project_se3_to_r3s2(density.points, axis),
            density.weights,
            sigma_t=density.sigma_t,
            sigma_r=density.sigma_r if sigma_r is None else sigma_r,
            kernel=density.kernel,
        )
