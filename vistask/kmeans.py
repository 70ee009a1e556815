"""Nearest centroids and Lloyd's k-means in torch, for visual vocabularies: thousands of
centroids over tens of thousands of descriptors, where scipy's k-means is too slow."""

from __future__ import annotations

import torch


def _chunk_rows(n_centroids: int) -> int:
    """Rows per block of a (rows, F) distance matrix: about 4M entries, small enough to stay
    in cache-friendly memory (an 8192 x 8192 block made matching 1.6x slower)."""
    return max(64, (1 << 22) // max(n_centroids, 1))


def nearest_centroids(
    x: torch.Tensor, centroids: torch.Tensor, k: int = 1, c_sq: torch.Tensor | None = None
):
    """K nearest centroids of each row of x (M, D), nearest first; ``c_sq`` (C,) are the
    centroids' squared norms when the caller has them.

    Returns (indices (M, k), squared distances (M, k)).
    """
    if c_sq is None:
        c_sq = (centroids * centroids).sum(1)
    index = torch.empty(len(x), k, dtype=torch.long, device=x.device)
    dist = torch.empty(len(x), k, dtype=x.dtype, device=x.device)
    chunk = _chunk_rows(len(centroids))
    for s in range(0, len(x), chunk):
        block = x[s : s + chunk]
        # ||x - c||^2 = ||x||^2 - 2 x.c + ||c||^2; ||x||^2 does not change the order.
        d = torch.addmm(c_sq, block, centroids.T, alpha=-2.0)
        best, index[s : s + chunk] = d.min(1, keepdim=True) if k == 1 else d.topk(k, largest=False)
        dist[s : s + chunk] = (best + (block * block).sum(1, keepdim=True)).clamp_min_(0)
    return index, dist


def kmeans(x: torch.Tensor, k: int, iters: int = 20, seed: int = 0) -> torch.Tensor:
    """Lloyd's k-means from k random points. x (M, D) float -> centroids (k, D).
    Deterministic for a seed.

    Random seeds follow the density of the points, which suits a vocabulary; the object
    models' few colour classes need k-means++ and use scipy's ``kmeans2``.

    Empty clusters are re-seeded with the points farthest from their centroids, so that every
    prototype ends up describing some descriptors.
    """
    if len(x) < k:
        raise ValueError(f"k-means needs at least k={k} descriptors, got {len(x)}")
    generator = torch.Generator().manual_seed(seed)
    centroids = x[torch.randperm(len(x), generator=generator)[:k].to(x.device)].clone()
    for _ in range(iters):
        index, dist = (column.squeeze(1) for column in nearest_centroids(x, centroids))
        counts = torch.bincount(index, minlength=k).to(x.dtype)
        sums = torch.zeros_like(centroids).index_add_(0, index, x)
        empty = counts == 0
        centroids = sums / counts.clamp_min(1)[:, None]
        if empty.any():
            far = dist.topk(int(empty.sum())).indices
            centroids[empty] = x[far]
    return centroids
