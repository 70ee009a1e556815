"""Pose votes of patch pairs: rigid-invariant features, votes against a brute force, poses
found among clutter."""

from __future__ import annotations

import math
import pickle

import pytest
import roma
import torch

from vistask.objects import ObjectModel
from vistask.objects.pair_votes import PEAKS_PER_REFERENCE, TURN_BINS, PairTable, pair_features
from vistask.se3 import compose, random_poses
from vistask.vision import Patches, pose_error


def _frames(n: int, seed: int, spread: float = 0.05) -> torch.Tensor:
    return random_poses(n, spread, generator=torch.Generator().manual_seed(seed))


def _right(pose: torch.Tensor, truth: torch.Tensor) -> bool:
    err_t, err_r = pose_error(pose, truth)
    return bool(err_t < 0.015 and err_r < 360 / TURN_BINS)


def test_pair_features_do_not_change_under_a_rigid_motion() -> None:
    a, b = _frames(50, 0), _frames(50, 1)
    x = _frames(1, 2, spread=0.3).expand(50, 7)
    before, after = pair_features(a, b), pair_features(compose(x, a), compose(x, b))
    for u, v in zip(before, after, strict=True):
        torch.testing.assert_close(u, v, atol=1e-4, rtol=1e-4)
    distance, angles, _ = before
    torch.testing.assert_close(distance, (b[:, :3] - a[:, :3]).norm(dim=1))
    assert ((angles >= 0) & (angles <= math.pi)).all()


def test_votes_equal_a_brute_force_over_every_pair_of_pairs() -> None:
    model = _frames(9, 3)
    table = PairTable(model)
    scene = torch.cat([compose(_frames(1, 4, 0.3).expand(9, 7), model), _frames(5, 5)])
    references = torch.tensor([0, 4, 10])
    votes = table.votes(scene, references)
    expected = torch.zeros(len(references), len(model), TURN_BINS, dtype=votes.dtype)
    n = len(model)
    for r, i in enumerate(references.tolist()):
        for j in range(len(scene)):
            d_s, a_s, t_s = pair_features(scene[i : i + 1], scene[j : j + 1])
            if j == i or d_s > table.diameter:
                continue
            for a in range(n):
                for b in range(n):
                    if a == b:
                        continue
                    d_m, a_m, t_m = pair_features(model[a : a + 1], model[b : b + 1])
                    if table.key(d_s, a_s) == table.key(d_m, a_m):
                        turn = float((t_m - t_s) / (2 * math.pi)) % 1.0
                        expected[r, a, min(int(turn * TURN_BINS), TURN_BINS - 1)] += 1
    assert votes.sum() > 0
    assert torch.equal(votes, expected)


def test_the_most_voted_pose_puts_the_model_where_it_lies_among_clutter() -> None:
    model = _frames(120, 6, spread=0.04)
    truth = _frames(1, 7, spread=0.3)[0]
    seen = compose(truth.expand(60, 7), model[:60])  # half of the object in view
    clutter = _frames(240, 8, spread=0.15)  # four times as many patches elsewhere
    scene = torch.cat([clutter, seen])
    poses, votes = PairTable(model).vote(scene, 40, torch.Generator().manual_seed(0))
    assert 0 < len(poses) <= 40 * PEAKS_PER_REFERENCE and (votes[:-1] >= votes[1:]).all()
    err_t, err_r = pose_error(poses[0], truth)
    # within half a turn bin, at the lever arm of the reference patch
    assert err_t < 0.01 and err_r < 360 / TURN_BINS


def test_a_reference_on_a_target_that_shows_few_patches_keeps_its_pose_beside_lookalikes() -> None:
    model = _frames(120, 6, spread=0.04)
    truth = _frames(1, 7, spread=0.3)[0]
    seen = compose(truth.expand(15, 7), model[:15])  # an eighth of the object in view
    # Two whole lookalikes: every one of their references is voted for by more partners.
    lookalikes = [compose(_frames(1, s, spread=0.3)[0].expand(120, 7), model) for s in (8, 9)]
    scene = torch.cat([*lookalikes, seen])
    poses, _ = PairTable(model).vote(scene, len(scene), torch.Generator().manual_seed(0))
    right = [i for i, p in enumerate(poses) if _right(p, truth)]
    assert right and right[0] >= 32  # below every lookalike reference's peaks, still returned


def test_references_drawn_among_preferred_patches_find_a_model_that_few_patches_show() -> None:
    model = _frames(120, 6, spread=0.04)
    truth = _frames(1, 7, spread=0.3)[0]
    seen = compose(truth.expand(30, 7), model[:30])  # a quarter of the object in view
    clutter = _frames(600, 8, spread=0.15)  # twenty times as many patches elsewhere
    scene = torch.cat([clutter, seen])
    prefer = torch.zeros(len(scene), dtype=torch.bool)
    prefer[-40:] = True  # the object's patches and ten of the clutter's
    table = PairTable(model)

    def found(preferred: torch.Tensor | None) -> int:
        right = 0
        for seed in range(5):
            poses, _ = table.vote(scene, 2, torch.Generator().manual_seed(seed), preferred)
            right += _right(poses[0], truth)
        return right

    # One reference of two is drawn among the 40 preferred, 30 of them on the object.
    assert found(prefer) >= 4 and found(None) == 0


def test_a_scene_without_matching_pairs_votes_for_nothing() -> None:
    model = _frames(10, 9, spread=0.01)
    far_apart = _frames(2, 10)
    far_apart[1, :3] = far_apart[0, :3] + 1.0  # beyond the model's diameter
    poses, votes = PairTable(model).vote(far_apart, 5, torch.Generator().manual_seed(0))
    assert poses.shape == (0, 7) and votes.shape == (0,)


def test_bad_arguments_are_named_in_the_error() -> None:
    with pytest.raises(ValueError, match="at least 2 patches, got 1"):
        PairTable(_frames(1, 0))
    with pytest.raises(ValueError, match="n_references must be >= 1, got 0"):
        PairTable(_frames(5, 0)).vote(_frames(5, 1), 0, torch.Generator())


def test_an_object_model_builds_its_table_once_and_does_not_pickle_it() -> None:
    frames = _frames(60, 11, spread=0.03)
    axes = roma.unitquat_to_rotmat(frames[:, 3:])
    colors = torch.rand(60, 2, 3, generator=torch.Generator().manual_seed(0))
    patches = Patches(frames[:, :3], axes[:, :, 0], colors, axes[:, :, 2])
    model = ObjectModel.learn(patches, "blob", n_classes=2)
    table = model.pair_table()
    assert model.pair_table() is table
    torch.testing.assert_close(table.frames, patches.frames())
    copy = pickle.loads(pickle.dumps(model))
    assert copy._pair_table is None and len(copy.pair_table().keys) == len(table.keys)
