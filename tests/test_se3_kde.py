"""SE3KDE: normalisation, sign invariance, exact agreement with brute force, sampling
distributions, reweighting, products, mixtures, modes, persistence and errors."""

import math

import numpy as np
import pytest
import roma
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, stats

from vistask.se3 import SE3KDE, identity_poses, kernels, mixture, product, random_poses
from vistask.se3.kernels import log_quaternion_normalizer, quaternion_kappa


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _cluster(n: int, seed: int, spread: float = 0.03, dtype=torch.float64) -> torch.Tensor:
    """Poses within a few cm, orientations within ~0.5 rad of a common one."""
    g = _gen(seed)
    t = spread * torch.randn(n, 3, generator=g, dtype=dtype)
    q = roma.rotvec_to_unitquat(0.3 * torch.randn(n, 3, generator=g, dtype=dtype))
    return torch.cat([t, q], dim=1)


def _brute_force(
    density: SE3KDE, queries: torch.Tensor, cutoff: float | None = None
) -> torch.Tensor:
    """f(x) from the kernel definition, pair by pair, with (Q, N, .) intermediates."""
    p = density.points
    sq = ((queries[:, None, :3] - p[None, :, :3]) ** 2).sum(-1)
    dot = (queries[:, None, 3:] * p[None, :, 3:]).sum(-1).abs()
    rot = torch.exp(density.kappa * (dot - 1))
    if density.kernel == "gaussian":
        pos = torch.exp(-sq / (2 * density.sigma_t**2))
        if cutoff is not None:
            pos = pos * (sq.sqrt() <= cutoff * density.sigma_t)
    else:
        pos = (1 - sq.sqrt() / (2 * density.sigma_t)).clamp(min=0)
    return (pos * rot) @ density.weights


@pytest.mark.parametrize("kernel", ["gaussian", "triangular"])
def test_evaluate_matches_brute_force(kernel: str) -> None:
    particles = _cluster(300, 0)
    weights = torch.rand(300, generator=_gen(1), dtype=torch.float64)
    density = SE3KDE(particles, weights, sigma_t=0.02, sigma_r=0.4, kernel=kernel)
    queries = torch.cat([_cluster(50, 2), random_poses(10, 0.1, _gen(3), dtype=torch.float64)])
    expected = _brute_force(density, queries)
    torch.testing.assert_close(density.evaluate(queries), expected, rtol=1e-9, atol=1e-300)
    torch.testing.assert_close(density.evaluate(queries, chunk_size=7), expected)
    # Batched query shapes are kept.
    assert density.evaluate(queries.reshape(6, 10, 7)).shape == (6, 10)


def test_cutoff_grid_search_matches_truncated_brute_force() -> None:
    # Particles in two clumps 30 cm apart; queries near both, between them and far away.
    particles = torch.cat([_cluster(400, 4), _cluster(400, 5) + torch.tensor([0.3] + [0] * 6)])
    particles[:, 3:] = torch.nn.functional.normalize(particles[:, 3:], dim=1)
    density = SE3KDE(particles, sigma_t=0.01, sigma_r=0.3)
    queries = torch.cat(
        [
            _cluster(60, 6),
            _cluster(60, 7) + torch.tensor([0.15] + [0] * 6),
            random_poses(20, 1.0, _gen(8), dtype=torch.float64),
        ]
    )
    queries[:, 3:] = torch.nn.functional.normalize(queries[:, 3:], dim=1)
    for cutoff in (1.5, 3.0):
        got = density.evaluate(queries, cutoff=cutoff)
        torch.testing.assert_close(
            got, _brute_force(density, queries, cutoff), rtol=1e-9, atol=1e-30
        )
        # The neighbour search skipped most pairs.
        assert density.last_evaluated_pairs < 0.7 * len(queries) * len(density)
    # A generous cut-off changes the Gaussian density by a negligible amount.
    full = density.evaluate(queries)
    torch.testing.assert_close(
        density.evaluate(queries, cutoff=8.0), full, rtol=1e-9, atol=1e-12 * full.max().item()
    )


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from(["gaussian", "triangular"]))
def test_evaluation_invariant_under_quaternion_sign(seed: int, kernel: str) -> None:
    g = _gen(seed)
    particles, queries = _cluster(40, seed), _cluster(30, seed + 1)
    density = SE3KDE(particles, sigma_t=0.03, sigma_r=0.5, kernel=kernel)
    flip_p = torch.where(torch.rand(40, 1, generator=g) < 0.5, -1.0, 1.0).double()
    flip_q = torch.where(torch.rand(30, 1, generator=g) < 0.5, -1.0, 1.0).double()
    particles[:, 3:] *= flip_p
    queries_flipped = torch.cat([queries[:, :3], queries[:, 3:] * flip_q], dim=1)
    flipped = SE3KDE(particles, sigma_t=0.03, sigma_r=0.5, kernel=kernel)
    reference = density.evaluate(queries)
    torch.testing.assert_close(flipped.evaluate(queries_flipped), reference)
    torch.testing.assert_close(
        flipped.evaluate(queries_flipped, cutoff=2.0), density.evaluate(queries, cutoff=2.0)
    )


@settings(max_examples=10, deadline=None)
@given(st.floats(0.05, 3.0))
def test_orientation_normaliser_matches_quadrature(sigma_r: float) -> None:
    kappa = quaternion_kappa(sigma_r)
    # Over SO(3) = S^3 / ±: half of the S^3 integral with volume element 4 pi sin^2(a) da.
    integral, _ = integrate.quad(
        lambda a: 4 * math.pi * math.exp(kappa * (math.cos(a) - 1)) * math.sin(a) ** 2,
        0,
        math.pi / 2,
        points=[min(1.0, 5 / math.sqrt(kappa))],
    )
    assert log_quaternion_normalizer(kappa) == pytest.approx(math.log(integral), abs=1e-6)


@pytest.mark.parametrize("kernel", ["gaussian", "triangular"])
def test_normalised_density_integrates_to_one(kernel: str) -> None:
    """Importance sampling: positions from a wide Gaussian, rotations uniform on SO(3)."""
    particles = _cluster(3, 11, spread=0.02)
    density = SE3KDE(
        particles, torch.tensor([0.2, 0.3, 0.5]), sigma_t=0.02, sigma_r=0.8, kernel=kernel
    )
    g = _gen(12)
    n, scale = 400_000, 0.05
    t = scale * torch.randn(n, 3, generator=g, dtype=torch.float64)
    q = roma.random_unitquat(n, dtype=torch.float64, generator=g)
    proposal = stats.multivariate_normal(np.zeros(3), scale**2 * np.eye(3)).pdf(t.numpy())
    proposal = torch.from_numpy(proposal) / math.pi**2
    ratio = density.evaluate(torch.cat([t, q], 1), normalized=True) / proposal
    estimate, stderr = ratio.mean().item(), ratio.std().item() / math.sqrt(n)
    assert stderr < 0.02
    assert abs(estimate - 1) < 4 * stderr + 1e-3


def test_single_kernel_samples_match_kernel_density() -> None:
    sigma_t, sigma_r = 0.02, 0.5
    center = torch.tensor([[0.1, -0.2, 0.3, 0.0, 0.0, 0.6, 0.8]], dtype=torch.float64)
    density = SE3KDE(center, sigma_t=sigma_t, sigma_r=sigma_r)
    samples = density.sample(4000, generator=_gen(0))
    # Position: distance / sigma_t follows a chi distribution with 3 degrees of freedom.
    r = (samples[:, :3] - center[:, :3]).norm(dim=1).numpy()
    assert stats.kstest(r, stats.chi(3, scale=sigma_t).cdf).pvalue > 0.01
    # Orientation: half-angle a = acos|q.mu| in [0, pi/2] has density ∝ exp(kappa cos a) sin^2 a.
    kappa = density.kappa
    a = torch.acos((samples[:, 3:] @ center[0, 3:]).abs().clamp(max=1)).numpy()
    grid = np.linspace(0, np.pi / 2, 20001)
    cdf = integrate.cumulative_trapezoid(
        np.exp(kappa * (np.cos(grid) - 1)) * np.sin(grid) ** 2, grid, initial=0
    )
    cdf /= cdf[-1]
    assert stats.kstest(a, lambda x: np.interp(x, grid, cdf)).pvalue > 0.01
    # Both signs of the quaternion occur (q ~ -q), about equally often.
    positive = int((samples[:, 3:] @ center[0, 3:] > 0).sum())
    assert stats.binomtest(positive, 4000).pvalue > 0.01
    # The rotation axis of the offset is isotropic: its z-component is uniform on [-1, 1].
    rel = roma.quat_product(roma.quat_conjugation(center[:, 3:]).expand(4000, 4), samples[:, 3:])
    axis = torch.nn.functional.normalize(roma.unitquat_to_rotvec(rel), dim=1)
    assert stats.kstest(axis[:, 2].numpy(), stats.uniform(-1, 2).cdf).pvalue > 0.01


def test_triangular_samples_match_kernel() -> None:
    density = SE3KDE(identity_poses(1), sigma_t=0.05, sigma_r=0.3, kernel="triangular")
    r = density.sample(3000, generator=_gen(1))[:, :3].norm(dim=1).numpy()
    # Radius density ∝ r^2 (1 - r / (2 sigma)): r / (2 sigma) ~ Beta(3, 2).
    assert stats.kstest(r / 0.1, stats.beta(3, 2).cdf).pvalue > 0.01


def test_systematic_resampling_follows_weights() -> None:
    particles = torch.stack([identity_poses(), identity_poses()]).clone()
    particles[1, 0] = 1.0
    density = SE3KDE(particles, torch.tensor([0.3, 0.7]), sigma_t=0.01, sigma_r=0.3)
    samples = density.sample(1000, generator=_gen(2))
    near_second = int((samples[:, 0] > 0.5).sum())
    assert abs(near_second - 700) <= 1  # systematic resampling: off by at most one
    # The samples come in random order, not grouped by particle.
    assert 0.5 < (samples[:500, 0] > 0.5).float().mean() < 0.9


def test_importance_reweighting_recovers_target_mean() -> None:
    g = _gen(3)
    n = 20_000
    t = 0.1 * torch.randn(n, 3, generator=g, dtype=torch.float64)
    proposal_particles = torch.cat(
        [t, roma.random_unitquat(n, dtype=torch.float64, generator=g)], 1
    )
    proposal = SE3KDE(proposal_particles, sigma_t=0.01, sigma_r=0.3)
    target_mean = torch.tensor([0.05, -0.02, 0.0], dtype=torch.float64)

    def gaussian(mean: torch.Tensor, std: float):
        return lambda x: torch.exp(-((x[:, :3] - mean) ** 2).sum(1) / (2 * std**2)) / std**3

    reweighted = proposal.reweight(
        gaussian(target_mean, 0.03), proposal=gaussian(torch.zeros(3), 0.1)
    )
    torch.testing.assert_close(reweighted.mean()[:3], target_mean, atol=3e-3, rtol=0)
    assert reweighted.effective_sample_size() < 0.5 * n
    # Reweighting by a density uses its evaluate().
    target = SE3KDE(
        torch.cat([target_mean, torch.tensor([0, 0, 0, 1.0])])[None], sigma_t=0.03, sigma_r=3.0
    )
    by_density = proposal.reweight(target)
    assert (by_density.mean()[:3] - target_mean).norm() < 0.03


def test_product_of_two_kernels_is_between_them() -> None:
    a = SE3KDE(identity_poses(1), sigma_t=0.02, sigma_r=0.5)
    shifted = identity_poses(1)
    shifted[0, 0] = 0.04
    b = SE3KDE(shifted, sigma_t=0.02, sigma_r=0.5)
    prod = product([a, b], 20_000, generator=_gen(4))
    assert len(prod) == 20_000
    # Gaussian x Gaussian with equal widths: the product's mean is the midpoint.
    assert prod.mean()[0].item() == pytest.approx(0.02, abs=1.5e-3)
    assert prod.sigma_t == a.sigma_t


def test_mixture_evaluates_to_weighted_sum() -> None:
    a = SE3KDE(_cluster(20, 5), sigma_t=0.03, sigma_r=0.4)
    b = SE3KDE(_cluster(30, 6), torch.rand(30, generator=_gen(7)), sigma_t=0.03, sigma_r=0.4)
    mix = mixture([a, b], [1.0, 3.0])
    queries = _cluster(25, 8)
    torch.testing.assert_close(
        mix.evaluate(queries), 0.25 * a.evaluate(queries) + 0.75 * b.evaluate(queries)
    )
    with pytest.raises(ValueError, match="bandwidth"):
        mixture([a, SE3KDE(_cluster(5, 9), sigma_t=0.5, sigma_r=0.4)])


def test_modes_find_both_clusters_heaviest_first() -> None:
    offset = torch.tensor([0.3, 0, 0, 0, 0, 0, 0], dtype=torch.float64)
    heavy, light = _cluster(300, 10, spread=0.01), _cluster(300, 11, spread=0.01) + offset
    light[:, 3:] = roma.quat_product(
        torch.tensor([0.0, 1.0, 0.0, 0.0], dtype=torch.float64).expand(300, 4), light[:, 3:]
    )
    weights = torch.cat([torch.full((300,), 0.7), torch.full((300,), 0.3)])
    density = SE3KDE(torch.cat([heavy, light]), weights, sigma_t=0.01, sigma_r=0.3)
    modes, values = density.modes(k=2, generator=_gen(12))
    assert modes.shape == (2, 7) and values[0] >= values[1]
    assert modes[0, 0].abs() < 0.02 and (modes[1, 0] - 0.3).abs() < 0.02
    assert density.mode(generator=_gen(12))[0].abs() < 0.02


def test_moments_and_effective_sample_size() -> None:
    particles = _cluster(500, 13, spread=0.01)
    density = SE3KDE(particles, sigma_t=0.01, sigma_r=0.3)
    m = density.moments()
    torch.testing.assert_close(m["mean"][:3], particles[:, :3].mean(0))
    torch.testing.assert_close(
        m["position_covariance"], torch.cov(particles[:, :3].T, correction=0)
    )
    # The mean orientation is near the identity the cluster was drawn around, either sign.
    assert m["mean"][6].abs() > 0.98
    assert density.effective_sample_size() == pytest.approx(500)
    weighted = SE3KDE(
        particles, torch.cat([torch.ones(100), torch.zeros(400)]), sigma_t=0.01, sigma_r=0.3
    )
    assert weighted.effective_sample_size() == pytest.approx(100)


def test_save_load_round_trip(tmp_path) -> None:
    density = SE3KDE(
        _cluster(50, 14),
        torch.rand(50, generator=_gen(15)),
        sigma_t=0.02,
        sigma_r=0.35,
        kernel="triangular",
    )
    path = tmp_path / "density.pt"
    density.save(path)
    loaded = SE3KDE.load(path)
    assert (loaded.sigma_t, loaded.sigma_r, loaded.kernel, len(loaded)) == (
        0.02,
        0.35,
        "triangular",
        50,
    )
    queries = _cluster(20, 16)
    torch.testing.assert_close(loaded.evaluate(queries), density.evaluate(queries))
    torch.testing.assert_close(density.to("cpu").evaluate(queries), density.evaluate(queries))


def test_clear_errors() -> None:
    good = _cluster(5, 17)
    bad_quat = good.clone()
    bad_quat[0, 3:] *= 1.5
    with pytest.raises(ValueError, match="unit"):
        SE3KDE(bad_quat, sigma_t=0.01, sigma_r=0.3)
    density = SE3KDE(good, sigma_t=0.01, sigma_r=0.3)
    with pytest.raises(ValueError, match="unit"):
        density.evaluate(bad_quat)
    with pytest.raises(ValueError, match="shape"):
        SE3KDE(good[:, :6], sigma_t=0.01, sigma_r=0.3)
    with pytest.raises(ValueError, match="shape"):
        density.evaluate(good[:, :4])
    with pytest.raises(ValueError, match="must not all be zero"):
        SE3KDE(good, torch.zeros(5), sigma_t=0.01, sigma_r=0.3)
    with pytest.raises(ValueError, match="non-negative"):
        SE3KDE(good, torch.tensor([1.0, -1, 1, 1, 1]), sigma_t=0.01, sigma_r=0.3)
    with pytest.raises(ValueError, match=r"shape \(5,\)"):
        SE3KDE(good, torch.ones(4), sigma_t=0.01, sigma_r=0.3)
    with pytest.raises(ValueError, match="sigma_t"):
        SE3KDE(good, sigma_t=0.0, sigma_r=0.3)
    with pytest.raises(ValueError, match="sigma_r"):
        SE3KDE(good, sigma_t=0.01, sigma_r=-1.0)
    with pytest.raises(ValueError, match="kernel"):
        SE3KDE(good, sigma_t=0.01, sigma_r=0.3, kernel="epanechnikov")
    with pytest.raises(ValueError, match="cutoff"):
        density.evaluate(good, cutoff=0.0)
    with pytest.raises(ValueError, match="at least one"):
        SE3KDE(good[:0], sigma_t=0.01, sigma_r=0.3)
    with pytest.raises(ValueError, match="not a SE3KDE"):
        from vistask.se3 import R3S2KDE

        path = "/tmp/_vistask_se3_wrong_type.pt"
        R3S2KDE(torch.tensor([[0.0, 0, 0, 0, 0, 1]]), sigma_t=0.1, sigma_r=0.1).save(path)
        SE3KDE.load(path)


def _difference_form(points: torch.Tensor, queries: torch.Tensor, sigma_t: float, kappa: float):
    """Unnormalised float64 density, 1 - |q . q_i| taken as min(|q - q_i|^2, |q + q_i|^2) / 2."""
    p, x = points.double(), queries.double()
    qp = torch.nn.functional.normalize(p[:, 3:], dim=-1)
    qx = torch.nn.functional.normalize(x[:, 3:], dim=-1)
    d2 = ((x[:, None, :3] - p[None, :, :3]) ** 2).sum(-1)
    minus = ((qx[:, None] - qp[None]) ** 2).sum(-1)
    plus = ((qx[:, None] + qp[None]) ** 2).sum(-1)
    one_minus_dot = torch.minimum(minus, plus) / 2
    return (torch.exp(-d2 / (2 * sigma_t**2) - kappa * one_minus_dot)).mean(dim=1)


@settings(max_examples=40, deadline=None)
@given(
    log_sigma_t=st.floats(math.log10(kernels.SIGMA_T_MIN), 0.0),
    log_sigma_r=st.floats(math.log10(kernels.SIGMA_R_MIN), math.log10(2 * math.pi)),
    scale=st.sampled_from([0.01, 0.1, 1.0]),
    seed=st.integers(0, 1000),
)
def test_float32_density_at_kernel_centres_keeps_its_precision(
    log_sigma_t, log_sigma_r, scale, seed
):
    sigma_t, sigma_r = 10**log_sigma_t, 10**log_sigma_r
    points = random_poses(
        30, translation_scale=scale, generator=torch.Generator().manual_seed(seed)
    )
    density = SE3KDE(points, sigma_t=sigma_t, sigma_r=sigma_r)
    expected = _difference_form(points, points, sigma_t, density.kappa)
    for cutoff in (None, 13.0):  # 13 sigma: truncated pairs weigh exp(-84.5), below float32
        got = density.evaluate(points, cutoff=cutoff).double()
        torch.testing.assert_close(got, expected, rtol=1e-4, atol=0.0)


def test_far_float32_kernels_times_particle_weights_stay_normal_numbers():
    # Denormal floats are ~30x slower on CPU: a mean-shift step over weighted far kernels
    # (their product with the weights) must not produce them.
    density = SE3KDE(random_poses(2000, 0.05, generator=_gen(0)))
    far = random_poses(32, 10.0, generator=_gen(1))
    products = density.kernel_matrix(far) * density.weights
    assert not ((products > 0) & (products < torch.finfo(torch.float32).tiny)).any()
    assert products.max() < 1e-20  # and far kernels still weigh nothing


@pytest.mark.parametrize(
    ("sigma_t", "sigma_r", "name"),
    [
        (1e-20, 0.3, "sigma_t"),
        (0.01, 1e-9, "sigma_r"),
        (float("nan"), 0.3, "sigma_t"),
        (0.01, 7.0, "sigma_r"),
    ],
)
def test_bandwidths_float_precision_cannot_hold_are_refused(sigma_t, sigma_r, name):
    with pytest.raises(ValueError, match=f"{name} must be .* got"):
        SE3KDE(random_poses(3), sigma_t=sigma_t, sigma_r=sigma_r)
