"""Pose algebra of vistask.se3: composition/inverse identities, distances, conventions, errors."""

import math

import pytest
import roma
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from vistask.se3 import (
    apply,
    check_poses,
    compose,
    identity_poses,
    inverse,
    pose_wxyz_to_xyzw,
    pose_xyzw_to_wxyz,
    random_poses,
    relative,
    rigid_refit,
    rotation_distance,
    translation_distance,
)

seeds = st.integers(min_value=0, max_value=2**31 - 1)


def _poses(seed: int, n: int = 8) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return random_poses(n, 2.0, generator=g, dtype=torch.float64)


def _same_pose(a: torch.Tensor, b: torch.Tensor, atol: float = 1e-9) -> None:
    torch.testing.assert_close(a[..., :3], b[..., :3], atol=atol, rtol=0)
    assert rotation_distance(a, b).max() < 1e-6


@settings(max_examples=25, deadline=None)
@given(seeds)
def test_inverse_composes_to_identity(seed: int) -> None:
    a = _poses(seed)
    ident = identity_poses(8, dtype=torch.float64)
    _same_pose(compose(a, inverse(a)), ident)
    _same_pose(compose(inverse(a), a), ident)
    _same_pose(inverse(inverse(a)), a)


@settings(max_examples=25, deadline=None)
@given(seeds)
def test_compose_is_associative_and_matches_point_action(seed: int) -> None:
    a, b, c = _poses(seed), _poses(seed + 1), _poses(seed + 2)
    _same_pose(compose(compose(a, b), c), compose(a, compose(b, c)))
    points = torch.randn(8, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))
    torch.testing.assert_close(apply(compose(a, b), points), apply(a, apply(b, points)))
    # The inverse undoes the action, and relative(a, b) is b seen from a.
    torch.testing.assert_close(apply(inverse(a), apply(a, points)), points)
    _same_pose(compose(a, relative(a, b)), b)


@settings(max_examples=25, deadline=None)
@given(seeds)
def test_distances_ignore_quaternion_sign_and_are_frame_invariant(seed: int) -> None:
    a, b, c = _poses(seed), _poses(seed + 1), _poses(seed + 2)
    flipped = torch.cat([b[:, :3], -b[:, 3:]], dim=1)
    torch.testing.assert_close(rotation_distance(a, b), rotation_distance(a, flipped))
    # Left-multiplying both by the same pose changes neither distance.
    torch.testing.assert_close(
        rotation_distance(compose(c, a), compose(c, b)), rotation_distance(a, b)
    )
    torch.testing.assert_close(
        translation_distance(compose(c, a), compose(c, b)), translation_distance(a, b)
    )
    # The rotation distance is the angle of the relative rotation.
    rotvec = roma.unitquat_to_rotvec(relative(a, b)[:, 3:])
    torch.testing.assert_close(rotation_distance(a, b), rotvec.norm(dim=1))
    assert (rotation_distance(a, b) <= math.pi + 1e-9).all()


def test_broadcasting_and_known_values() -> None:
    quarter_turn_z = torch.tensor(
        [1.0, 2.0, 3.0, 0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)]
    )
    out = apply(quarter_turn_z, torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    torch.testing.assert_close(out, torch.tensor([[1.0, 3.0, 3.0], [0.0, 2.0, 3.0]]))
    assert rotation_distance(quarter_turn_z, identity_poses()).item() == pytest.approx(math.pi / 2)


def test_wxyz_round_trip() -> None:
    poses = _poses(3)
    wxyz = pose_xyzw_to_wxyz(poses)
    torch.testing.assert_close(wxyz[:, 3], poses[:, 6])
    torch.testing.assert_close(pose_wxyz_to_xyzw(wxyz), poses)


def test_check_poses_errors() -> None:
    with pytest.raises(ValueError, match="unit"):
        check_poses(torch.tensor([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0]]))
    with pytest.raises(ValueError, match="shape"):
        check_poses(torch.zeros(4, 6))
    with pytest.raises(ValueError, match="shape"):
        check_poses(identity_poses(2, 3), batched=True)
    with pytest.raises(ValueError, match="NaN"):
        check_poses(torch.tensor([[math.nan, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]]))
    # Small deviations within the tolerance are renormalised.
    almost = torch.tensor([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0005]])
    assert check_poses(almost)[0, 3:].norm().item() == pytest.approx(1.0)


def test_rigid_refit_recovers_the_poses_of_matched_points_and_keeps_those_with_too_few() -> None:
    truth, start = _poses(0, 3).float(), _poses(1, 3).float()
    g = torch.Generator().manual_seed(2)
    source = torch.randn(3, 10, 3, generator=g)
    target = apply(truth[:, None], source)
    weights = torch.ones(3, 10)
    weights[1, 3:] = 0.0  # pose 1: three matches only, its other targets meaningless
    target[1, 3:] = float("nan")
    weights[2, 5:] = 0.0
    target[2, 5:] = float("nan")
    fitted, moved = rigid_refit(start, source, target, weights, min_points=4)
    assert moved
    for i in (0, 2):
        assert translation_distance(fitted[i], truth[i]) < 1e-4
        assert rotation_distance(fitted[i], truth[i]) < 1e-3
    assert torch.equal(fitted[1], start[1])
    same, moved = rigid_refit(start, source, target, weights, min_points=11)
    assert not moved and torch.equal(same, start)
