"""R3S2KDE (position + axial direction) and the projection SE(3) -> R^3 x S^2."""

import math

import numpy as np
import pytest
import roma
import torch
from scipy import stats

from vistask.se3 import R3S2KDE, SE3KDE, project_se3_to_r3s2, random_poses


def _gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _edges(n: int, seed: int) -> torch.Tensor:
    g = _gen(seed)
    t = 0.02 * torch.randn(n, 3, generator=g, dtype=torch.float64)
    v = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64) + 0.3 * torch.randn(
        n, 3, generator=g, dtype=torch.float64
    )
    return torch.cat([t, torch.nn.functional.normalize(v, dim=1)], dim=1)


def test_projection_takes_a_rotation_column() -> None:
    poses = random_poses(20, 1.0, _gen(0), dtype=torch.float64)
    rotmat = roma.unitquat_to_rotmat(poses[:, 3:])
    for axis in range(3):
        projected = project_se3_to_r3s2(poses, axis)
        torch.testing.assert_close(projected[:, :3], poses[:, :3])
        torch.testing.assert_close(projected[:, 3:], rotmat[:, :, axis])
    with pytest.raises(ValueError, match="axis"):
        project_se3_to_r3s2(poses, 3)


def test_se3_density_projects_to_r3s2_density() -> None:
    poses = random_poses(30, 0.05, _gen(1), dtype=torch.float64)
    density = SE3KDE(poses, torch.rand(30, generator=_gen(2)), sigma_t=0.02, sigma_r=0.4)
    projected = R3S2KDE.from_se3(density, axis=1)
    assert isinstance(projected, R3S2KDE) and projected.sigma_r == 0.4
    torch.testing.assert_close(projected.points, project_se3_to_r3s2(poses, 1))
    torch.testing.assert_close(projected.weights, density.weights)


def test_evaluate_is_axial_and_matches_definition() -> None:
    particles, queries = _edges(50, 3), _edges(20, 4)
    density = R3S2KDE(particles, sigma_t=0.02, sigma_r=0.3)
    kappa = 1 / (1 - math.cos(0.3))
    sq = ((queries[:, None, :3] - particles[None, :, :3]) ** 2).sum(-1)
    dot = (queries[:, None, 3:] * particles[None, :, 3:]).sum(-1).abs()
    expected = (torch.exp(-sq / (2 * 0.02**2) + kappa * (dot - 1))).mean(1)
    torch.testing.assert_close(density.evaluate(queries), expected)
    flipped = torch.cat([queries[:, :3], -queries[:, 3:]], dim=1)
    torch.testing.assert_close(density.evaluate(flipped), expected)
    torch.testing.assert_close(density.evaluate(queries, cutoff=10.0), expected)


@pytest.mark.parametrize("sigma_r", [0.2, 1.0])
def test_normalised_density_integrates_to_one(sigma_r: float) -> None:
    """Directions uniform on S^2 (S^2 / ± has area 2 pi), positions from a wide Gaussian."""
    density = R3S2KDE(_edges(3, 5), sigma_t=0.02, sigma_r=sigma_r)
    g = _gen(6)
    n, scale = 400_000, 0.05
    t = scale * torch.randn(n, 3, generator=g, dtype=torch.float64)
    v = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64), dim=1)
    proposal = torch.from_numpy(
        stats.multivariate_normal(np.zeros(3), scale**2 * np.eye(3)).pdf(t.numpy())
    )
    ratio = density.evaluate(torch.cat([t, v], 1), normalized=True) / (proposal / (2 * math.pi))
    estimate, stderr = ratio.mean().item(), ratio.std().item() / math.sqrt(n)
    assert stderr < 0.03
    assert abs(estimate - 1) < 4 * stderr + 1e-3


def test_single_kernel_direction_samples() -> None:
    mu = torch.tensor([0.0, 0.6, 0.8], dtype=torch.float64)
    density = R3S2KDE(
        torch.cat([torch.zeros(3, dtype=torch.float64), mu])[None], sigma_t=0.01, sigma_r=0.4
    )
    samples = density.sample(4000, generator=_gen(7))
    assert torch.allclose(samples[:, 3:].norm(dim=1), torch.ones(4000, dtype=torch.float64))
    # w = |v . mu| on [0, 1] has density ∝ exp(kappa w): CDF (e^{kappa w} - 1) / (e^kappa - 1).
    kappa = density.kappa
    w = (samples[:, 3:] @ mu).abs().numpy()
    assert stats.kstest(w, lambda x: np.expm1(kappa * x) / np.expm1(kappa)).pvalue > 0.01
    positive = int((samples[:, 3:] @ mu > 0).sum())
    assert stats.binomtest(positive, 4000).pvalue > 0.01
    r = samples[:, :3].norm(dim=1).numpy()
    assert stats.kstest(r, stats.chi(3, scale=0.01).cdf).pvalue > 0.01


def test_save_load_and_errors(tmp_path) -> None:
    density = R3S2KDE(_edges(10, 8), sigma_t=0.02, sigma_r=0.3)
    density.save(tmp_path / "edges.pt")
    loaded = R3S2KDE.load(tmp_path / "edges.pt")
    queries = _edges(5, 9)
    torch.testing.assert_close(loaded.evaluate(queries), density.evaluate(queries))
    with pytest.raises(ValueError, match="unit"):
        R3S2KDE(torch.tensor([[0.0, 0, 0, 0, 0, 3.0]]), sigma_t=0.1, sigma_r=0.1)
    with pytest.raises(ValueError, match="shape"):
        density.evaluate(torch.zeros(4, 7))
    with pytest.raises(ValueError, match="must not all be zero"):
        R3S2KDE(_edges(3, 1), torch.zeros(3), sigma_t=0.1, sigma_r=0.1)
