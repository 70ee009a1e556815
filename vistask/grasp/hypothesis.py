"""Grasp hypothesis densities in the object frame (paper 3.5).

Two sources bias the exploration of grasps:

- *feature-induced*: a pair of similar-coloured, coplanar edge patches suggests a planar
  surface between them (Kraft et al. 2008); a parallel-jaw gripper approaching along the
  plane's normal, fingers on either side of the two edges, closing across them, may hold
  it. Each such pair gives one grasp pose.
- *demonstrations*: teacher grasp poses (here from a scripted expert, standing in for the
  paper's motion capture), each repeated with noise.

Gripper frame (as in ``vistask/GraspTrial-v0``): origin between the fingertip pads, +z the
approach direction, +x the closing axis. Grasps are (N, 7) poses [t, qx, qy, qz, qw].
"""

from __future__ import annotations

import math

import roma
import torch
import torch.nn.functional as F

from vistask.checks import check_at_least, check_positive, checked
from vistask.se3 import SE3KDE, check_poses, make_poses
from vistask.vision import Patches


@checked
def frames_to_poses(positions: torch.Tensor, x: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """Gripper poses from positions and closing / approach axes.

    Args:
        positions: (N, 3) gripper origins.
        x: (N, 3) closing axes (orthogonalised against z here).
        z: (N, 3) approach directions (normalised here).

    Returns:
        (N, 7) poses with rotation columns [x, z × x, z].
    """
    z = F.normalize(z, dim=-1)
    x = F.normalize(x - (x * z).sum(-1, keepdim=True) * z, dim=-1)
    y = torch.linalg.cross(z, x)
    R = torch.stack([x, y, z], dim=-1)
    return make_poses(positions, roma.rotmat_to_unitquat(R))


def _colour_distance(colors: torch.Tensor) -> torch.Tensor:
    """(N, 2, 3) two-sided colours -> (N, N) distances, invariant to swapping the sides."""
    flat = colors.reshape(len(colors), 6)
    swapped = colors.flip(1).reshape(len(colors), 6)
    return torch.minimum(torch.cdist(flat, flat), torch.cdist(flat, swapped)) / math.sqrt(2)


@checked
def feature_grasps(
    patches: Patches,
    max_colour_distance: float = 0.15,
    max_angle: float = math.radians(20.0),
    width_range: tuple[float, float] = (0.015, 0.075),
    depth: float = 0.015,
    max_patches: int = 600,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Grasps suggested by pairs of similar-coloured, coplanar, parallel edge patches.

    For a pair (i, j): the edges are parallel (``|d_i . d_j| >= cos max_angle``), d_j lies in the
    plane spanned by d_i and p_j - p_i (coplanarity within ``max_angle``), and the distance
    across the edges fits the open gripper (``width_range``). The grasp closes across the
    edges (x = the part of p_j - p_i orthogonal to d_i) and approaches along the plane normal,
    from the side away from the patches' centroid (the object), its fingertips ``depth``
    beyond the plane; pairs whose plane passes through the centroid give both approaches.

    Args:
        patches: object-frame patches (positions, directions, colours).
        max_colour_distance: colour distance below which two patches count as similar
            (RGB in [0, 1], both sides).
        max_angle: tolerance of the parallel and coplanar tests (radians).
        width_range: (min, max) distance across the two edges (metres).
        depth: how far past the plane the fingertips reach (metres).
        max_patches: patches kept at random before the O(N^2) pair test.
        generator: random generator for that subsampling.

    Returns:
        (M, 7) object-frame grasps (M may be 0).
    """
    n = len(patches)
    if n > max_patches:
        keep = torch.randperm(n, generator=generator)[:max_patches]
        patches = patches.select(keep)
    p, d = patches.positions.double(), F.normalize(patches.directions.double(), dim=-1)
    sep = p[None, :, :] - p[:, None, :]  # (N, N, 3): p_j - p_i
    across = sep - (sep * d[:, None, :]).sum(-1, keepdim=True) * d[:, None, :]
    width = across.norm(dim=-1)
    normal = F.normalize(torch.linalg.cross(d[:, None, :].expand_as(sep), sep, dim=-1), dim=-1)
    cos_tol, sin_tol = math.cos(max_angle), math.sin(max_angle)
    ok = (
        (torch.triu(torch.ones(len(p), len(p), dtype=torch.bool), diagonal=1))
        & ((d @ d.T).abs() >= cos_tol)
        & ((normal * d[None, :, :]).sum(-1).abs() <= sin_tol)
        & (width >= width_range[0])
        & (width <= width_range[1])
        & (_colour_distance(patches.colors.double()) <= max_colour_distance)
    )
    i, j = ok.nonzero(as_tuple=True)
    if len(i) == 0:
        return torch.empty(0, 7, dtype=patches.positions.dtype)
    centre = 0.5 * (p[i] + p[j])
    x, n_ij = across[i, j], normal[i, j]
    # Approach from outside: the normal's sign that points from the pair into the object.
    inward = ((p.mean(0) - centre) * n_ij).sum(-1)
    z = torch.where(inward[:, None] >= 0, n_ij, -n_ij)
    through = inward.abs() < 1e-3
    both_x = torch.cat([x, x[through]])
    both_z = torch.cat([z, -z[through]])
    both_c = torch.cat([centre, centre[through]])
    poses = frames_to_poses(both_c + depth * F.normalize(both_z, dim=-1), both_x, both_z)
    return poses.to(patches.positions.dtype)


@checked
def feature_hypothesis_density(
    patches: Patches,
    sigma_t: float = 0.01,
    sigma_r: float = 0.25,
    max_grasps: int = 1000,
    generator: torch.Generator | None = None,
) -> SE3KDE:
    """Feature-induced hypothesis density: ``feature_grasps`` (with its default pair tests) as
    equally weighted particles.

    Args:
        patches: object-frame patches.
        sigma_t, sigma_r: kernel bandwidth (metres, radians).
        max_grasps: grasps kept at random (the pair count grows quadratically).
        generator: random generator.

    Raises:
        ValueError: no patch pair passed the tests.
    """
    grasps = feature_grasps(patches, generator=generator)
    if len(grasps) == 0:
        raise ValueError("no pair of similar-coloured coplanar patches fits the gripper")
    if len(grasps) > max_grasps:
        grasps = grasps[torch.randperm(len(grasps), generator=generator)[:max_grasps]]
    return SE3KDE(grasps.float(), sigma_t=sigma_t, sigma_r=sigma_r)


@checked
def scripted_teacher_grasps(bounds: torch.Tensor, depth: float = 0.02) -> torch.Tensor:
    """A scripted expert's grasps of an upright object from its object-frame bounding box.

    Top-down grasps at the centre of the top face, closing across the horizontal extents that
    fit the gripper, in both finger orders, plus horizontal side grasps at mid-height.

    Args:
        bounds: (2, 3) object-frame box (min corner, max corner).
        depth: how far below the top face the fingertips go (metres).

    Returns:
        (K, 7) object-frame grasps.
    """
    bounds = torch.as_tensor(bounds, dtype=torch.float64)
    if bounds.shape != (2, 3):
        raise ValueError(f"bounds must have shape (2, 3), got {tuple(bounds.shape)}")
    lo, hi = bounds
    if not (torch.isfinite(bounds).all() and (lo < hi).all()):
        raise ValueError(f"bounds must be (min corner, max corner) with min < max, got {bounds}")
    check_positive(depth=depth)
    centre, size = (lo + hi) / 2, hi - lo
    ex, ey = torch.eye(3, dtype=torch.float64)[:2]
    down = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)
    positions, xs, zs = [], [], []
    top = torch.stack([centre[0], centre[1], hi[2] - min(depth, 0.5 * float(size[2]))])
    for axis, width in ((ex, size[0]), (ey, size[1])):
        if width <= 0.075:
            for sign in (1.0, -1.0):
                positions.append(top)
                xs.append(sign * axis)
                zs.append(down)
            # Side grasps: approach horizontally along the other horizontal axis.
            other = ey if axis is ex else ex
            for sign in (1.0, -1.0):
                positions.append(centre)
                xs.append(axis)
                zs.append(sign * other)
    if not positions:
        raise ValueError(f"the object ({size.tolist()}) is wider than the gripper everywhere")
    return frames_to_poses(torch.stack(positions), torch.stack(xs), torch.stack(zs)).float()


@checked
def demonstration_density(
    teacher_grasps: torch.Tensor,
    n_per_demo: int = 20,
    noise_t: float = 0.015,
    noise_r: float = 0.25,
    sigma_t: float = 0.01,
    sigma_r: float = 0.25,
    generator: torch.Generator | None = None,
) -> SE3KDE:
    """Hypothesis density from demonstrations: each teacher grasp repeated with noise.

    The noise (isotropic Gaussian position offset, rotation by a Gaussian rotation vector)
    stands in for the scatter of recorded human grasps.

    Args:
        teacher_grasps: (K, 7) object-frame grasps.
        n_per_demo: noisy copies per teacher grasp.
        noise_t, noise_r: noise std in metres / radians (per rotation-vector component).
        sigma_t, sigma_r: kernel bandwidth of the density.
        generator: random generator.

    Returns:
        an ``SE3KDE`` of K * n_per_demo particles.
    """
    teacher = torch.as_tensor(teacher_grasps, dtype=torch.float32)
    if teacher.dim() != 2 or teacher.shape[1] != 7 or len(teacher) == 0:
        raise ValueError(f"teacher_grasps must have shape (K, 7), got {tuple(teacher.shape)}")
    teacher = check_poses(teacher, "teacher_grasps")
    check_at_least(1, n_per_demo=n_per_demo)
    check_at_least(0, noise_t=noise_t, noise_r=noise_r)
    reps = teacher.repeat_interleave(n_per_demo, dim=0)
    t = reps[:, :3] + noise_t * torch.randn(len(reps), 3, generator=generator)
    rotvec = noise_r * torch.randn(len(reps), 3, generator=generator)
    q = roma.quat_product(reps[:, 3:], roma.rotvec_to_unitquat(rotvec))
    return SE3KDE(make_poses(t, q), sigma_t=sigma_t, sigma_r=sigma_r)
