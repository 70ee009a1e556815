"""Object symmetries and pose errors measured modulo them.

Poses are (..., 7) ``[tx, ty, tz, qx, qy, qz, qw]`` (roma XYZW), object frame -> world.
A symmetry is a set of object-frame rotations about the object's origin that leave the
object unchanged; two poses that differ by one of them are the same physical pose.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
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


# Angles that test a continuous symmetry: no n-fold symmetry with n <= 12 maps a shape onto
# itself at all three.
CONTINUOUS_TEST_ANGLES = tuple(2 * math.pi * k / 13 for k in (1, 3, 5))
ORDERS = (8, 6, 5, 4, 3, 2)  # the discrete orders tested about each axis, largest first
MAX_GROUP = 48  # the finite group's size is bounded: symmetries of a cube are 24
# Compositions of near-symmetries found about slightly tilted axes drift by a few degrees: a
# rotation this close to a member is that member (no finite group of a shape's symmetries
# holds two rotations this close).
SAME_ROTATION = math.radians(5.0)
SAME_QUATERNION = math.cos(SAME_ROTATION / 2)


@checked
def estimate_symmetry(points: Tensor, tolerance: float, axes: Tensor | None = None) -> Symmetry:
    """The rotational symmetry of a shape, found by turning its surface points onto
    themselves about its frame origin.

    A rotation is a symmetry when the turned points lie within ``tolerance`` of the shape
    (95% of them: the points are samples). The axes tried are the frame's, the shape's
    principal axes (about the origin) and the ``axes`` given. An axis about which three
    unrelated angles (``CONTINUOUS_TEST_ANGLES``) are symmetries is continuous; about any
    other, the largest order of ``ORDERS`` that the others that hold agree with is kept
    (``_order``). The finite group is closed under composition; with a continuous axis it
    keeps the half-turns that flip that axis.

    Example:
        >>> estimate_symmetry(points_on_a_can, tolerance=0.002).axis
        tensor([0., 0., 1.])

    Args:
        points: (N, 3) points on the shape's surface, in its frame (N >= 100).
        tolerance: how far, in the points' unit, a turned point may lie from the shape.
        axes: (K, 3) more axes to try after the frame's and the principal ones (the frames of
            the model's parts; default none).

    Returns:
        the ``Symmetry`` (one continuous axis at most: a sphere is taken as symmetric about
        one axis and the half-turns across it).
    """
    from scipy.spatial import cKDTree

    if points.dim() != 2 or points.shape[1] != 3 or len(points) < 100:
        raise ValueError(f"points must have shape (N >= 100, 3), got {tuple(points.shape)}")
    if not tolerance > 0:
        raise ValueError(f"tolerance must be > 0, got {tolerance}")
    p = points.double()
    tree = cKDTree(p.numpy())
    sample = p[torch.randperm(len(p), generator=torch.Generator().manual_seed(0))[:2000]]

    def misfit(rotvec: Tensor) -> float:
        distances, _ = tree.query((sample @ roma.rotvec_to_rotmat(rotvec).T).numpy())
        return float(np.quantile(distances, 0.95))

    def holds(rotvec: Tensor) -> bool:
        return misfit(rotvec) <= tolerance

    axes = _candidate_axes(p, () if axes is None else axes.double())
    continuous = next(
        (a for a in axes if all(holds(angle * a) for angle in CONTINUOUS_TEST_ANGLES)), None
    )
    generators = []
    for a in axes:
        if continuous is not None:
            if abs(float(a @ continuous)) < 1e-6 and holds(math.pi * a):
                generators.append(math.pi * a)  # a flip of the continuous axis
            continue
        order = _order({n: misfit(2 * math.pi / n * a) for n in ORDERS}, tolerance)
        if order is not None:
            generators.append(2 * math.pi / order * a)
    # Compositions of near-symmetries drift: each member of the group must hold itself.
    group = _closure([roma.rotvec_to_unitquat(g) for g in generators])
    rotations = torch.stack([q for q in group if holds(roma.unitquat_to_rotvec(q))])
    axis = None if continuous is None else continuous.float()
    return Symmetry(rotations=rotations.float(), axis=axis)


def _order(misfits: dict[int, float], tolerance: float) -> int | None:
    """The order of an axis from the misfit of each order's turn about it: the largest order
    that holds and that every order that holds divides; where the orders that hold disagree
    (a 72-degree turn of a thin square prism passes beside its quarter turn), the largest
    that holds among the multiples of the best fitting one. None where no order holds."""
    held = [n for n, misfit in misfits.items() if misfit <= tolerance]
    if not held:
        return None
    agreeing = [n for n in held if all(n % m == 0 for m in held)]
    if agreeing:
        return max(agreeing)
    best = min(held, key=misfits.get)
    return max(n for n in held if n % best == 0)


def _candidate_axes(points: Tensor, extra: Tensor | Sequence = ()) -> list[Tensor]:
    """The frame's axes, the principal axes of ``points`` about the origin and the ``extra``
    axes, those within about 8 degrees of an earlier one left out."""
    _, vectors = torch.linalg.eigh(points.T @ points)
    axes: list[Tensor] = []
    for a in [*torch.eye(3, dtype=points.dtype), *vectors.T, *extra]:
        if all(abs(float(a @ b)) < 0.99 for b in axes):
            axes.append(a / a.norm())
    return axes


def _closure(generators: list[Tensor]) -> Tensor:
    """(K, 4) the finite group the XYZW quaternions ``generators`` make, identity first."""
    group = [_IDENTITY[0].double()]

    def known(q: Tensor) -> bool:  # within SAME_ROTATION of a member: a drifted composition
        return any(abs(float(q @ g)) > SAME_QUATERNION for g in group)

    frontier = []
    for g in generators:
        if not known(g):
            group.append(g)
            frontier.append(g)
    while frontier and len(group) < MAX_GROUP:
        new = []
        for a in frontier:
            for b in list(group):
                q = roma.quat_product(a, b)
                if not known(q) and len(group) < MAX_GROUP:
                    group.append(q)
                    new.append(q)
        frontier = new
    return torch.stack(group)
