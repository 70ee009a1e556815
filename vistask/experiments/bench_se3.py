"""Throughput benchmark of SE(3) kernel density evaluation (used by scripts/bench_se3.py)."""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable

import numpy as np
import roma
import torch

from vistask.se3.kde import SE3KDE


def synthetic_grasp_poses(
    n: int,
    generator: torch.Generator | None = None,
    radius: float = 0.04,
    height: float = 0.10,
    standoff: float = 0.02,
) -> torch.Tensor:
    """(n, 7) gripper poses around a mug-sized cylinder, shaped like a learned grasp density.

    Positions lie on a cylinder ``standoff`` outside the object's side (5 mm noise); the
    approach axis (gripper z) points at the object's axis, and the closing axis is vertical or
    horizontal (two grasp families), with 0.1 rad orientation noise.
    """
    g = generator
    azimuth = 2 * math.pi * torch.rand(n, generator=g)
    z = height * torch.rand(n, generator=g)
    radial = torch.stack([azimuth.cos(), azimuth.sin(), torch.zeros(n)], dim=1)
    t = (radius + standoff) * radial + z[:, None] * torch.tensor([0.0, 0.0, 1.0])
    t = t + 0.005 * torch.randn(n, 3, generator=g)
    approach = -radial
    vertical = torch.tensor([0.0, 0.0, 1.0]).expand(n, 3)
    tangent = torch.cross(approach, vertical, dim=1)
    family = torch.rand(n, 1, generator=g) < 0.5
    closing = torch.where(family, vertical, tangent)
    rotmat = torch.stack([closing, torch.cross(approach, closing, dim=1), approach], dim=2)
    noise = roma.rotvec_to_unitquat(0.1 * torch.randn(n, 3, generator=g))
    q = roma.quat_product(roma.rotmat_to_unitquat(rotmat), noise)
    return torch.cat([t, q], dim=1)


def numpy_loop_density(
    queries: np.ndarray, particles: np.ndarray, weights: np.ndarray, sigma_t: float, kappa: float
) -> np.ndarray:
    """Reference: one query at a time, vectorised over particles, in NumPy."""
    out = np.empty(len(queries), dtype=queries.dtype)
    tp, qp = particles[:, :3], particles[:, 3:]
    for i, x in enumerate(queries):
        sq = ((tp - x[:3]) ** 2).sum(axis=1)
        log_k = -sq / (2 * sigma_t**2) + kappa * (np.abs(qp @ x[3:]) - 1)
        out[i] = weights @ np.exp(log_k)
    return out


def eager_torch_density(density: SE3KDE, queries: torch.Tensor, chunk: int = 64) -> torch.Tensor:
    """Reference: straightforward broadcasting torch with (chunk, N, 3) intermediates."""
    tp, qp, w = density.points[:, :3], density.points[:, 3:], density.weights
    out = []
    for a in range(0, len(queries), chunk):
        x = queries[a : a + chunk]
        sq = ((x[:, None, :3] - tp[None]) ** 2).sum(-1)
        dots = (x[:, None, 3:] * qp[None]).sum(-1).abs()
        out.append(torch.exp(-sq / (2 * density.sigma_t**2) + density.kappa * (dots - 1)) @ w)
    return torch.cat(out)


def _times(fn: Callable[[], object], repeats: int, sync: Callable[[], None]) -> list[float]:
    fn()
    sync()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - start)
    return times


def run_benchmark(
    device: str = "cpu",
    dense_queries: int = 1000,
    dense_particles: int = 10_000,
    cutoff_queries: int = 10_000,
    cutoff_particles: int = 100_000,
    sigma_t: float = 0.01,
    sigma_r: float = 0.3,
    cutoff: float = 3.0,
    repeats: int = 5,
    numpy_queries: int = 200,
    seed: int = 0,
) -> dict[str, float]:
    """Measure kernel-pair throughput of dense and cut-off evaluation on one device.

    Dense: random poses (5 cm spread). Cut-off: ``synthetic_grasp_poses`` particles and queries
    drawn from the same distribution. Times are medians over ``repeats`` runs after a warm-up.

    Returns:
        figures keyed as in summary.json (pairs per second, times, agreement errors).
    """
    dev = torch.device(device)
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    g = torch.Generator().manual_seed(seed)
    res: dict[str, float] = {"threads": torch.get_num_threads()}

    particles = _random_poses(dense_particles, g)
    queries = _random_poses(dense_queries, g)
    density = SE3KDE(particles, sigma_t=sigma_t, sigma_r=sigma_r, device=dev)
    q_dev = queries.to(dev)
    t_dense = _times(lambda: density.evaluate(q_dev), repeats, sync)
    pairs = dense_queries * dense_particles
    res["dense_pairs_per_s"] = pairs / statistics.median(t_dense)
    res["dense_best_pairs_per_s"] = pairs / min(t_dense)
    values = density.evaluate(q_dev).cpu()

    if dev.type == "cpu":
        nq = min(numpy_queries, dense_queries)
        args = (
            queries[:nq].numpy(),
            particles.numpy(),
            density.weights.numpy(),
            sigma_t,
            density.kappa,
        )
        t_np = _times(lambda: numpy_loop_density(*args), max(1, repeats // 2), sync)
        res["numpy_pairs_per_s"] = nq * dense_particles / statistics.median(t_np)
        res["speedup_vs_numpy"] = res["dense_pairs_per_s"] / res["numpy_pairs_per_s"]
        ref = torch.from_numpy(numpy_loop_density(*args))
        res["dense_max_rel_error_vs_numpy"] = float((values[:nq] - ref).abs().max() / ref.max())
        t_eager = _times(lambda: eager_torch_density(density, q_dev[:nq]), 1, sync)
        res["eager_torch_pairs_per_s"] = nq * dense_particles / min(t_eager)

    grasp = SE3KDE(
        synthetic_grasp_poses(cutoff_particles, g), sigma_t=sigma_t, sigma_r=sigma_r, device=dev
    )
    grasp_queries = synthetic_grasp_poses(cutoff_queries, g).to(dev)
    t_cut = _times(lambda: grasp.evaluate(grasp_queries, cutoff=cutoff), repeats, sync)
    pairs = cutoff_queries * cutoff_particles
    res["cutoff_effective_pairs_per_s"] = pairs / statistics.median(t_cut)
    res["cutoff_best_effective_pairs_per_s"] = pairs / min(t_cut)
    res["cutoff_seconds"] = statistics.median(t_cut)
    res["cutoff_evaluated_pair_fraction"] = grasp.last_evaluated_pairs / pairs
    # Check the truncation on a query subset against dense evaluation of every pair.
    sub = grasp_queries[:500]
    dense_sub = grasp.evaluate(sub)
    cut_sub = grasp.evaluate(sub, cutoff=cutoff)
    res["cutoff_max_rel_error_vs_dense"] = float(((cut_sub - dense_sub).abs() / dense_sub).max())
    res["cutoff_particles"], res["cutoff_queries"], res["cutoff"] = (
        cutoff_particles,
        cutoff_queries,
        cutoff,
    )
    return res


def _random_poses(n: int, g: torch.Generator) -> torch.Tensor:
    return torch.cat(
        [0.05 * torch.randn(n, 3, generator=g), roma.random_unitquat(n, generator=g)], 1
    )
