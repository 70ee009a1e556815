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


def _sse(n: torch.Tensor, s1: torch.Tensor, s2: torch.Tensor) -> torch.Tensor:
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
    bonferroni: bool = True,
) -> list[Split]:
    """Best significant split of every class.

    Args:
        rows, features: (nnz,) sparse pairs "feature ``features[k]`` present in the percept of
            interaction ``rows[k]``" (``InteractionDatabase.interaction_features``).
        states, actions, deltas: (N,) class of x_t, action, TD error of each interaction.
        n_states, n_actions, n_features: sizes S, A, F.
        alpha: significance level of Welch's two-sample t-test.
        min_count: minimum number of interactions on each side of a split.
        bonferroni: test at alpha / (number of candidate (action, feature) pairs of the class).
            The best of thousands of candidate features is always "significant" at a plain
            alpha, even on pure noise; the correction keeps alpha the family-wise error rate.

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
    shape, size = (len(active), n_features), len(active) * n_features
    n_f = torch.bincount(key, minlength=size).double().view(shape)
    s1_f = torch.zeros(size, dtype=torch.float64).index_add_(0, key, d).view(shape)
    s2_f = torch.zeros(size, dtype=torch.float64).index_add_(0, key, d * d).view(shape)
    n_g, s1_g, s2_g = n_g[active], s1_g[active], s2_g[active]

    n_nf = n_g[:, None] - n_f
    s1_nf, s2_nf = s1_g[:, None] - s1_f, s2_g[:, None] - s2_f
    sse_f, sse_nf = _sse(n_f, s1_f, s2_f), _sse(n_nf, s1_nf, s2_nf)
    reduction = _sse(n_g, s1_g, s2_g)[:, None] - sse_f - sse_nf
    valid = (n_f >= min_count) & (n_nf >= min_count) & (reduction > 0)
    state_of, action_of = active // n_actions, active % n_actions
    tests = torch.zeros(n_states, dtype=torch.float64).index_add_(
        0, state_of, valid.sum(1).double()
    )
    level = alpha / tests.clamp_min(1) if bonferroni else torch.full((n_states,), alpha)

    # Welch's t for every candidate, in torch; exact p-values (scipy) only where |t| beats the
    # normal quantile, a lower bound of every Student quantile, so the rest cannot pass.
    v_f, v_nf = sse_f / (n_f - 1).clamp_min(1), sse_nf / (n_nf - 1).clamp_min(1)
    se2_f, se2_nf = v_f / n_f.clamp_min(1), v_nf / n_nf.clamp_min(1)
    diff = s1_f / n_f.clamp_min(1) - s1_nf / n_nf.clamp_min(1)
    t = diff.abs() / (se2_f + se2_nf).sqrt()  # inf for a perfect split, nan for no difference
    row_level = level[state_of][:, None].expand_as(t)
    z = torch.from_numpy(stats.norm.isf(row_level.numpy() / 2))
    maybe = valid & (t.nan_to_num(0.0) > z)
    p = torch.ones_like(t)
    if maybe.any():
        a, b = se2_f[maybe], se2_nf[maybe]
        df = (a + b) ** 2 / (a**2 / (n_f[maybe] - 1) + b**2 / (n_nf[maybe] - 1))
        df = df.nan_to_num(nan=1.0).clamp_min(1)
        p[maybe] = torch.from_numpy(2 * stats.t.sf(t[maybe].numpy(), df.numpy()))
    significant = maybe & (p < row_level)

    # Eq. (7) among the significant candidates: the purest split of every class.
    score = reduction.masked_fill(~significant, -torch.inf)
    group_best, group_feature = score.max(dim=1)
    splits: dict[int, Split] = {}
    for k in torch.nonzero(torch.isfinite(group_best)).flatten().tolist():
        state, f = int(state_of[k]), int(group_feature[k])
        if state not in splits or group_best[k] > splits[state].reduction:
            splits[state] = Split(state, f, int(action_of[k]), float(group_best[k]), float(p[k, f]))
    return sorted(splits.values(), key=lambda split: -split.reduction)
