"""SE(3) kernel densities: fit poses, evaluate, sample, and multiply two densities.

    python examples/se3_densities.py

Poses are (N, 7) tensors ``[tx, ty, tz, qx, qy, qz, qw]`` (unit quaternion, XYZW as in roma).
"""

import math

import roma
import torch

from vistask.se3 import SE3KDE, make_poses, product, rotation_distance

torch.manual_seed(0)
# Grasps around a top-down pose 2 cm above an object's origin, scattered by noise.
centre = make_poses(
    torch.tensor([0.0, 0.0, 0.02]), roma.rotvec_to_unitquat(torch.tensor([math.pi, 0.0, 0.0]))
)
noise_t = 0.01 * torch.randn(200, 3)
noise_r = roma.rotvec_to_unitquat(0.2 * torch.randn(200, 3))
poses = make_poses(centre[:3] + noise_t, roma.quat_product(noise_r, centre[3:].expand(200, 4)))

density = SE3KDE(poses, sigma_t=0.01, sigma_r=0.2)  # kernel widths: metres, radians
away = centre + torch.tensor([0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # 5 cm along x
print("density at the centre (unnormalised):", float(density(centre[None])[0]))
print("density 5 cm away (unnormalised):", float(density(away[None])[0]))

samples = density.sample(1000, generator=torch.Generator().manual_seed(1))
angle = rotation_distance(samples, centre.expand(1000, 7))
mean = [round(x, 4) for x in samples[:, :3].mean(0).tolist()]
print(f"samples: mean position {mean} m, median angle to the centre {angle.median():.3f} rad")

# The product of two densities (as in belief propagation) keeps where both agree.
shifted = SE3KDE(poses + torch.tensor([0.01] + [0.0] * 6), sigma_t=0.01, sigma_r=0.2)
both = product([density, shifted], n=500, generator=torch.Generator().manual_seed(2))
mean_x = both.sample(500, generator=torch.Generator().manual_seed(3))[:, 0].mean()
print(f"product: {len(both)} particles, mean x {mean_x:.4f} m (the factors: 0.000, 0.010)")
