"""Grasp densities of object instances (paper eq. 8).

A grasp density is an ``SE3KDE`` over gripper poses. The object model stores it in the
object frame (the compatibility potential psi_og between the top feature and the grasp
feature); the density of an object *instance* in the world is

    p(X_g | Y) = integral psi_og(X_o, X_g) p(X_o | Y) dX_o,                      (8)

the grasp density pushed through the pose belief p(X_o | Y) of the top node. With particles
this is a composition: draw X_o from the belief, draw a grasp from the object-frame density,
compose. For a belief that is a single pose the integral is an exact rigid transform of
every particle (the kernels are invariant under left multiplication), which
``transform_density`` computes without sampling.
"""

from __future__ import annotations

import torch

from vistask.checks import checked
from vistask.se3 import SE3KDE, check_poses, compose


@checked
def transform_density(density: SE3KDE, pose: torch.Tensor) -> SE3KDE:
    """Express an object-frame density in the world for one known object pose.

    Args:
        density: object-frame grasp density.
        pose: (7,) object pose in the world.

    Returns:
        the density of ``pose ∘ X_g`` (same weights and bandwidth; exact, since position and
        orientation kernels are invariant under rigid motions applied on the left).
    """
    pose = check_poses(torch.as_tensor(pose), "pose")
    if pose.shape != (7,):
        raise ValueError(f"pose must have shape (7,), got {tuple(pose.shape)}")
    points = compose(pose.to(density.points).expand_as(density.points), density.points)
    return SE3KDE(
        points,
        density.weights,
        sigma_t=density.sigma_t,
        sigma_r=density.sigma_r,
        kernel=density.kernel,
    )


@checked
def instance_grasp_density(
    pose_belief: SE3KDE,
    grasp_density: SE3KDE,
    n: int = 500,
    generator: torch.Generator | None = None,
    sigma_t: float | None = None,
    sigma_r: float | None = None,
) -> SE3KDE:
    """Eq. (8): the world-frame grasp density of an instance from its pose belief.

    Monte Carlo message passing through psi_og: ``n`` object poses are drawn from the belief
    and each is composed with one grasp drawn from the object-frame density (the orientation
    kernel spread of both is thereby part of the samples).

    Args:
        pose_belief: density of the object pose X_o in the world (e.g. the NBP top belief).
        grasp_density: object-frame grasp density psi_og (the model's grasp feature).
        n: number of particles of the result.
        generator: random generator on the densities' device.
        sigma_t, sigma_r: bandwidth of the result (default: the grasp density's).

    Returns:
        an ``SE3KDE`` of n equally weighted world-frame grasp poses.
    """
    if n <= 0:
        raise ValueError(f"n must be positive, got {n}")
    poses = pose_belief.sample(n, generator)
    grasps = grasp_density.sample(n, generator).to(poses)
    return SE3KDE(
        compose(poses, grasps),
        sigma_t=grasp_density.sigma_t if sigma_t is None else sigma_t,
        sigma_r=grasp_density.sigma_r if sigma_r is None else sigma_r,
        kernel=grasp_density.kernel,
    )
