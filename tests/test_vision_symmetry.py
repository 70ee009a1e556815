"""pose_error modulo object symmetries."""

import math

import pytest
import roma
import torch

from vistask.vision import Symmetry, pose_error


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
