"""Bandwidth selection: rule of thumb and leave-one-out likelihood cross-validation."""

import math

import pytest
import roma
import torch

from vistask.se3 import (
    R3S2KDE,
    SE3KDE,
    cross_validate_bandwidth,
    fit_density,
    project_se3_to_r3s2,
    rule_of_thumb_bandwidth,
    select_bandwidth,
)


def _samples(n: int, seed: int, spread_t: float, spread_r: float) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    t = spread_t * torch.randn(n, 3, generator=g, dtype=torch.float64)
    q = roma.rotvec_to_unitquat(spread_r * torch.randn(n, 3, generator=g, dtype=torch.float64))
    return torch.cat([t, q], dim=1)


def test_rule_of_thumb_follows_the_spread() -> None:
    narrow = _samples(500, 0, 0.01, 0.1)
    wide = narrow.clone()
    wide[:, :3] *= 3
    st_narrow, sr_narrow = rule_of_thumb_bandwidth(narrow)
    st_wide, sr_wide = rule_of_thumb_bandwidth(wide)
    assert st_wide == pytest.approx(3 * st_narrow)
    assert sr_wide == pytest.approx(sr_narrow)
    _, sr_rot = rule_of_thumb_bandwidth(_samples(500, 0, 0.01, 0.3))
    assert sr_rot > 2 * sr_narrow
    # More particles, smaller bandwidth.
    assert rule_of_thumb_bandwidth(_samples(5000, 1, 0.01, 0.1))[0] < st_narrow
    # Works on R^3 x S^2 points too.
    st_edge, sr_edge = rule_of_thumb_bandwidth(project_se3_to_r3s2(narrow, 2))
    assert st_edge > 0 and 0 < sr_edge < math.pi


def test_cross_validation_picks_the_held_out_best() -> None:
    train, test = _samples(300, 2, 0.02, 0.2), _samples(300, 3, 0.02, 0.2)
    grid_t = [0.002, 0.005, 0.01, 0.02, 0.05]
    grid_r = [0.05, 0.1, 0.2, 0.4, 0.8]
    sigma_t, sigma_r, scores = cross_validate_bandwidth(
        train, sigma_t_grid=grid_t, sigma_r_grid=grid_r
    )
    assert scores.shape == (5, 5) and torch.isfinite(scores).all()
    held_out = torch.tensor(
        [
            [
                SE3KDE(train, sigma_t=a, sigma_r=b)
                .evaluate(test, normalized=True)
                .log()
                .mean()
                .item()
                for b in grid_r
            ]
            for a in grid_t
        ]
    )
    best_t, best_r = divmod(int(held_out.argmax()), len(grid_r))
    assert abs(grid_t.index(sigma_t) - best_t) <= 1 and abs(grid_r.index(sigma_r) - best_r) <= 1
    # Extreme bandwidths score worse than the chosen one.
    assert scores[0, 0] < scores.max() and scores[-1, -1] < scores.max()


def test_fit_and_errors() -> None:
    samples = _samples(200, 4, 0.02, 0.2)
    density = fit_density(samples, method="cv", max_points=100)
    assert isinstance(density, SE3KDE) and density.sigma_t > 0
    edges = fit_density(project_se3_to_r3s2(samples, 0))
    assert isinstance(edges, R3S2KDE)
    with pytest.raises(ValueError, match="method"):
        select_bandwidth(samples, method="silverman")
    with pytest.raises(ValueError, match="spread"):
        rule_of_thumb_bandwidth(samples[:1].expand(5, 7))
    with pytest.raises(ValueError, match="N, 7"):
        rule_of_thumb_bandwidth(torch.zeros(5, 4))
