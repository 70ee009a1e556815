"""The tensor-heavy cores on CUDA give what they give on the CPU (skipped without a GPU).

Run on a machine with one: ``pytest tests/test_cuda.py``.
"""

import math

import numpy as np
import pytest
import roma
import torch

from vistask.features.vocabulary import CoarseGroups, grouped_kmeans
from vistask.grasp import GraspLearner, demonstration_density
from vistask.kmeans import kmeans, nearest_centroids
from vistask.objects import NBP, ObjectModel
from vistask.objects.pair_votes import PairTable
from vistask.objects.synthetic import synthetic_object, synthetic_scene
from vistask.rlvc import ClassBDD, ClassTree
from vistask.se3 import (
    SE3KDE,
    compose,
    identity_poses,
    make_poses,
    random_poses,
    relative,
    rotation_distance,
    translation_distance,
)
from vistask.vision import pose_error

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
CUDA = torch.device("cuda")


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _cluster(n: int, seed: int, spread: float = 0.03) -> torch.Tensor:
    g = _gen(seed)
    t = spread * torch.randn(n, 3, generator=g, dtype=torch.float64)
    q = roma.rotvec_to_unitquat(0.3 * torch.randn(n, 3, generator=g, dtype=torch.float64))
    return torch.cat([t, q], dim=1)


@pytest.mark.parametrize("kernel", ["gaussian", "triangular"])
def test_density_values_equal_the_cpus(kernel: str) -> None:
    points = torch.cat([_cluster(2000, 0), _cluster(2000, 1) + torch.tensor([0.2] + [0] * 6)])
    weights = torch.rand(len(points), generator=_gen(2), dtype=torch.float64)
    cpu = SE3KDE(points, weights, sigma_t=0.01, sigma_r=0.3, kernel=kernel)
    gpu = cpu.to(CUDA)
    queries = torch.cat([_cluster(500, 3), _cluster(500, 4) + torch.tensor([0.1] + [0] * 6)])
    expected = cpu.evaluate(queries)
    got = gpu.evaluate(queries.to(CUDA))
    assert got.device.type == "cuda"
    torch.testing.assert_close(got.cpu(), expected, rtol=1e-9, atol=1e-12 * float(expected.max()))
    if kernel == "gaussian":
        cut = gpu.evaluate(queries.to(CUDA), cutoff=3.0)
        torch.testing.assert_close(cut.cpu(), cpu.evaluate(queries, cutoff=3.0), rtol=1e-9, atol=0)


def test_samples_and_modes_on_the_gpu_follow_the_density() -> None:
    # Two clumps of one orientation, 30 cm apart, holding 3/4 and 1/4 of the mass.
    t = 0.002 * torch.randn(400, 3, generator=_gen(5), dtype=torch.float64)
    t[300:, 0] += 0.3
    points = torch.cat([t, identity_poses(400, dtype=torch.float64)[:, 3:]], 1)
    density = SE3KDE(points, sigma_t=0.005, sigma_r=0.1, device=CUDA)
    draws = density.sample(20_000, torch.Generator(device=CUDA).manual_seed(0))
    assert draws.device.type == "cuda" and draws.shape == (20_000, 7)
    norms = draws[:, 3:].norm(dim=1)
    torch.testing.assert_close(norms, torch.ones_like(norms))
    assert abs(float((draws[:, 0] > 0.15).double().mean()) - 0.25) < 0.02
    modes, _ = density.modes(k=2, generator=torch.Generator(device=CUDA).manual_seed(1))
    assert modes.device.type == "cuda"
    assert abs(float(modes[0, 0])) < 0.01 and abs(float(modes[1, 0]) - 0.3) < 0.01


def test_nearest_centroids_and_kmeans_equal_the_cpus() -> None:
    g = _gen(7)
    centres = 10 * torch.randn(64, 32, generator=g)
    x = centres[torch.randint(64, (20_000,), generator=g)] + torch.randn(20_000, 32, generator=g)
    index, dist = nearest_centroids(x, centres, k=3)
    index_gpu, dist_gpu = nearest_centroids(x.to(CUDA), centres.to(CUDA), k=3)
    assert torch.equal(index_gpu.cpu(), index)
    torch.testing.assert_close(dist_gpu.cpu(), dist, rtol=1e-4, atol=1e-2)
    fitted_gpu = kmeans(x.to(CUDA), 64, iters=10, seed=0)
    assert fitted_gpu.device.type == "cuda"
    # The GPU's sums are atomic, so their rounding (and a point between two centroids) can
    # differ from run to run: both devices fit the points equally well.
    fitted = (fitted_gpu.cpu(), kmeans(x, 64, iters=10, seed=0))
    inertia = [float(nearest_centroids(x, c)[1].mean()) for c in fitted]
    assert inertia[0] == pytest.approx(inertia[1], rel=0.01)


def test_grouped_vocabulary_search_equals_the_cpus() -> None:
    x = torch.randn(5000, 16, generator=_gen(8))
    prototypes, group_of, centres = grouped_kmeans(x, 128, groups=8, iters=5)
    cpu = CoarseGroups(centres, group_of, probes=2)
    gpu = CoarseGroups(centres.to(CUDA), group_of.to(CUDA), probes=2)
    for rows in (x[:50], x):  # one percept's few descriptors, and a database's many
        index, _ = cpu.nearest(rows, prototypes, k=2)
        index_gpu, _ = gpu.nearest(rows.to(CUDA), prototypes.to(CUDA), k=2)
        assert torch.equal(index_gpu.cpu(), index)


def test_pair_votes_equal_the_cpus() -> None:
    def poses(n: int, spread: float, seed: int) -> torch.Tensor:
        return random_poses(n, spread, generator=_gen(seed), dtype=torch.float64)

    model = poses(60, 0.04, 9)
    # Scene patches 1 mm and 3 degrees off the model's: exact copies would put the turn of
    # every right pair exactly on the edge between the last turn bin and the first.
    g = _gen(12)
    noise = torch.cat(
        [
            0.001 * torch.randn(60, 3, generator=g, dtype=torch.float64),
            roma.rotvec_to_unitquat(0.05 * torch.randn(60, 3, generator=g, dtype=torch.float64)),
        ],
        1,
    )
    placed = compose(poses(1, 0.3, 10).expand(60, 7), compose(model, noise))
    scene = torch.cat([placed, poses(200, 0.2, 11)])
    references = torch.arange(0, 260, 13)
    votes = PairTable(model).votes(scene, references)
    votes_gpu = PairTable(model.to(CUDA)).votes(scene.to(CUDA), references.to(CUDA))
    assert votes.amax() > 10
    assert torch.equal(votes_gpu.cpu(), votes)


@pytest.fixture(scope="module")
def chair() -> ObjectModel:
    return ObjectModel.learn(synthetic_object(), "chair", n_classes=6)


@pytest.mark.parametrize("seed", [0, 1])
def test_nbp_on_the_gpu_recovers_the_pose_in_clutter(chair: ObjectModel, seed: int) -> None:
    pose = random_poses(1, 0.1, generator=_gen(100 + seed))[0]
    scene = synthetic_scene(pose, n_clutter=300, keep=0.6, seed=seed)
    result = NBP(n_particles=400, mode_starts=24).infer(chair, scene, device=CUDA, seed=seed)
    t_err, r_err = pose_error(result.pose.cpu(), pose)
    assert t_err < 0.005 and r_err < 3.0


def test_class_tree_and_bdd_classify_gpu_presence_as_cpu_presence() -> None:
    rng = np.random.default_rng(0)
    tree, bdd = ClassTree(30), ClassBDD(30)
    for _ in range(60):
        c, f = int(rng.integers(tree.n_classes)), int(rng.integers(30))
        tree.split(c, f), bdd.split(c, f)
    presence = torch.from_numpy(rng.random((3000, 30)) < 0.3)
    expected = tree.classify(presence)
    for classifier in (tree, bdd):
        got = classifier.classify(presence.to(CUDA))
        assert got.device.type == "cuda"
        assert torch.equal(got.cpu(), expected)


class _Runner:
    """Objects at random yaws on the CPU, as a simulator holds them; a grasp succeeds near
    one object-frame pose."""

    num_envs = 4

    def __init__(self, target: torch.Tensor) -> None:
        self.target, self.poses = target, identity_poses(self.num_envs)

    def reset(self, seeds) -> torch.Tensor:
        yaw = 2 * math.pi * torch.rand(self.num_envs, generator=_gen(int(seeds[0])))
        q = roma.rotvec_to_unitquat(torch.stack([0 * yaw, 0 * yaw, yaw], -1))
        self.poses = make_poses(torch.full((self.num_envs, 3), 0.1), q)
        return self.poses

    def execute(self, grasps: torch.Tensor):
        local = relative(self.poses, grasps.cpu())
        target = self.target.expand_as(local)
        ok = (translation_distance(local, target) < 0.02) & (rotation_distance(local, target) < 0.4)
        return ok, {}


def test_grasp_learning_with_a_gpu_density_improves_on_its_hypothesis() -> None:
    target = make_poses(
        torch.tensor([0.0, 0.0, 0.02]), roma.rotvec_to_unitquat(torch.tensor([math.pi, 0.0, 0.0]))
    )
    other = make_poses(
        torch.tensor([0.03, 0.0, 0.0]), roma.rotvec_to_unitquat(torch.tensor([math.pi, 0.0, 1.0]))
    )
    hypothesis = demonstration_density(
        torch.stack([target, other]), n_per_demo=50, noise_t=0.02, noise_r=0.4, generator=_gen(7)
    ).to(CUDA)
    learner = GraspLearner(hypothesis, None, c_rel=0.1, sigma_t=0.005, sigma_r=0.15)
    rates = []
    for k in range(4):
        generator = torch.Generator(device=CUDA).manual_seed(10 + k)
        rates.append(
            learner.run_cycle(
                _Runner(target), 80, range(100 * k, 100 * k + 80), generator
            ).success_rate
        )
    assert rates[-1] > rates[0] + 0.3
    assert learner.empirical.device.type == "cuda"
