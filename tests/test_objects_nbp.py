"""NBP on synthetic scenes: messages, products, pose recovery in clutter, clear errors."""

from dataclasses import replace

import pytest
import torch

from vistask.objects import NBP, ObjectModel, appearance_descriptors, multiply, push_up
from vistask.objects.messages import SceneMatch, scene_evidence
from vistask.objects.nbp import link_groups
from vistask.objects.synthetic import synthetic_object, synthetic_scene
from vistask.se3 import SE3KDE, compose, inverse, kernels, random_poses, rotation_distance
from vistask.vision import Patches, pose_error

FAST = NBP(n_particles=400, mode_starts=24)


@pytest.fixture(scope="module")
def model() -> ObjectModel:
    return ObjectModel.learn(synthetic_object(), "chair", n_classes=6)


def test_push_up_composes_with_the_inverse_potential() -> None:
    g = torch.Generator().manual_seed(0)
    x, r = random_poses(1, 0.1, generator=g), random_poses(1, 0.1, generator=g)
    child = SE3KDE(x, sigma_t=0.01, sigma_r=0.1)
    potential = SE3KDE(r, sigma_t=0.01, sigma_r=0.1)
    message = push_up(child, potential, 10, 0.02, 0.3, g)
    expected = compose(x, inverse(r))
    torch.testing.assert_close(message.points[:, :3], expected[:, :3], atol=1e-5, rtol=0)
    assert rotation_distance(message.points, expected).max() < 1e-3
    assert (message.sigma_t, message.sigma_r) == (0.02, 0.3)


def test_product_keeps_what_the_messages_agree_on() -> None:
    g = torch.Generator().manual_seed(1)
    a, b, c = random_poses(3, 0.2, generator=g)

    def near(p: torch.Tensor) -> torch.Tensor:  # 50 poses within ~2 mm of p
        return p + torch.cat([0.002 * torch.randn(50, 3, generator=g), torch.zeros(50, 4)], 1)

    first = SE3KDE(torch.cat([near(a), near(b)]), sigma_t=0.01, sigma_r=0.2)
    second = SE3KDE(torch.cat([near(a), near(c)]), sigma_t=0.01, sigma_r=0.2)
    prod = multiply([first, second], 200, floor=0.01, cutoff=None, generator=g)
    mass_at_a = prod.weights[(prod.points[:, :3] - a[:3]).norm(dim=1) < 0.02].sum()
    assert mass_at_a > 0.95


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_nbp_recovers_the_pose_in_clutter(model: ObjectModel, seed: int) -> None:
    g = torch.Generator().manual_seed(100 + seed)
    pose = random_poses(1, 0.1, generator=g)[0]
    scene = synthetic_scene(pose, n_clutter=300, keep=0.6, seed=seed)
    result = FAST.infer(model, scene, seed=seed)
    t_err, r_err = pose_error(result.pose, pose)
    assert t_err < 0.005 and r_err < 3.0
    assert result.scores[0] >= result.scores.max()
    assert result.poses.shape[1] == 7 and len(result.poses) <= FAST.n_modes


def test_two_instances_give_two_modes(model: ObjectModel) -> None:
    g = torch.Generator().manual_seed(7)
    poses = random_poses(2, 0.0, generator=g)
    poses[0, :3] = torch.tensor([0.2, 0.0, 0.0])
    poses[1, :3] = torch.tensor([-0.2, 0.0, 0.0])
    scene = Patches.cat(
        [synthetic_scene(p, n_clutter=0, keep=0.8, seed=i) for i, p in enumerate(poses)]
    )
    result = NBP(n_particles=800, n_modes=4).infer(model, scene, seed=0)
    for true in poses:
        t_err, r_err = pose_error(result.poses[:2], true)
        assert (t_err < 0.01).any() and (r_err[t_err < 0.01] < 5.0).any()


def test_top_down_pass_gives_a_belief_for_every_feature(model: ObjectModel) -> None:
    pose = random_poses(1, 0.1, generator=torch.Generator().manual_seed(3))[0]
    scene = synthetic_scene(pose, n_clutter=50, seed=3)
    result = NBP(n_particles=300, top_down=True).infer(model, scene, seed=0)
    assert set(result.beliefs) == set(range(len(model.features)))
    # The top-down belief of a primitive feature lies on the object's instances.
    leaf = model.leaves()[0]
    belief = result.beliefs[leaf]
    instances = compose(pose, model.instances(model.features[leaf].appearance))
    nearest = torch.cdist(belief.points[:, :3], instances[:, :3]).min(dim=1).values
    assert (belief.weights * (nearest < 0.01)).sum() > 0.8


def test_empty_or_foreign_scenes_are_clear_errors(model: ObjectModel) -> None:
    obj = synthetic_object()
    with pytest.raises(ValueError, match="empty scene"):
        FAST.infer(model, obj.select(torch.zeros(len(obj), dtype=torch.bool)))
    grey = Patches(obj.positions, obj.directions, torch.full_like(obj.colors, 0.5), obj.normals)
    with pytest.raises(ValueError, match="no scene patch matches"):
        FAST.infer(model, grey)
    with pytest.raises(ValueError, match="normals"):
        FAST.infer(model, Patches(obj.positions, obj.directions, obj.colors))


def test_colours_moved_out_of_tight_classes_are_matched_within_wider_ones(
    model: ObjectModel,
) -> None:
    # Another lamp darkens one side of every edge: each observed colour pair lies between
    # one and two radii from its class's centre.
    pose = random_poses(1, 0.1, generator=torch.Generator().manual_seed(5))[0]
    scene = synthetic_scene(pose, n_clutter=0, keep=0.8, seed=5)
    shade = torch.tensor([0.75, 1.0])[:, None]
    relit = Patches(scene.positions, scene.directions, scene.colors * shade, scene.normals)
    labels = model.classify(scene.colors)
    moved = appearance_descriptors(relit.colors) - model.centres[labels]
    radii = torch.stack([moved.norm(dim=1)[labels == k].min() for k in range(model.n_classes)])
    tight = replace(model, radii=radii / 1.5)
    assert (tight.classify(relit.colors) == -1).all()
    with pytest.raises(ValueError, match="no scene patch matches"):
        NBP(n_particles=400, mode_starts=24, min_matches=0).infer(tight, relit)
    t_err, r_err = pose_error(FAST.infer(tight, relit).pose, pose)
    assert t_err < 0.005 and r_err < 3.0


def test_scene_match_blocks_give_the_support_of_every_instance_against_every_patch(
    model: ObjectModel,
) -> None:
    pose = random_poses(1, 0.1, generator=torch.Generator().manual_seed(4))[0]
    scene = synthetic_scene(pose, n_clutter=100, seed=4)
    evidence = scene_evidence(model, scene)
    match = SceneMatch.build(model, evidence, color_sigma=0.1)
    # Brute force: every instance against every observed patch, other features masked out.
    inst, inst_c, inst_l, obs, obs_c, obs_l = [], [], [], [], [], []
    for leaf, ev in evidence.items():
        if ev is not None:
            k = model.features[leaf].appearance
            inst.append(model.instances(k))
            inst_c.append(model.instance_colors(k))
            inst_l.append(torch.full((len(inst[-1]),), leaf))
            obs.append(ev.density.points)
            obs_c.append(ev.colors)
            obs_l.append(torch.full((len(obs[-1]),), leaf))
    same = torch.cat(inst_l)[:, None] == torch.cat(obs_l)[None]
    color_d2 = torch.cdist(torch.cat(inst_c), torch.cat(obs_c)).square()
    affinity = same * torch.exp(-0.5 * color_d2 / 0.1**2)
    others = random_poses(3, 0.1, generator=torch.Generator().manual_seed(5))
    poses = torch.cat([pose[None], others])
    pred = compose(poses[:, None], torch.cat(inst)[None])
    o = torch.cat(obs)
    d2 = torch.cdist(pred[..., :3], o[None, :, :3]).square()
    dot = (pred[..., 3:] @ o[:, 3:].T).abs()
    kern = torch.exp(-0.5 * d2 / 0.004**2 + kernels.quaternion_kappa(0.35) * (dot - 1.0))
    expected = (kern * affinity).amax(dim=2).sum(dim=1)
    torch.testing.assert_close(match.support(poses, 0.004, 0.35), expected, rtol=1e-5, atol=1e-4)
    assert expected[0] > expected[1:].max()


def test_bad_arguments_are_named_in_the_error() -> None:
    with pytest.raises(ValueError, match="n_particles must be >= 1, got 0"):
        NBP(n_particles=0)
    with pytest.raises(ValueError, match=r"evidence_sigma_r must be positive, got -0\.1"):
        NBP(evidence_sigma_r=-0.1)
    with pytest.raises(ValueError, match="cutoff"):
        NBP(cutoff=0.0)
    with pytest.raises(ValueError, match="min_matches must be >= 0, got -1"):
        NBP(min_matches=-1)
    with pytest.raises(ValueError, match="pair_references must be >= 0, got -1"):
        NBP(pair_references=-1)


def test_link_groups_join_chains_of_near_points_as_a_brute_force_does() -> None:
    g = torch.Generator().manual_seed(4)
    points = torch.rand(120, 3, generator=g) * 0.2
    groups = link_groups(points, 0.03)
    near = torch.cdist(points, points) < 0.03
    for start in range(len(points)):  # breadth-first search from every point
        reached, frontier = {start}, [start]
        while frontier:
            frontier = [j for i in frontier for j in torch.nonzero(near[i])[:, 0].tolist()]
            frontier = [j for j in frontier if j not in reached]
            reached.update(frontier)
        assert groups[start] == min(reached)
    assert 1 < len(torch.unique(groups)) < len(points)
