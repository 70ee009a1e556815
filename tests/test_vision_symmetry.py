"""pose_error modulo object symmetries."""

import math

import pytest
import roma
import torch

from vistask.vision import Symmetry, estimate_symmetry, pose_error


def _pose(t, rotvec) -> torch.Tensor:
    return torch.cat(
        [torch.tensor(t, dtype=torch.float32), roma.rotvec_to_unitquat(torch.tensor(rotvec))]
    )


@pytest.mark.parametrize(
    ("symmetry", "rotvec", "expected_deg"),
    [
        (Symmetry.none(), (0.0, 0.0, math.pi / 2), 90.0),
        (Symmetry.about_axis((0.0, 0.0, 1.0)), (0.0, 0.0, math.pi / 2), 0.0),  # spin of a can
        (Symmetry.about_axis((0.0, 0.0, 1.0)), (math.radians(30), 0.0, 0.0), 30.0),  # tilt counts
        (Symmetry.about_axis((0.0, 0.0, 1.0), order=4), (0.0, 0.0, math.radians(100)), 10.0),
        (Symmetry.box(), (math.pi, 0.0, 0.0), 0.0),
        (Symmetry.box(), (0.0, 0.0, math.radians(170)), 10.0),
        (Symmetry.box(), (0.0, 0.0, math.pi / 2), 90.0),
    ],
)
def test_rotation_error_modulo_symmetry(symmetry: Symmetry, rotvec, expected_deg: float) -> None:
    true = _pose([0.1, 0.2, 0.8], (0.3, -0.2, 1.0))
    # The estimate differs from the truth by ``rotvec`` in the object's own frame.
    R = roma.unitquat_to_rotmat(true[3:]) @ roma.rotvec_to_rotmat(torch.tensor(rotvec))
    est = torch.cat([true[:3] + torch.tensor([0.03, 0.0, -0.04]), roma.rotmat_to_unitquat(R)])
    t_err, r_err = pose_error(est, true, symmetry)
    assert t_err.item() == pytest.approx(0.05, abs=1e-6)
    assert r_err.item() == pytest.approx(expected_deg, abs=1e-2)


def test_batched_and_broadcast() -> None:
    true = _pose([0.0, 0.0, 0.0], (0.0, 0.0, 0.0))
    angles = torch.linspace(0.0, math.pi, 5)
    est = torch.cat(
        [
            torch.zeros(5, 3),
            roma.rotvec_to_unitquat(angles[:, None] * torch.tensor([1.0, 0.0, 0.0])),
        ],
        -1,
    )
    t_err, r_err = pose_error(est, true)
    assert t_err.shape == r_err.shape == (5,)
    torch.testing.assert_close(r_err, torch.rad2deg(angles), atol=0.05, rtol=0)  # float32 near 180
    # q and -q are the same rotation.
    _, r = pose_error(-est[1:2], est[1:2])
    assert r.item() < 1e-2


def test_bad_input() -> None:
    with pytest.raises(ValueError, match="7"):
        pose_error(torch.zeros(3), torch.zeros(7))
    with pytest.raises(ValueError, match="order"):
        Symmetry.about_axis(order=0)
    with pytest.raises(ValueError, match="rotations"):
        Symmetry(rotations=torch.zeros(0, 4))


def _box_points(half: tuple[float, float, float], n: int = 20_000) -> torch.Tensor:
    """Points on the faces of a box of half sides ``half`` centred at the origin."""
    gen = torch.Generator().manual_seed(0)
    points = (torch.rand(n, 3, generator=gen, dtype=torch.float64) * 2 - 1) * torch.tensor(half)
    axis = torch.randint(0, 3, (n,), generator=gen)
    sign = torch.randint(0, 2, (n,), generator=gen) * 2 - 1
    points[torch.arange(n), axis] = sign * torch.tensor(half, dtype=torch.float64)[axis]
    return points


def _cylinder_points(radius: float, half_height: float, n: int = 20_000) -> torch.Tensor:
    gen = torch.Generator().manual_seed(1)
    theta = torch.rand(n, generator=gen, dtype=torch.float64) * 2 * math.pi
    z = (torch.rand(n, generator=gen, dtype=torch.float64) * 2 - 1) * half_height
    return torch.stack([radius * theta.cos(), radius * theta.sin(), z], 1)


@pytest.mark.parametrize(
    ("points", "order", "axis"),
    [
        (_box_points((0.05, 0.03, 0.02)), 4, None),  # half-turns about each axis
        (_box_points((0.03, 0.03, 0.03)), 24, None),  # a cube's rotations
        (_box_points((0.03, 0.03, 0.06)), 8, None),  # a square prism: quarter turns, flips
        (_cylinder_points(0.03, 0.05), 4, (0.0, 0.0, 1.0)),  # any spin, end for end
        (_box_points((0.05, 0.03, 0.02)) + torch.tensor([0.01, 0.0, 0.0]), 2, None),  # off x
    ],
)
def test_symmetry_is_estimated_from_points_on_the_shape(points, order, axis) -> None:
    found = estimate_symmetry(points, tolerance=0.002)
    assert len(found.rotations) == order
    if axis is None:
        assert found.axis is None
    else:
        assert torch.allclose(found.axis.abs(), torch.tensor(axis))
    # Every rotation found turns the shape onto itself: the pose it gives is the same pose.
    turned = torch.cat([torch.zeros(len(found.rotations), 3), found.rotations], 1)
    _, error = pose_error(turned, _pose((0, 0, 0), (0.0, 0.0, 0.0)).expand_as(turned), found)
    assert error.max() < 0.1
    with pytest.raises(ValueError, match="N >= 100"):
        estimate_symmetry(points[:50], tolerance=0.002)
