"""Split search (paper eq. 7) over all features of all classes at once, with Welch's t-test.

For a class s and action a, with the interactions of (s, a) and their TD errors Δ, feature f
splits them into Δ_f (f present) and Δ_¬f. Eq. (7) minimises p_f Var(Δ_f) + p_¬f Var(Δ_¬f);
equivalently we maximise the reduction of the sum of squared deviations

    SSE(Δ) − SSE(Δ_f) − SSE(Δ_¬f),

which, unlike the raw eq. (7) value, is comparable across actions with different sample counts.
Counts, sums and sums of squares of Δ for every (class, action, feature) are three scatter-adds
over the sparse (interaction, feature) list: X^T 1, X^T Δ and X^T Δ² restricted to each group.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from scipy import stats


@dataclass
class Split:
    """A significant split: class ``state`` on ``feature``, found under ``action``."""

    state: int
    feature: int
    action: int
    reduction: float
    p_value: float


def sse(n: torch.Tensor, s1: torch.Tensor, s2: torch.Tensor) -> torch.Tensor:
    """Sum of squared deviations from counts, sums, sums of squares (0 for empty groups)."""
    return (s2 - s1 * s1 / n.clamp_min(1)).clamp_min(0)


def find_splits(
    rows: torch.Tensor,
    features: torch.Tensor,
    states: torch.Tensor,
    actions: torch.Tensor,
    deltas: torch.Tensor,
    n_states: int,
    n_actions: int,
    n_features: int,
    alpha: float = 0.05,
    min_count: int = 10,
) -> list[Split]:
    """Best significant split of every class.

    Args:
        rows, features: (nnz,) sparse pairs "feature ``features[k]`` present in the percept of
            interaction ``rows[k]``" (``InteractionDatabase.interaction_features``).
        states, actions, deltas: (N,) class of x_t, action, TD error of each interaction.
        n_states, n_actions, n_features: sizes S, A, F.
        alpha: significance level of Welch's two-sample t-test.
        min_count: minimum number of interactions on each side of a split.

    Returns:
        One ``Split`` per class whose best split is significant, by decreasing reduction.
    """
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    if min_count < 2:
        raise ValueError(f"min_count must be >= 2 (a variance needs two samples), got {min_count}")
    deltas = deltas.double()
    groups = n_states * n_actions
    group = states * n_actions + actions  # (N,)

    # Per (class, action) totals.
    n_g = torch.bincount(group, minlength=groups).double()
    s1_g = torch.zeros(groups, dtype=torch.float64).index_add_(0, group, deltas)
    s2_g = torch.zeros(groups, dtype=torch.float64).index_add_(0, group, deltas * deltas)

    # Only (class, action) groups with room for min_count on both sides can split; compacting
    # them bounds the (group x feature) tables by the data, not by S x A x F.
    active = torch.nonzero(n_g >= 2 * min_count).flatten()
    if len(active) == 0:
        return []
    compact = torch.full((groups,), -1, dtype=torch.long)
    compact[active] = torch.arange(len(active))
    row_group = compact[group[rows]]
    keep = row_group >= 0
    key = row_group[keep] * n_features + features[keep]
    d = deltas[rows[keep]]
    size = len(active) * n_features
    n_g, s1_g, s2_g = n_g[active], s1_g[active], s2_g[active]
    # Candidates: (group, feature) pairs with min_count on both sides, a small share of the
    # group x feature table once classes are small; the statistics below are per candidate.
    n_f = torch.bincount(key, minlength=size)
    room = (n_g.long() - min_count)[:, None]
    both_sides = (n_f.view(-1, n_features) >= min_count) & (n_f.view(-1, n_features) <= room)
    candidate = torch.nonzero(both_sides.flatten()).flatten()
    if len(candidate) == 0:
        return []
    cg, cf = candidate // n_features, candidate % n_features  # group row, feature
    s1_f = torch.zeros(size, dtype=torch.float64).index_add_(0, key, d)[candidate]
    s2_f = torch.zeros(size, dtype=torch.float64).index_add_(0, key, d * d)[candidate]
    n_f = n_f[candidate].double()
    n_gc, s1_gc, s2_gc = n_g[cg], s1_g[cg], s2_g[cg]

    n_nf, s1_nf, s2_nf = n_gc - n_f, s1_gc - s1_f, s2_gc - s2_f
    sse_f, sse_nf = sse(n_f, s1_f, s2_f), sse(n_nf, s1_nf, s2_nf)
    reduction = sse(n_gc, s1_gc, s2_gc) - sse_f - sse_nf
    valid = reduction > 0
    state_of, action_of = active // n_actions, active % n_actions

    # Welch's t for every candidate, in torch; exact p-values (scipy) only where |t| beats the
    # normal quantile, a lower bound of every Student quantile, so the rest cannot pass.
    v_f, v_nf = sse_f / (n_f - 1), sse_nf / (n_nf - 1)
    se2_f, se2_nf = v_f / n_f, v_nf / n_nf
    diff = s1_f / n_f - s1_nf / n_nf
    t = diff.abs() / (se2_f + se2_nf).sqrt()  # inf for a perfect split, nan for no difference
    z = float(stats.norm.isf(alpha / 2))
    maybe = valid & (t.nan_to_num(0.0) > z)
    p = torch.ones_like(t)
    if maybe.any():
        a, b = se2_f[maybe], se2_nf[maybe]
        df = (a + b) ** 2 / (a**2 / (n_f[maybe] - 1) + b**2 / (n_nf[maybe] - 1))
        df = df.nan_to_num(nan=1.0).clamp_min(1)
        p[maybe] = torch.from_numpy(2 * stats.t.sf(t[maybe].numpy(), df.numpy()))
    significant = maybe & (p < alpha)

    # Eq. (7) among the significant candidates: the purest split of every class; among equal
    # ones (features with the same presence split alike), the first in (action, feature) order.
    best = torch.nonzero(significant).flatten()
    best = best[torch.argsort(reduction[best], descending=True, stable=True)]
    first = torch.full((n_states,), len(best)).scatter_reduce_(
        0, state_of[cg[best]], torch.arange(len(best)), "amin"
    )
    chosen = best[first[first < len(best)]].tolist()  # one candidate per splitting class
    splits = [
        Split(
            int(state_of[cg[k]]),
            int(cf[k]),
            int(action_of[cg[k]]),
            float(reduction[k]),
            float(p[k]),
        )
        for k in chosen
    ]
    return sorted(splits, key=lambda split: -split.reduction)
