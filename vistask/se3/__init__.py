"""SE(3) and R^3 x S^2 kernel densities in torch (the nuklei model).

Conventions, used throughout the project:

- A pose is a (..., 7) tensor [tx, ty, tz, qx, qy, qz, qw]: translation, then a unit quaternion
  in roma's XYZW order. q and -q are the same rotation; every density and distance here is
  invariant to the sign. MuJoCo / robosuite use WXYZ: convert at the boundary with
  ``pose_wxyz_to_xyzw`` / ``pose_xyzw_to_wxyz`` (or ``wxyz_to_xyzw`` for bare quaternions).
- ``compose(a, b)`` is a ∘ b (apply b first); ``relative(a, b) = inverse(a) ∘ b`` is b in a's
  frame; ``apply(pose, p) = R p + t``.
- A point of R^3 x S^2 is a (..., 6) tensor [t, v] with v a unit direction and v ~ -v.
- Densities are weighted particles with one bandwidth (sigma_t, sigma_r). The kernel is a
  position part (Gaussian with std sigma_t, or triangular max(0, 1 - d / (2 sigma_t))) times
  ``exp(kappa (|u . u_i| - 1))``, kappa = 1 / (1 - cos(sigma_r / 2)) for quaternions and
  1 / (1 - cos sigma_r) for axial directions, so both are about exp(-angle^2 / sigma_r^2).
  Normalised densities integrate to 1 over R^3 x SO(3) with SO(3) of volume pi^2 (the
  quaternion half-sphere), or over R^3 x S^2 / {v ~ -v} of area 2 pi.
"""

from vistask.se3.bandwidth import (
    cross_validate_bandwidth,
    fit_density,
    rule_of_thumb_bandwidth,
    select_bandwidth,
)
from vistask.se3.kde import SE3KDE, KernelDensity, mixture, product
from vistask.se3.poses import (
    ROTATION_VOLUME,
    apply,
    check_poses,
    compose,
    identity_poses,
    inverse,
    make_poses,
    pose_wxyz_to_xyzw,
    pose_xyzw_to_wxyz,
    random_poses,
    relative,
    rigid_refit,
    rotation_distance,
    translation_distance,
    wxyz_to_xyzw,
    xyzw_to_wxyz,
)
from vistask.se3.r3s2 import R3S2KDE, check_r3s2, project_se3_to_r3s2

__all__ = [
    "R3S2KDE",
    "ROTATION_VOLUME",
    "SE3KDE",
    "KernelDensity",
    "apply",
    "check_poses",
    "check_r3s2",
    "compose",
    "cross_validate_bandwidth",
    "fit_density",
    "identity_poses",
    "inverse",
    "make_poses",
    "mixture",
    "pose_wxyz_to_xyzw",
    "pose_xyzw_to_wxyz",
    "product",
    "project_se3_to_r3s2",
    "random_poses",
    "relative",
    "rigid_refit",
    "rotation_distance",
    "rule_of_thumb_bandwidth",
    "select_bandwidth",
    "translation_distance",
    "wxyz_to_xyzw",
    "xyzw_to_wxyz",
]
