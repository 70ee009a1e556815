"""Split search (paper eq. 7) over all features of all classes at once, with Welch's t-test.

For a class s and action a, with the interactions of (s, a) and their TD errors Δ, feature f
splits them into Δ_f (f present) and Δ_¬f. Eq. (7) minimises p_f Var(Δ_f) + p_¬f Var(Δ_¬f);
equivalently we maximise the reduction of the sum of squared deviations

    SSE(Δ) − SSE(Δ_f) − SSE(Δ_¬f),

which, unlike the raw eq. (7) value, is comparable across actions with different sample counts.
Counts, sums and sums of squares of Δ for every (class, action, feature) are X^T 1, X^T Δ and
X^T Δ² restricted to each group, X the sparse (interaction, feature) presence, added group by
group in one pass (``kernels.passing_cells``).
RLJC's joint classes also split on action thresholds (``find_threshold_splits``), scored the
same way from cumulative sums over the actions sorted per class.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy import stats

from vistask.checks import checked
from vistask.features.compounds import concatenated_ranges


@checked
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


def group_moments(
    group: torch.Tensor, deltas: torch.Tensor, n_groups: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Count, sum and sum of squares (n_groups,) float64 of ``deltas`` (N,) in each ``group``
    (N,) long, the statistics that ``sse`` and ``welch_splits`` read.

    Example:
        >>> n, s1, s2 = group_moments(torch.tensor([0, 0, 2]), torch.tensor([1.0, 3.0, 2.0]), 3)
        >>> s2
        tensor([10.,  0.,  4.], dtype=torch.float64)
    """
    deltas = deltas.double()
    n = torch.bincount(group, minlength=n_groups).double()
    s1 = torch.zeros(n_groups, dtype=torch.float64).index_add_(0, group, deltas)
    s2 = torch.zeros(n_groups, dtype=torch.float64).index_add_(0, group, deltas * deltas)
    return n, s1, s2


def first_in_group(groups: torch.Tensor, n_groups: int) -> torch.Tensor:
    """Position in ``groups`` (K,) of the first element of each group that occurs, by group.

    Example:
        >>> first_in_group(torch.tensor([2, 0, 2, 0]), 3)
        tensor([1, 0])
    """
    first = torch.full((n_groups,), len(groups)).scatter_reduce_(
        0, groups, torch.arange(len(groups)), "amin"
    )
    return first[first < len(groups)]


def welch_splits(
    n_a: torch.Tensor,
    s1_a: torch.Tensor,
    s2_a: torch.Tensor,
    n_b: torch.Tensor,
    s1_b: torch.Tensor,
    s2_b: torch.Tensor,
    alpha: float | torch.Tensor,
    margin: float = 0.0,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Score candidate splits of TD errors into two sides a and b, each given by its counts,
    sums and sums of squares (K,) float64, at significance level ``alpha`` (one, or (K,)):
    Welch's test that the sides' means differ by more than ``margin`` (>= 0, in TD-error
    units; 0: that they differ at all).

    Returns:
        reduction (K,): SSE(a + b) - SSE(a) - SSE(b); p (K,): Welch's two-sided p-value (1
        where it cannot pass); significant (K,) bool: reduction > 0 and p < alpha.
    """
    sse_a, sse_b = sse(n_a, s1_a, s2_a), sse(n_b, s1_b, s2_b)
    reduction = sse(n_a + n_b, s1_a + s1_b, s2_a + s2_b) - sse_a - sse_b
    # Welch's t for every candidate, in torch; exact p-values (scipy) only where |t| beats the
    # normal quantile, a lower bound of every Student quantile, so the rest cannot pass.
    se2_a, se2_b = sse_a / (n_a - 1) / n_a, sse_b / (n_b - 1) / n_b
    diff = (s1_a / n_a - s1_b / n_b).abs()
    if margin > 0:
        diff = (diff - margin).clamp_min(0.0)
    t = diff / (se2_a + se2_b).sqrt()  # inf for a perfect split, nan for no difference
    z = torch.as_tensor(stats.norm.isf(torch.as_tensor(alpha).numpy() / 2))
    maybe = (reduction > 0) & (t.nan_to_num(0.0) > z)
    p = torch.ones_like(t)
    if maybe.any():
        a, b = se2_a[maybe], se2_b[maybe]
        df = (a + b) ** 2 / (a**2 / (n_a[maybe] - 1) + b**2 / (n_b[maybe] - 1))
        df = df.nan_to_num(nan=1.0).clamp_min(1)
        p[maybe] = torch.from_numpy(2 * stats.t.sf(t[maybe].numpy(), df.numpy()))
    return reduction, p, maybe & (p < alpha)


FIRST_CELLS = 1 << 12  # room for passing cells; doubled as they come


def candidate_moments(
    row_group: torch.Tensor,
    features: torch.Tensor,
    rows: torch.Tensor,
    moments: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
    n_g: torch.Tensor,
    n_features: int,
    min_count: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The (group, feature) cells with ``min_count`` interactions on both sides of a split,
    and their count, sum and sum of squares of TD errors where the feature is present.

    Args:
        row_group: (R,) long group of each row, in 0..G (G: a group that cannot split, never
            counted).
        features: (nnz,) long feature of each (row, feature) pair.
        rows: (nnz,) long row of each pair, non-decreasing (pairs by row).
        moments: (R,) float64 count (whole numbers), sum and sum of squares of the TD errors
            of each row.
        n_g: (G,) float64 interactions of each group.
        n_features: F.
        min_count: interactions needed on each side.

    Returns:
        cells (K,) long, ``group * F + feature``, ascending; counts, sums and sums of squares
        (K,) float64, each summed row by row in the rows' order.
    """
    n_rows = len(row_group)
    starts = np.zeros(n_rows + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows.numpy(), minlength=n_rows), out=starts[1:])
    from vistask.rlvc.kernels import passing_cells  # numba, on first use

    found = passing_cells(
        row_group.numpy(),
        starts,
        features.numpy(),
        *(m.double().numpy() for m in moments),
        (n_g - min_count).numpy(),
        n_features,
        min_count,
        FIRST_CELLS,
    )
    return tuple(torch.from_numpy(a) for a in found)


# Splits of a class whose SSE reductions differ by less than this share of their group's sum
# of squared TD errors are summed again over interactions: rounding reaches about 1e-14.
TIE_TOLERANCE = 1e-8


def near_ties(
    state: torch.Tensor, reduction: torch.Tensor, significant: torch.Tensor, scale: torch.Tensor
) -> torch.Tensor:
    """Candidates (K,) of one class (``state``) whose significant ``reduction`` lies within
    ``TIE_TOLERANCE`` times ``scale`` (K,) of another's: their indices, ascending."""
    k = torch.nonzero(significant).flatten()
    k = k[torch.from_numpy(np.lexsort((reduction[k].numpy(), state[k].numpy())))]
    gap = reduction[k[1:]] - reduction[k[:-1]]
    tie = (state[k[1:]] == state[k[:-1]]) & (
        gap <= TIE_TOLERANCE * torch.maximum(scale[k[1:]], scale[k[:-1]])
    )
    return torch.unique(torch.cat([k[:-1][tie], k[1:][tie]]))


def interaction_moments(
    cells: torch.Tensor,
    pair_group: torch.Tensor,
    pairs: torch.Tensor,
    rows: torch.Tensor,
    features: torch.Tensor,
    deltas: torch.Tensor,
    n_features: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Count, sum and sum of squares (K,) float64 of the TD errors in (group row, feature)
    ``cells`` (K,), added interaction by interaction in their order, as a search whose rows
    are interactions adds them.

    Args:
        cells: (K,) long, ``group row * F + feature``, ascending.
        pair_group: (P,) long group row of each pair. pairs: (N,) long pair of each
            interaction. rows, features: (nnz,) the (pair, feature) presence.
        deltas: (N,) float64. n_features: F.
    """
    if len(cells) == 0:
        return tuple(torch.zeros(0, dtype=torch.float64) for _ in range(3))
    wanted = torch.zeros(n_features, dtype=torch.bool)
    wanted[cells % n_features] = True
    near = torch.nonzero(wanted[features]).flatten()
    key = pair_group[rows[near]] * n_features + features[near]
    at = torch.searchsorted(cells, key).clamp_max(len(cells) - 1)
    hit = cells[at] == key
    # The cells of each pair, then of each interaction, by interaction: each cell's in order.
    pair, cell = rows[near][hit], at[hit]
    by_pair = torch.argsort(pair, stable=True)
    pair, cell = pair[by_pair], cell[by_pair]
    count = torch.bincount(pair, minlength=len(pair_group))
    start = torch.cumsum(count, 0) - count
    inter = torch.nonzero(count[pairs]).flatten()
    per = count[pairs[inter]]
    i = torch.repeat_interleave(inter, per)
    k = cell[torch.from_numpy(concatenated_ranges(start[pairs[inter]].numpy(), per.numpy()))]
    d = deltas[i]
    return tuple(
        torch.zeros(len(cells), dtype=torch.float64).index_add_(0, k, v)
        for v in (torch.ones_like(d), d, d * d)
    )


@checked
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
    prefer: torch.Tensor | None = None,
    prefer_share: float = 0.5,
    pairs: torch.Tensor | None = None,
    margin: float = 0.0,
) -> list[Split]:
    """Best significant split of every class.

    Args:
        rows, features: (nnz,) sparse pairs "feature ``features[k]`` present in the percept of
            interaction ``rows[k]``" (``InteractionDatabase.interaction_features``), or of
            percept-action pair ``rows[k]`` when ``pairs`` is given.
        states, actions, deltas: (N,) class of x_t, action, TD error of each interaction.
        n_states, n_actions, n_features: sizes S, A, F.
        alpha: significance level of Welch's two-sample t-test.
        min_count: minimum number of interactions on each side of a split.
        prefer: (F,) bool, features to split on before the others: a class splits on its best
            significant preferred feature when that reduces the SSE by at least
            ``prefer_share`` of the class's best significant split (None: the best split).
        prefer_share: see ``prefer``.
        pairs: (N,) long, the distinct (x_t, action) pair of each interaction, which ``rows``
            index (``InteractionDatabase.percept_action_features``): the search then reads each
            pair once however often it was met. None: ``rows`` index interactions.
        margin: the TD errors' means on the two sides of a split must differ by more than
            this (``welch_splits``; 0: by anything significant).

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

    n_g, s1_g, s2_g = group_moments(group, deltas, groups)  # per (class, action)

    # Only (class, action) groups with room for min_count on both sides can split; compacting
    # them bounds the (group x feature) tables by the data, not by S x A x F.
    active = torch.nonzero(n_g >= 2 * min_count).flatten()
    if len(active) == 0:
        return []
    # The other groups share one row past the active ones, never counted.
    compact = torch.full((groups,), len(active), dtype=torch.long)
    compact[active] = torch.arange(len(active))
    n_g, s1_g, s2_g = n_g[active], s1_g[active], s2_g[active]
    if pairs is None:
        row_group, moments = group, (torch.ones_like(deltas), deltas, deltas * deltas)
    else:
        n_pairs = int(pairs.max()) + 1
        row_group = torch.zeros(n_pairs, dtype=torch.long).scatter_(0, pairs, group)
        moments = group_moments(pairs, deltas, n_pairs)
    row_group = compact[row_group]
    candidate, n_f, s1_f, s2_f = candidate_moments(
        row_group, features, rows, moments, n_g, n_features, min_count
    )
    if len(candidate) == 0:
        return []
    cg, cf = candidate // n_features, candidate % n_features  # group row, feature
    n_gc, s1_gc, s2_gc = n_g[cg], s1_g[cg], s2_g[cg]

    state_of, action_of = active // n_actions, active % n_actions

    def score(k: torch.Tensor | slice) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        n, s1, s2 = n_gc[k], s1_gc[k], s2_gc[k]
        a, b = (n_f[k], s1_f[k], s2_f[k]), (n - n_f[k], s1 - s1_f[k], s2 - s2_f[k])
        return welch_splits(*a, *b, alpha, margin)

    def summed_by_interaction(k: torch.Tensor) -> tuple[torch.Tensor, ...]:
        k = torch.sort(k).values  # candidates ascend with their cells
        moments = interaction_moments(
            candidate[k], row_group, pairs, rows, features, deltas, n_features
        )
        n_f[k], s1_f[k], s2_f[k] = moments
        return k, *score(k)

    reduction, p, significant = score(slice(None))
    if pairs is not None:
        # Sums over pairs round otherwise than sums over interactions: near-equal splits of a
        # class (features with the same presence split alike) are summed again interaction by
        # interaction, so that the first in (action, feature) order wins as it does there.
        k, *scores = summed_by_interaction(near_ties(state_of[cg], reduction, significant, s2_gc))
        reduction[k], p[k], significant[k] = scores

    # Eq. (7) among the significant candidates: the purest split of every class; among equal
    # ones (features with the same presence split alike), the first in (action, feature) order.
    best = torch.nonzero(significant).flatten()
    best = best[torch.argsort(reduction[best], descending=True, stable=True)]
    if prefer is not None and len(best):
        state = state_of[cg[best]]
        top = torch.zeros(n_states, dtype=torch.float64).scatter_reduce_(
            0, state, reduction[best], "amax", include_self=False
        )
        first = prefer[cf[best]] & (reduction[best] >= prefer_share * top[state])
        best = torch.cat([best[first], best[~first]])  # still by reduction on either side
    chosen = best[first_in_group(state_of[cg[best]], n_states)]  # one per class
    if pairs is not None:  # the chosen splits' figures as summed over interactions
        k, *scores = summed_by_interaction(chosen)
        reduction[k], p[k] = scores[:2]
    chosen = chosen.tolist()
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


@checked
@dataclass
class ThresholdSplit:
    """A significant split of class ``state`` on "action component ``dim`` >= ``threshold``"."""

    state: int
    dim: int
    threshold: float
    reduction: float
    p_value: float


@checked
def find_threshold_splits(
    states: torch.Tensor,
    actions: torch.Tensor,
    deltas: torch.Tensor,
    n_states: int,
    alpha: float = 0.05,
    min_count: int = 10,
) -> list[ThresholdSplit]:
    """Best significant split of every class on one component of a continuous action.

    The candidate thresholds of a class are, per action dimension, the midpoints between
    consecutive distinct values of the actions seen in the class (paper 2.5.3), scored like a
    feature from cumulative sums over the actions sorted per class. The best cut of a class,
    over all dimensions, is tested with Welch's t-test at ``alpha`` divided by the class's
    number of cuts: the largest of many correlated statistics would pass an uncorrected test
    by chance.

    Args:
        states: (N,) class of each interaction.
        actions: (N, m) float actions.
        deltas: (N,) TD errors.
        n_states: number of classes S.
        alpha, min_count: as in ``find_splits``.

    Returns:
        One ``ThresholdSplit`` per class whose best threshold is significant.
    """
    if actions.ndim != 2 or len(actions) != len(states):
        raise ValueError(f"actions must be (N, m) with N = {len(states)}, got {actions.shape}")
    cuts = [
        _cuts(states, actions[:, dim].double(), deltas.double(), n_states, min_count)
        for dim in range(actions.shape[1])
    ]
    dims = torch.cat([torch.full((len(c[0]),), dim) for dim, c in enumerate(cuts)])
    state_of, threshold, below, above = (torch.cat(column) for column in zip(*cuts, strict=True))
    if len(state_of) == 0:
        return []
    reduction = sse(*(below + above).T) - sse(*below.T) - sse(*above.T)
    best = torch.full((n_states,), -torch.inf, dtype=torch.float64)
    best.scatter_reduce_(0, state_of, reduction, "amax")
    tops = torch.nonzero(reduction == best[state_of]).flatten()
    i = tops[first_in_group(state_of[tops], n_states)]  # the first best cut of each class
    n_cuts = torch.bincount(state_of, minlength=n_states)[state_of[i]].double()
    _, p, significant = welch_splits(*below[i].T, *above[i].T, alpha / n_cuts)
    i, p = i[significant], p[significant]
    splits = [
        ThresholdSplit(
            int(state_of[k]), int(dims[k]), float(threshold[k]), float(reduction[k]), float(pk)
        )
        for k, pk in zip(i.tolist(), p.tolist(), strict=True)
    ]
    return sorted(splits, key=lambda split: -split.reduction)


def _cuts(
    states: torch.Tensor, a: torch.Tensor, deltas: torch.Tensor, n_states: int, min_count: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The candidate cuts of one action dimension ``a`` (N,) in every class.

    Returns:
        per cut: its class (K,), threshold (K,), and (K, 3) counts, sums and sums of squares of
        the TD errors below and above it.
    """
    n_class = torch.bincount(states, minlength=n_states)
    start_of_class = torch.cumsum(n_class, 0) - n_class
    order = torch.from_numpy(np.lexsort((a.numpy(), states.numpy())))  # class, then a
    s, a, d = states[order], a[order], deltas[order]
    # Below the cut after row i: the rows of i's class up to i, in this order.
    n_b = (torch.arange(len(s)) - start_of_class[s] + 1).double()
    c1, c2 = torch.cumsum(d, 0), torch.cumsum(d * d, 0)
    before = start_of_class[s] - 1  # cumulative sums up to the class's first row
    base1 = torch.where(before >= 0, c1[before.clamp_min(0)], 0.0)
    base2 = torch.where(before >= 0, c2[before.clamp_min(0)], 0.0)
    end = start_of_class[s] + n_class[s] - 1  # the class's last row
    n_all, s1_all, s2_all = n_class[s].double(), c1[end] - base1, c2[end] - base2
    following = torch.clamp(torch.arange(len(s)) + 1, max=len(s) - 1)
    cut = (
        (n_b >= min_count)
        & (n_all - n_b >= min_count)
        & (s[following] == s)
        & (a[following] > a)  # a threshold between two distinct values
    )
    k = torch.nonzero(cut).flatten()
    below = torch.stack([n_b[k], (c1 - base1)[k], (c2 - base2)[k]], 1)
    everything = torch.stack([n_all[k], s1_all[k], s2_all[k]], 1)
    return s[k], (a[k] + a[following[k]]) / 2, below, everything - below
