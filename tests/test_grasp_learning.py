"""Grasp densities without a simulator: eq. (8), importance weighting, learning, persistence."""

from __future__ import annotations

import math

import pytest
import torch

from vistask.grasp import (
    GraspLearner,
    Trials,
    Workspace,
    demonstration_density,
    draw_reachable,
    empirical_density,
    feature_grasps,
    frames_to_poses,
    importance_weights,
    instance_grasp_density,
    local_success_rates,
    mixture_proposal,
    reachable,
    scripted_teacher_grasps,
    transform_density,
)
from vistask.grasp.importance import (
    RANKING_WIDTHS,
    RELIABILITY_WIDTH,
    ranking_auc,
    validated_ranking_width,
)
from vistask.grasp.reach import draw_candidates
from vistask.se3 import SE3KDE, compose, identity_poses, make_poses, random_poses
from vistask.vision import Patches


def _gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _pose(t: list[float], rotvec: list[float]) -> torch.Tensor:
    import roma

    return make_poses(torch.tensor(t), roma.rotvec_to_unitquat(torch.tensor(rotvec)))


def test_transform_density_is_the_density_seen_from_the_world() -> None:
    grasps = random_poses(30, 0.05, generator=_gen(1))
    density = SE3KDE(grasps, torch.rand(30, generator=_gen(2)), sigma_t=0.01, sigma_r=0.3)
    pose = _pose([0.3, -0.1, 0.9], [0.2, -1.0, 2.0])
    world = transform_density(density, pose)
    queries = torch.cat([grasps[:10], random_poses(10, 0.05, generator=_gen(3))])
    expected = density.evaluate(queries)
    assert expected.max() > 0.01  # the queries do probe the density (weights sum to 1)
    torch.testing.assert_close(
        world.evaluate(compose(pose, queries)), expected, atol=1e-5, rtol=1e-4
    )
    # ...and is not the untransformed density.
    assert not torch.allclose(world.evaluate(queries), expected, atol=1e-3)


def test_eq8_pushes_the_grasp_density_through_the_pose_belief() -> None:
    # Object model: grasps concentrated at one pose in the object frame.
    g0 = _pose([0.0, 0.02, 0.05], [math.pi, 0.0, 0.0])
    psi = SE3KDE(g0[None], sigma_t=0.005, sigma_r=0.1)
    # Belief: two equally likely object poses (e.g. two instances), sharply known.
    a, b = _pose([0.5, 0.0, 0.8], [0.0, 0.0, 0.5]), _pose([0.2, 0.3, 0.8], [0.0, 0.0, -2.0])
    belief = SE3KDE(torch.stack([a, b]), sigma_t=0.001, sigma_r=0.01)
    world = instance_grasp_density(belief, psi, n=4000, generator=_gen(4))
    ga, gb = compose(a, g0), compose(b, g0)
    near_a = (world.points[:, :3] - ga[:3]).norm(dim=-1) < 0.03
    near_b = (world.points[:, :3] - gb[:3]).norm(dim=-1) < 0.03
    assert (near_a | near_b).all()
    assert abs(near_a.float().mean().item() - 0.5) < 0.05
    # Around each mode the samples follow the transformed kernel: mean position and spread.
    for near, g in ((near_a, ga), (near_b, gb)):
        pts = world.points[near, :3]
        assert (pts.mean(0) - g[:3]).norm() < 0.002
        assert abs(pts.std(0).mean().item() - 0.005) < 0.001
    # The world density peaks at the transformed grasps, not at the object-frame one.
    values = world.evaluate(torch.stack([ga, gb, g0]))
    assert values[0] > 10 * values[2] and values[1] > 10 * values[2]


def test_importance_weights_recover_a_known_success_function() -> None:
    """Successes drawn from a biased proposal, reweighted, estimate the success function."""
    torch.manual_seed(0)
    width = 0.03  # success probability s(t) = exp(-|t|^2 / (2 width^2)), orientation-free
    proposal = SE3KDE(_pose([0.08, 0.0, 0.0], [0.0, 0.0, 0.0])[None], sigma_t=0.05, sigma_r=0.2)
    grasps = proposal.sample(20000, _gen(5))
    s = torch.exp(-(grasps[:, :3] ** 2).sum(-1) / (2 * width**2))
    success = torch.rand(len(grasps), generator=_gen(6)) < s
    trials = Trials()
    trials.add(grasps, success, cycle=0)
    empirical = empirical_density(
        trials, [proposal], c_rel=0.01, sigma_t=0.01, sigma_r=0.2, reliability=0
    )
    raw = grasps[success, :3].double()
    weighted = (empirical.weights.double()[:, None] * empirical.points[:, :3].double()).sum(0)
    # The proposal drags the raw successes towards +x; the weighted ones are centred on 0.
    assert raw[:, 0].mean() > 0.015
    assert weighted.norm() < 0.006
    # The empirical position density has the success function's spread ...
    var = (empirical.weights.double()[:, None] * empirical.points[:, :3].double() ** 2).sum(0)
    assert torch.allclose(var.sqrt(), torch.full((3,), width, dtype=torch.float64), atol=0.006)
    # ... and its values along x follow s up to scale (KDE blur: width^2 + sigma_t^2).
    xs = torch.linspace(-0.06, 0.06, 13)
    queries = make_poses(torch.stack([xs, 0 * xs, 0 * xs], -1), grasps[:1, 3:].expand(13, 4))
    queries = queries.clone()
    queries[:, 3:] = empirical.mean()[3:]
    f = empirical.evaluate(queries)
    target = torch.exp(-(xs**2) / (2 * (width**2 + 0.01**2)))
    assert torch.allclose(f / f.max(), target / target.max(), atol=0.15)


def test_local_success_rates_match_brute_force() -> None:
    grasps = random_poses(40, generator=_gen(30))
    grasps[:, :3] *= 0.02
    success = torch.rand(40, generator=_gen(31)) < 0.5
    trials = Trials()
    trials.add(grasps, success, cycle=0)
    w = 0.5 + torch.rand(40, generator=_gen(32), dtype=torch.float64)
    rates = local_success_rates(trials, w, 0.01, 0.3, prior=2.0)
    # K[i, j]: the kernel of trial j at successful grasp i, one particle at a time.
    at = grasps[success]
    K = torch.stack([SE3KDE(g[None], sigma_t=0.01, sigma_r=0.3).evaluate(at) for g in grasps], 1)
    wn = (w / w.mean()).float()
    overall = wn[success].sum() / wn.sum()
    expected = ((K[:, success] * wn[success]).sum(1) + 2 * overall) / ((K * wn).sum(1) + 2)
    torch.testing.assert_close(rates, expected, rtol=1e-4, atol=1e-5)
    assert len(rates) == int(success.sum())
    # At any grasps: the same regression, failures and successes alike.
    queries = random_poses(7, generator=_gen(36))
    queries[:, :3] *= 0.02
    K = torch.stack(
        [SE3KDE(g[None], sigma_t=0.01, sigma_r=0.3).evaluate(queries) for g in grasps], 1
    )
    expected = ((K[:, success] * wn[success]).sum(1) + 2 * overall) / ((K * wn).sum(1) + 2)
    rates = local_success_rates(trials, w, 0.01, 0.3, prior=2.0, at=queries)
    torch.testing.assert_close(rates, expected, rtol=1e-4, atol=1e-5)


def test_reliability_weighting_favours_grasps_that_succeed_again() -> None:
    """Two places succeed: one always, one one time in three. Weighting successes by the
    success rate around them moves draws from the shaky place to the sure one, the more so
    at a higher power of the rate."""
    sure, shaky = _pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]), _pose([0.08, 0.0, 0.0], [0.0, 0.0, 0.0])
    proposal = SE3KDE(torch.stack([sure, shaky]), sigma_t=0.015, sigma_r=0.1)
    near = lambda g, c: (g[:, :3] - c[:3]).norm(dim=-1) < 0.02  # noqa: E731
    grasps = proposal.sample(600, _gen(33))
    p = near(grasps, sure).float() + near(grasps, shaky).float() / 3
    trials = Trials()
    trials.add(grasps, torch.rand(600, generator=_gen(34)) < p, cycle=0)
    rates = local_success_rates(trials, torch.ones(600), 0.006, 0.16)
    at_sure = near(trials.grasps[trials.success], sure)
    assert rates[at_sure].mean() > 1.5 * rates[~at_sure].mean()
    kwargs = {"c_rel": 1.0, "sigma_t": 0.003, "sigma_r": 0.08}
    plain, once, cubed = (
        empirical_density(trials, [proposal], reliability=k, **kwargs) for k in (0, 1, 3)
    )
    share = lambda d: near(d.sample(4000, _gen(35)), sure).float().mean().item()  # noqa: E731
    assert share(once) > share(plain) + 0.05
    assert share(cubed) > share(once) + 0.05
    with pytest.raises(ValueError, match="reliability"):
        empirical_density(trials, [proposal], reliability=-1.0, **kwargs)
    with pytest.raises(ValueError, match="exploration"):
        GraspLearner(proposal, exploration=float("nan"))
    # With every trial a success, the rates are all 1 and the weights those of the paper.
    trials.success[:] = True
    torch.testing.assert_close(
        empirical_density(trials, [proposal], **kwargs).weights,
        empirical_density(trials, [proposal], reliability=0, **kwargs).weights,
    )


def test_importance_weights_reject_bad_input() -> None:
    assert torch.allclose(
        importance_weights(torch.tensor([0.0, 1.0]), 1.0), torch.tensor([1.0, 0.5])
    )
    with pytest.raises(ValueError, match="non-negative"):
        importance_weights(torch.tensor([-1.0]), 0.1)
    with pytest.raises(ValueError, match="c must"):
        importance_weights(torch.tensor([1.0]), -0.1)


class _SyntheticRunner:
    """Objects at random planar poses; a grasp succeeds near one object-frame pose."""

    num_envs = 4

    def __init__(self, target: torch.Tensor) -> None:
        self.target = target
        self.poses = identity_poses(self.num_envs)

    def reset(self, seeds) -> torch.Tensor:
        g = _gen(int(seeds[0]))
        yaw = 2 * math.pi * torch.rand(self.num_envs, generator=g)
        import roma

        q = roma.rotvec_to_unitquat(torch.stack([0 * yaw, 0 * yaw, yaw], -1))
        t = torch.cat([0.1 * torch.rand(self.num_envs, 2, generator=g), torch.full((4, 1), 0.8)], 1)
        self.poses = make_poses(t, q)
        return self.poses

    def execute(self, grasps: torch.Tensor):
        from vistask.se3 import relative, rotation_distance, translation_distance

        local = relative(self.poses, grasps)
        target = self.target.expand_as(local)
        ok = (translation_distance(local, target) < 0.02) & (rotation_distance(local, target) < 0.4)
        return ok, {}


def test_learning_cycles_improve_on_the_hypothesis_and_round_trip(tmp_path) -> None:
    target = _pose([0.0, 0.0, 0.02], [math.pi, 0.0, 0.0])
    # A broad hypothesis with a little mass near the target.
    hyp = demonstration_density(
        torch.stack([target, _pose([0.03, 0.0, 0.0], [math.pi, 0.0, 1.0])]),
        n_per_demo=50,
        noise_t=0.02,
        noise_r=0.4,
        generator=_gen(7),
    )
    runner = _SyntheticRunner(target)
    learner = GraspLearner(hyp, None, c_rel=0.1, sigma_t=0.005, sigma_r=0.15)
    rates = []
    for k in range(4):
        stats = learner.run_cycle(runner, 80, range(100 * k, 100 * k + 80), _gen(10 + k))
        rates.append(stats.success_rate)
    assert stats.trials == 80 and len(learner.trials) == 320
    assert rates[0] < 0.4
    assert rates[-1] > rates[0] + 0.3
    assert learner.history[-1].effective_sample_size > 1

    path = tmp_path / "learner.pt"
    learner.save(path)
    loaded = GraspLearner.load(path)
    a, b = learner.empirical, loaded.empirical
    torch.testing.assert_close(a.points, b.points)
    torch.testing.assert_close(a.weights, b.weights)
    assert (a.sigma_t, a.sigma_r) == (b.sigma_t, b.sigma_r)
    assert loaded.history == learner.history
    # The next trials are drawn from the successes weighted by the rate itself, the robot
    # samples them weighted by its cube; a loaded learner goes on as the saved one would.
    assert (learner.exploration, learner.reliability) == (1.0, 3.0)
    explored = empirical_density(
        learner.trials, learner.proposals, 0.1, 0.005, 0.15, reliability=1.0
    )
    torch.testing.assert_close(learner.proposal.weights, explored.weights)
    assert not torch.allclose(learner.proposal.weights, a.weights)
    torch.testing.assert_close(loaded.proposal.points, a.points)
    torch.testing.assert_close(loaded.proposal.weights, learner.proposal.weights)
    a.save(tmp_path / "empirical.pt")
    c = SE3KDE.load(tmp_path / "empirical.pt")
    queries = a.sample(50, _gen(11))
    torch.testing.assert_close(c.evaluate(queries), a.evaluate(queries))


def test_reachability_filter() -> None:
    ws = Workspace(floor_z=0.8, base=(-0.56, 0.0, 0.9))
    down = _pose([0.0, 0.0, 0.85], [math.pi, 0.0, 0.0])  # z axis pointing down
    up = _pose([0.0, 0.0, 0.85], [0.0, 0.0, 0.0])  # approach from below the table
    low = _pose([0.0, 0.0, 0.79], [math.pi, 0.0, 0.0])  # below the table top
    far = _pose([0.6, 0.0, 0.85], [math.pi, 0.0, 0.0])  # out of reach
    back = _pose([0.0, 0.0, 0.85], [0.0, -math.pi / 2, 0.0])  # approach towards the base
    out = _pose([0.0, 0.0, 0.85], [0.0, 3 * math.pi / 4, 0.0])  # 45 degrees down, outwards
    ok = reachable(torch.stack([down, up, low, far, back, out]), ws)
    assert ok.tolist() == [True, False, False, False, False, True]
    folded = reachable(
        out[None], Workspace(floor_z=0.8, base=(-0.56, 0.0, 0.9), max_approach_out=0.5)
    )
    assert not folded.any()
    # 2 cm above the table, its closing axis tilted 45 degrees: the open fingers' lower tip
    # (4 cm out along that axis) would reach 8 mm into the table.
    tilted = _pose([0.0, 0.0, 0.82], [2.9025, 0.0, 1.2022])  # down, then 45 degrees about y
    level = _pose([0.0, 0.0, 0.82], [math.pi, 0.0, 0.0])
    fingers = Workspace(floor_z=0.8, base=(-0.56, 0.0, 0.9), opening=0.08)
    assert reachable(torch.stack([tilted, level]), ws).tolist() == [True, True]
    assert reachable(torch.stack([tilted, level]), fingers).tolist() == [False, True]
    density = SE3KDE(torch.stack([down, up]), sigma_t=0.001, sigma_r=0.01)
    _, world, found = draw_reachable(density, identity_poses(8), ws, _gen(12))
    assert found.all() and reachable(world, ws).all()


def test_a_reachable_grasp_is_found_where_one_draw_in_a_hundred_is_reachable() -> None:
    ws = Workspace(floor_z=0.8, base=(-0.56, 0.0, 0.9))
    down = _pose([0.0, 0.0, 0.05], [math.pi, 0.0, 0.0])  # from above: reachable
    up = _pose([0.0, 0.0, 0.05], [0.0, 0.0, 0.0])  # from below the table: never
    density = SE3KDE(torch.stack([down] + [up] * 99), sigma_t=0.001, sigma_r=0.01)
    poses = make_poses(torch.tensor([[0.0, 0.0, 0.85]]).expand(40, 3), identity_poses(40)[:, 3:])
    local, world, found = draw_reachable(density, poses, ws, _gen(14))
    assert found.all() and reachable(world, ws).all()
    torch.testing.assert_close(local[:, :3], down[:3].expand(40, 3), atol=0.01, rtol=0.0)
    assert ((local[:, 3:] * down[3:]).sum(-1).abs() > 0.99).all()  # q and -q: one rotation
    _, _, found = draw_reachable(density, poses, ws, _gen(14), max_draws=1)
    assert found.sum() < 5  # one draw each finds about one in a hundred


def test_trials_fall_back_on_the_hypothesis_where_the_density_reaches_nothing() -> None:
    from vistask.grasp import run_trials

    ws = Workspace(floor_z=0.8, base=(-0.56, 0.0, 0.9))
    down = _pose([0.0, 0.0, 0.05], [math.pi, 0.0, 0.0])  # from above: reachable
    up = _pose([0.0, 0.0, 0.05], [0.0, 0.0, 0.0])  # from below the table: never
    hypothesis = SE3KDE(down[None], sigma_t=0.002, sigma_r=0.05)
    learned = SE3KDE(up[None], sigma_t=0.002, sigma_r=0.05)
    runner = _SyntheticRunner(down)
    _, _, reach, fell = run_trials(learned, runner, 8, range(8), ws, _gen(40))
    assert not reach.any() and not fell.any()
    _, success, reach, fell = run_trials(
        learned, runner, 8, range(8), ws, _gen(40), fallback=hypothesis
    )
    assert reach.all() and fell.all() and success.all()
    # In learning, such draws count as the hypothesis's in the importance weights.
    learner = GraspLearner(hypothesis, ws, sigma_t=0.002, sigma_r=0.05)
    learner.run_cycle(runner, 8, range(8), _gen(41))
    learner.proposal = learned
    stats = learner.run_cycle(runner, 8, range(8, 16), _gen(42))
    assert stats.fallback_rate == 1.0 and learner.trials.cycle.tolist() == [0] * 16


def test_hypothesis_sources_give_valid_grasps() -> None:
    bounds = torch.tensor([[-0.045, -0.03, -0.02], [0.045, 0.03, 0.02]])
    teacher = scripted_teacher_grasps(bounds)
    z = frames_to_poses(
        torch.zeros(1, 3), torch.tensor([[1.0, 0, 0]]), torch.tensor([[0, 0, -1.0]])
    )
    assert torch.allclose(
        z[0, 3:].abs(), torch.tensor([1.0, 0.0, 0.0, 0.0]), atol=1e-6
    )  # pi about x
    assert len(teacher) >= 2 and torch.allclose(
        teacher[:, 3:].norm(dim=-1), torch.ones(len(teacher))
    )
    # Two parallel, same-coloured edges 4 cm apart on the plane z = 0 of an object below it.
    xs = torch.linspace(-0.02, 0.02, 5)
    pos = torch.cat(
        [torch.stack([xs, xs * 0 - 0.02, xs * 0], -1), torch.stack([xs, xs * 0 + 0.02, xs * 0], -1)]
    )
    below = torch.tensor([[0.0, 0.0, -0.03]])
    blue = torch.tensor([[0.1, 0.3, 0.8], [0.9, 0.9, 0.9]])
    colors = blue.expand(11, 2, 3).clone()
    colors[10, 0] = torch.tensor([0.1, 0.8, 0.1])  # the object's body: another colour
    patches = Patches(
        torch.cat([pos, below]), torch.tensor([[1.0, 0.0, 0.0]]).expand(11, 3).clone(), colors
    )
    grasps = feature_grasps(patches)
    assert len(grasps) > 0
    import roma

    R = roma.unitquat_to_rotmat(grasps[:, 3:])
    assert torch.allclose(
        R[:, :, 0].abs(), torch.tensor([0.0, 1.0, 0.0]).expand(len(R), 3), atol=1e-4
    )
    assert torch.allclose(R[:, :, 2], torch.tensor([0.0, 0.0, -1.0]).expand(len(R), 3), atol=1e-4)
    # Differently coloured edges suggest nothing.
    red = patches.colors.clone()
    red[5:10, 0] = torch.tensor([0.9, 0.1, 0.1])
    assert len(feature_grasps(Patches(patches.positions, patches.directions, red))) == 0


def test_best_of_k_draws_pick_the_likelier_grasps() -> None:
    heavy = _pose([0.0, 0.0, 0.0], [math.pi, 0.0, 0.0])
    light = _pose([0.05, 0.0, 0.0], [math.pi, 0.0, 0.0])
    density = SE3KDE(
        torch.stack([heavy, light]), torch.tensor([0.7, 0.3]), sigma_t=0.002, sigma_r=0.05
    )
    plain, _, _ = draw_reachable(density, identity_poses(200), None, _gen(13))
    best, _, _ = draw_reachable(density, identity_poses(200), None, _gen(13), candidates=10)
    near_heavy = lambda g: ((g[:, :3] - heavy[:3]).norm(dim=-1) < 0.01).float().mean()  # noqa: E731
    assert 0.55 < near_heavy(plain) < 0.85
    assert near_heavy(best) > near_heavy(plain) + 0.15
    with pytest.raises(ValueError, match="candidates"):
        draw_reachable(density, identity_poses(2), None, _gen(13), candidates=0)
    with pytest.raises(ValueError, match="max_draws"):
        draw_reachable(density, identity_poses(2), None, _gen(13), max_draws=0)


class _ZoneRunner:
    """Objects at the origin; a grasp within 3 cm of ``good`` always succeeds, any other one
    in a third of the trials."""

    num_envs = 20

    def __init__(self, good: torch.Tensor) -> None:
        self.good, self.draws = good, _gen(41)

    def reset(self, seeds) -> torch.Tensor:
        return identity_poses(self.num_envs)

    def execute(self, grasps: torch.Tensor):
        near = (grasps[:, :3] - self.good[:3]).norm(dim=-1) < 0.03
        return near | (torch.rand(len(grasps), generator=self.draws) < 1 / 3), {}


def test_best_of_k_ranks_by_success_rates_where_the_cycles_validate_them() -> None:
    """Grasps drawn mostly at a shaky place (one success in three), some at a sure one: the
    likeliest of 10 draws lies at the shaky place; the learner's ranking, validated on its
    second cycle, picks the sure one. Where success is chance everywhere, the ranking keeps
    the first candidate: a plain sample."""
    sure, shaky = _pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]), _pose([0.08, 0.0, 0.0], [0.0, 0.0, 0.0])
    proposal = SE3KDE(torch.stack([sure, shaky]), torch.tensor([0.15, 0.85]), 0.01, 0.1)
    learner = GraspLearner(proposal, sigma_t=0.003, sigma_r=0.08)
    with pytest.raises(ValueError, match="no trials"):
        learner.success_rates(sure[None], width=6.0)
    assert learner.ranking_width is None  # nothing to validate on yet
    runner = _ZoneRunner(sure)
    for cycle in range(2):
        learner.run_cycle(runner, 400, range(400 * cycle, 400 * (cycle + 1)), _gen(40 + cycle))
    assert learner.ranking_width in RANKING_WIDTHS
    rates = learner.rank(torch.stack([sure, shaky]))
    assert rates[0] > 0.9 and rates[1] < 0.5
    near_sure = lambda g: ((g[:, :3] - sure[:3]).norm(dim=-1) < 0.03).float().mean()  # noqa: E731
    poses = identity_poses(200)
    likeliest, _, _ = draw_reachable(proposal, poses, None, _gen(42), candidates=10)
    best, _, _ = draw_reachable(proposal, poses, None, _gen(42), candidates=10, score=learner.rank)
    assert near_sure(likeliest) < 0.1
    assert near_sure(best) > 0.7  # 1 - 0.85^10 = 0.80 of the placements have a sure draw

    # Where success does not depend on the grasp, no width ranks better than chance.
    learner = GraspLearner(proposal, sigma_t=0.003, sigma_r=0.08)
    runner.good = _pose([1.0, 0.0, 0.0], [0.0, 0.0, 0.0])  # out of reach: a third everywhere
    for cycle in range(3):
        learner.run_cycle(runner, 400, range(400 * cycle, 400 * (cycle + 1)), _gen(50 + cycle))
    assert learner.ranking_width is None
    kept, _, _ = draw_reachable(proposal, poses, None, _gen(42), candidates=10, score=learner.rank)
    candidates, _, _ = draw_candidates(proposal, poses, None, _gen(42), candidates=10)
    torch.testing.assert_close(kept, candidates[0])


def test_ranking_auc_and_its_validation_split() -> None:
    rates = torch.tensor([0.9, 0.8, 0.8, 0.1])
    auc, z = ranking_auc(rates, torch.tensor([True, True, False, False]))
    assert auc == 0.875 and z > 0
    assert ranking_auc(rates, torch.tensor([False, False, True, True]))[0] == 0.125
    assert ranking_auc(rates, torch.ones(4, dtype=torch.bool)) is None
    # Within strata: each success is compared only with the failures of its own stratum.
    strata = torch.tensor([0, 0, 1, 1])
    auc, _ = ranking_auc(rates, torch.tensor([True, False, False, True]), strata)
    assert auc == 0.5  # 0.9 > 0.8 in stratum 0, 0.1 < 0.8 in stratum 1
    assert ranking_auc(rates, torch.tensor([True, True, False, False]), strata) is None
    # z grows with the evidence: the same order over ten times the outcomes.
    many = ranking_auc(rates.repeat(10), torch.tensor([True, True, False, False]).repeat(10))
    assert many[0] == pytest.approx(0.875, abs=0.01) and many[1] > 2 * z
    flat = SE3KDE(identity_poses(1), torch.ones(1), 1.0, 3.0)
    trials = Trials()
    trials.add(identity_poses(4), torch.tensor([True, False, True, True]), cycle=0)
    trials.add(identity_poses(2), torch.tensor([True, True]), cycle=1)
    # Held-out trials all succeeded: nothing to rank them by.
    assert validated_ranking_width(trials, [flat, flat], 1.0, 0.01, 0.1) is None
    with pytest.raises(ValueError, match="significance"):
        validated_ranking_width(trials, [flat, flat], 1.0, 0.01, 0.1, significance=0.0)


def test_success_rates_for_ranking_see_the_failures_a_centimetre_around() -> None:
    """A lucky success ringed by failures 12 mm away, against a grasp that failed once among
    successes: kernels of the reliability's width (4 mm) see only the trials on each and rate
    the lucky one higher; the ranking's (12 mm) see the rings and rate it lower."""
    lucky, solid = _pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]), _pose([0.1, 0.0, 0.0], [0.0, 0.0, 0.0])
    angles = torch.arange(10) * (2 * math.pi / 10)
    ring = 0.012 * torch.stack([angles.cos(), angles.sin(), torch.zeros(10)], dim=1)
    around = lambda g: torch.cat([g[:3] + ring, g[3:].expand(10, 4)], dim=1)  # noqa: E731
    grasps = torch.cat([lucky[None], around(lucky), solid.expand(3, 7), around(solid)])
    success = torch.tensor([True] + [False] * 10 + [True, True, False] + [True] * 10)
    flat = SE3KDE(identity_poses(1), torch.ones(1), 1.0, 3.0)  # equal importance weights
    learner = GraspLearner(flat, sigma_t=0.002, sigma_r=0.05)
    learner.trials.add(grasps, success, cycle=0)
    learner.proposals.append(flat)
    narrow = learner.success_rates(grasps[[0, 11]], width=RELIABILITY_WIDTH)
    assert narrow[0] > narrow[1]
    rates = learner.success_rates(grasps[[0, 11]], width=6.0)
    assert rates[0] < 0.3 < 0.8 < rates[1]


def test_pooled_cycles_are_weighted_by_the_mixture_of_their_proposals() -> None:
    broad = SE3KDE(identity_poses(1), sigma_t=0.05, sigma_r=0.5)
    sharp = SE3KDE(identity_poses(1), sigma_t=0.005, sigma_r=0.1)
    trials = Trials()
    g0, g1 = broad.sample(100, _gen(14)), sharp.sample(300, _gen(15))
    trials.add(g0, torch.ones(100, dtype=torch.bool), cycle=0)
    trials.add(g1, torch.ones(300, dtype=torch.bool), cycle=1)
    q = mixture_proposal(trials, [broad, sharp])
    expected = 0.25 * broad.evaluate(trials.grasps, normalized=True) + 0.75 * sharp.evaluate(
        trials.grasps, normalized=True
    )
    torch.testing.assert_close(q, expected.double(), rtol=1e-4, atol=0.0)
    empirical = empirical_density(trials, [broad, sharp], c_rel=0.0)
    torch.testing.assert_close(
        empirical.weights.double(), (1 / q) / (1 / q).sum(), rtol=1e-4, atol=0.0
    )
    with pytest.raises(ValueError, match="proposals"):
        mixture_proposal(trials, [broad])


class _SeededRunner:
    """Each trial's object pose follows its own placement seed, as in the simulator."""

    def __init__(self, num_envs: int, target: torch.Tensor) -> None:
        self.num_envs, self.target = num_envs, target

    def reset(self, seeds) -> torch.Tensor:
        assert len(seeds) == self.num_envs
        t = torch.stack([0.1 * torch.rand(3, generator=_gen(int(s))) for s in seeds])
        self.poses = make_poses(t, identity_poses(len(seeds))[:, 3:])
        return self.poses

    def execute(self, grasps: torch.Tensor):
        from vistask.se3 import relative, translation_distance

        local = relative(self.poses, grasps)
        return translation_distance(local, self.target.expand_as(local)) < 0.03, {}


def test_trials_do_not_depend_on_how_many_simulators_run_them() -> None:
    from vistask.grasp import run_trials

    target = _pose([0.0, 0.0, 0.02], [math.pi, 0.0, 0.0])
    density = demonstration_density(target[None], n_per_demo=40, noise_t=0.03, generator=_gen(1))
    results = [
        run_trials(density, _SeededRunner(b, target), 10, range(50, 60), None, _gen(5))
        for b in (1, 3, 4)
    ]
    for grasps, success, reach, _ in results[1:]:
        assert len(success) == 10
        torch.testing.assert_close(grasps, results[0][0])
        assert torch.equal(success, results[0][1]) and torch.equal(reach, results[0][2])
    assert 0 < int(results[0][1].sum()) < 10  # the outcomes carry information
    with pytest.raises(ValueError, match="need 10 placement seeds"):
        run_trials(density, _SeededRunner(2, target), 10, range(9), None, _gen(5))


class _RecordingRunner(_SeededRunner):
    """``_SeededRunner`` for ``GraspExperiment``: a 4 cm cube; records the placement seeds."""

    workspace = None
    object_bounds = ((-0.02,) * 3, (0.02,) * 3)

    def __init__(self) -> None:
        super().__init__(1, _pose([0.0, 0.0, 0.02], [math.pi, 0.0, 0.0]))
        self.placements: list[int] = []

    def reset(self, seeds) -> torch.Tensor:
        self.placements += [int(s) for s in seeds]
        return super().reset(seeds)

    def close(self) -> None:
        pass


def test_learning_placements_follow_the_seed_and_held_out_ones_do_not(tmp_path, monkeypatch):
    from types import SimpleNamespace

    from vistask.experiments.grasps import GraspExperiment, learning_placements

    def placements(seed: int) -> tuple[list[int], list[int]]:
        """(learning, held-out) placement seeds of a run seeded ``seed``."""
        runner = _RecordingRunner()
        monkeypatch.setattr(GraspExperiment, "_runner", lambda self, kind, model: runner)
        experiment = GraspExperiment(
            objects=("cube",),
            hypothesis="demo",
            cycles=2,
            trials_per_cycle=3,
            eval_trials=2,
            seed=seed,
        )
        corners = 0.02 * torch.tensor([[x, y, 1.0] for x in (-1, 1) for y in (-1, 1)])
        top = Patches(corners, torch.eye(3)[[0, 1, 0, 1]], torch.rand(4, 2, 3, generator=_gen()))
        model = SimpleNamespace(name="cube", patches=top)  # all that the demo hypothesis needs
        experiment.learn_object("cube", model, tmp_path / str(seed))
        # Held out: 2 placements, sampled then best of 10, before and after learning.
        held_out = runner.placements[:4] + runner.placements[-4:]
        return runner.placements[4:-4], held_out

    learn0, held0 = placements(0)
    learn1, held1 = placements(1)
    assert learn0 == [*learning_placements(0, 0, 3), *learning_placements(0, 1, 3)]
    assert held0 == held1 and len(set(held0)) == 2
    assert len(set(learn0)) == len(set(learn1)) == 6 and not set(learn0) & set(learn1)
    assert not set(held0) & (set(learn0) | set(learn1))
    with pytest.raises(ValueError, match="seed"):
        GraspExperiment(seed=-1)
