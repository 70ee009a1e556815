"""Novelty of percepts for directed exploration: counts over hashed feature sets.

A percept's code is the SimHash of its feature presence (Tang et al. 2017, #Exploration): the
signs of ``bits`` random projections of its presence vector, so that percepts showing nearly
the same features share a code. The bonus of an interaction is ``1 / sqrt(n)``, ``n`` the
interactions of the database that lead to a percept of its successor's code: rarely reached
percepts are worth reaching.
"""

from __future__ import annotations

import torch

from vistask.checks import checked
from vistask.rlvc.presence import PackedPresence

CODE_BITS = 32  # bits of a percept's code


@checked
def simhash_codes(
    presence: PackedPresence | torch.Tensor, bits: int = CODE_BITS, seed: int = 0
) -> torch.Tensor:
    """(M, F) feature presence -> (M,) int64 codes: bit b is the sign of the sum of the
    Gaussian projections ``A[b, f]`` of the features present (A seeded by ``seed``, the same
    for every call with the same F).

    Example:
        >>> codes = simhash_codes(db.presence)       # (M,) equal for equal feature sets
    """
    if not 1 <= bits <= 62:
        raise ValueError(f"bits must be in 1..62, got {bits}")
    n, f = presence.shape
    generator = torch.Generator().manual_seed(seed)
    projection = torch.randn(f, bits, generator=generator, dtype=torch.float64)
    rows, features = presence.nonzero(as_tuple=True)
    sums = torch.zeros(n, bits, dtype=torch.float64).index_add_(0, rows, projection[features])
    weights = 2 ** torch.arange(bits, dtype=torch.int64)
    return ((sums > 0).long() * weights).sum(dim=1)


@checked
def novelty_bonus(
    presence: PackedPresence | torch.Tensor,
    next_obs: torch.Tensor,
    bits: int = CODE_BITS,
    seed: int = 0,
) -> torch.Tensor:
    """(N,) float64 bonus ``1 / sqrt(n)`` of each interaction, ``n`` the interactions whose
    successor percept ``next_obs`` (N,) has the code of this one's (``simhash_codes`` of
    ``presence``)."""
    codes = simhash_codes(presence, bits, seed)[next_obs]
    _, code, counts = torch.unique(codes, return_inverse=True, return_counts=True)
    return counts[code].double().rsqrt()


__all__ = ["CODE_BITS", "novelty_bonus", "simhash_codes"]
