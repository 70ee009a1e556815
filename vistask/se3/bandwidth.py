"""Bandwidth selection for SE(3) and R^3 x S^2 kernel densities.

The space is read from the points' last dimension: 7 (poses) or 6 (position + axial direction).
"""

from __future__ import annotations

import math

import torch

from vistask.checks import check_at_least, checked
from vistask.se3 import kernels
from vistask.se3.kde import SE3KDE, KernelDensity
from vistask.se3.r3s2 import R3S2KDE

DEFAULT_FACTORS = (0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0)


def _space(points: torch.Tensor) -> type[KernelDensity]:
    if not isinstance(points, torch.Tensor) or points.shape[-1:] not in ((7,), (6,)):
        shape = tuple(points.shape) if isinstance(points, torch.Tensor) else type(points).__name__
        raise ValueError(f"points must be (N, 7) poses or (N, 6) [t, v] points, got {shape}")
    return SE3KDE if points.shape[-1] == 7 else R3S2KDE


@checked
def rule_of_thumb_bandwidth(
    points: torch.Tensor, weights: torch.Tensor | None = None
) -> tuple[float, float]:
    """Scott-like bandwidth from the particle spread.

    sigma_t = n_eff^(-1/(d+4)) * (per-axis position std), and the same factor on the per-axis
    angular spread about the mean axis, converted to the kernel's exp(-angle^2 / sigma_r^2)
    scale (per-axis kernel std sigma_r / sqrt 2). d = 6 on SE(3), 5 on R^3 x S^2.

    Args:
        points: (N, 7) poses or (N, 6) [t, v] points.
        weights: (N,) non-negative weights or None.

    Returns:
        (sigma_t, sigma_r).
    """
    space = _space(points)
    points = space.check_points(points, "points", batched=True)
    w = kernels.normalise_weights(weights, points).double()
    t, u = points[:, :3].double(), points[:, 3:].double()
    n_eff = 1.0 / float((w**2).sum())
    rot_dims = 3 if space is SE3KDE else 2
    factor = n_eff ** (-1.0 / (3 + rot_dims + 4))
    centred = t - w @ t
    spread_t = math.sqrt(float(w @ (centred**2).sum(1)) / 3.0)
    angles = space.direction_angle(u, kernels.principal_axis(u, w)[None, :])
    spread_r = math.sqrt(float(w @ angles**2) / rot_dims)
    if spread_t <= 0 or spread_r <= 0:
        raise ValueError(
            f"points must spread in position and direction for the rule of thumb, got "
            f"{len(t)} particle(s) with spreads {spread_t:.3g} m and {spread_r:.3g} rad"
        )
    sigma_t = factor * spread_t
    sigma_r = min(max(math.sqrt(2.0) * factor * spread_r, 1e-3), math.pi)
    return sigma_t, sigma_r


@checked
def cross_validate_bandwidth(
    points: torch.Tensor,
    weights: torch.Tensor | None = None,
    sigma_t_grid: torch.Tensor | list[float] | None = None,
    sigma_r_grid: torch.Tensor | list[float] | None = None,
    max_points: int = 1000,
    generator: torch.Generator | None = None,
) -> tuple[float, float, torch.Tensor]:
    """Leave-one-out likelihood cross-validation over a grid of Gaussian-kernel bandwidths.

    Maximises sum_i w_i log f_{-i}(x_i), where f_{-i} is the normalised density of all other
    particles (weights renormalised), over sigma_t_grid x sigma_r_grid.

    Args:
        points: (N, 7) poses or (N, 6) [t, v] points.
        weights: (N,) weights or None.
        sigma_t_grid, sigma_r_grid: candidate bandwidths (default: the rule of thumb times
            0.25 ... 2).
        max_points: random subset size used when N is larger (pairwise cost is N^2).
        generator: random generator for the subset.

    Returns:
        (sigma_t, sigma_r, scores) with scores (T, R) the mean held-out log-likelihood.
    """
    space = _space(points)
    points = space.check_points(points, "points", batched=True)
    w = kernels.normalise_weights(weights, points)
    if points.shape[0] < 2:
        raise ValueError("cross-validation needs at least 2 particles")
    if sigma_t_grid is None or sigma_r_grid is None:
        st, sr = rule_of_thumb_bandwidth(points, w)
        if sigma_t_grid is None:
            sigma_t_grid = [st * f for f in DEFAULT_FACTORS]
        if sigma_r_grid is None:
            sigma_r_grid = [min(sr * f, math.pi) for f in DEFAULT_FACTORS]
    grid_t = [float(s) for s in sigma_t_grid]
    grid_r = [float(s) for s in sigma_r_grid]
    for name, grid in (("sigma_t_grid", grid_t), ("sigma_r_grid", grid_r)):
        if not grid or not all(math.isfinite(s) and s > 0 for s in grid):
            raise ValueError(f"{name} must hold finite bandwidths > 0, got {grid}")
    check_at_least(2, max_points=max_points)
    if points.shape[0] > max_points:
        keep = torch.randperm(points.shape[0], generator=generator)[:max_points]
        points, w = points[keep.to(points.device)], w[keep.to(points.device)]
    x, w = points.double(), (w / w.sum()).double()
    t, u = x[:, :3], x[:, 3:]
    sq_dist = torch.cdist(t, t).square()
    abs_dot = (u @ u.T).abs().clamp(max=1.0)
    log_w = torch.log(w)[None, :].expand(len(w), -1).clone()
    log_w.fill_diagonal_(-math.inf)
    # Held-out weights sum to 1 - w_i.
    log_rest = torch.log1p(-w.clamp(max=1 - 1e-12))
    scores = torch.empty(len(grid_t), len(grid_r), dtype=torch.float64)
    for a, st in enumerate(grid_t):
        log_pos = -sq_dist / (2 * st**2) - 1.5 * math.log(2 * math.pi * st**2)
        for b, sr in enumerate(grid_r):
            kappa = space.kappa_from_sigma(sr)
            log_k = log_pos + kappa * (abs_dot - 1) - space.log_direction_normalizer(kappa)
            loo = torch.logsumexp(log_k + log_w, dim=1) - log_rest
            scores[a, b] = w @ loo
    best = int(torch.argmax(scores))
    return grid_t[best // len(grid_r)], grid_r[best % len(grid_r)], scores


@checked
def select_bandwidth(
    points: torch.Tensor,
    weights: torch.Tensor | None = None,
    method: str = "rule",
    sigma_t_grid: torch.Tensor | list[float] | None = None,
    sigma_r_grid: torch.Tensor | list[float] | None = None,
    max_points: int = 1000,
    generator: torch.Generator | None = None,
) -> tuple[float, float]:
    """(sigma_t, sigma_r) by the rule of thumb (``method="rule"``) or cross-validation ("cv").

    Args:
        points: (N, 7) poses or (N, 6) [t, v] points.
        weights: (N,) weights or None.
        method: "rule" (``rule_of_thumb_bandwidth``) or "cv" (``cross_validate_bandwidth``).
        sigma_t_grid, sigma_r_grid, max_points, generator: cross-validation settings (see
            ``cross_validate_bandwidth``); unused by the rule of thumb.
    """
    if method == "rule":
        cv_only = {"sigma_t_grid": sigma_t_grid, "sigma_r_grid": sigma_r_grid}
        cv_only["max_points"] = None if max_points == 1000 else max_points
        for name, value in cv_only.items():
            if value is not None:
                raise ValueError(f"{name} acts only with method='cv', not {method!r}")
        return rule_of_thumb_bandwidth(points, weights)
    if method == "cv":
        sigma_t, sigma_r, _ = cross_validate_bandwidth(
            points, weights, sigma_t_grid, sigma_r_grid, max_points, generator
        )
        return sigma_t, sigma_r
    raise ValueError(f"method must be 'rule' or 'cv', got {method!r}")


@checked
def fit_density(
    points: torch.Tensor,
    weights: torch.Tensor | None = None,
    method: str = "rule",
    kernel: str = "gaussian",
    sigma_t_grid: torch.Tensor | list[float] | None = None,
    sigma_r_grid: torch.Tensor | list[float] | None = None,
    max_points: int = 1000,
    generator: torch.Generator | None = None,
) -> SE3KDE | R3S2KDE:
    """A density of ``points`` with its bandwidth chosen by ``select_bandwidth``.

    Args:
        points: (N, 7) poses (gives an ``SE3KDE``) or (N, 6) [t, v] points (an ``R3S2KDE``).
        weights: (N,) weights or None.
        method: "rule" or "cv" (see ``select_bandwidth``).
        kernel: position kernel of the density, "gaussian" or "triangular".
        sigma_t_grid, sigma_r_grid, max_points, generator: cross-validation settings.
    """
    sigma_t, sigma_r = select_bandwidth(
        points, weights, method, sigma_t_grid, sigma_r_grid, max_points, generator
    )
    return _space(points)(points, weights, sigma_t, sigma_r, kernel=kernel)
