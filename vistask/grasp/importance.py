"""Empirical grasp densities from trials by importance sampling (paper 3.5): the trials, their
weights 1 / (q + c) under the mixture of the proposals they were drawn from, and the local
success rates that weigh reliable grasps up."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from statistics import NormalDist

import torch

from vistask.checks import check_at_least, check_positive, checked
from vistask.se3 import SE3KDE, check_poses


@checked
def importance_weights(q: torch.Tensor, c: float) -> torch.Tensor:
    """(N,) proposal density values -> (N,) importance weights 1 / (q + c)."""
    if c < 0 or not math.isfinite(c):
        raise ValueError(f"c must be finite and non-negative, got {c}")
    if (q < 0).any() or not torch.isfinite(q).all():
        raise ValueError("proposal values must be finite and non-negative")
    return 1.0 / (q + c)


@checked
@dataclass
class Trials:
    """Executed trials, object frame.

    Attributes:
        grasps: (N, 7) object-frame grasps.
        success: (N,) bool outcomes.
        cycle: (N,) learning cycle of each trial (index into the proposals).
    """

    grasps: torch.Tensor = field(default_factory=lambda: torch.empty(0, 7))
    success: torch.Tensor = field(default_factory=lambda: torch.empty(0, dtype=torch.bool))
    cycle: torch.Tensor = field(default_factory=lambda: torch.empty(0, dtype=torch.long))

    def __len__(self) -> int:
        return len(self.success)

    def add(self, grasps: torch.Tensor, success: torch.Tensor, cycle: int | torch.Tensor) -> None:
        """Append (n, 7) grasps and (n,) successes drawn from proposal ``cycle`` (one index
        for all, or (n,) indices)."""
        grasps = check_poses(grasps, "grasps", batched=True)
        if success.shape != (len(grasps),):
            raise ValueError(
                f"success must have shape ({len(grasps)},), one per grasp, got "
                f"{tuple(success.shape)}"
            )
        if success.dtype != torch.bool:
            raise TypeError(f"success must be a bool tensor, got {success.dtype}")
        cycle = torch.as_tensor(cycle)
        if cycle.is_floating_point() or cycle.dtype == torch.bool or (cycle < 0).any():
            raise ValueError(f"cycle must be proposal indices >= 0, got {cycle.tolist()}")
        self.grasps = torch.cat([self.grasps, grasps.float().cpu()])
        self.success = torch.cat([self.success, success.cpu()])
        cycle = cycle.to(torch.long).cpu().expand(len(success))
        self.cycle = torch.cat([self.cycle, cycle])


@checked
def mixture_proposal(trials: Trials, proposals: Sequence[SE3KDE]) -> torch.Tensor:
    """(N,) the normalised density sum_k (n_k / N) q_k at every trial's grasp."""
    if len(trials) == 0:
        return torch.empty(0, dtype=torch.float64)
    counts = torch.bincount(trials.cycle, minlength=len(proposals)).double()
    if len(counts) != len(proposals):
        raise ValueError(f"trials come from {len(counts)} cycles, got {len(proposals)} proposals")
    q = torch.zeros(len(trials), dtype=torch.float64)
    for n_k, proposal in zip(counts / len(trials), proposals, strict=True):
        if n_k > 0:
            x = trials.grasps.to(proposal.points)
            q += n_k * proposal.evaluate(x, normalized=True).double().cpu()
    return q


RELIABILITY_WIDTH = 2.0
"""The local success rate is estimated with kernels this many times the density's: success
varies more smoothly than the particles are spread, and a wider neighbourhood holds enough
trials to tell a reliable grasp from a lucky one."""

RANKING_WIDTHS = (2.0, 4.0, 6.0, 8.0)
"""The kernel widths, in multiples of the density's, among which a learner chooses the one that
ranks best-of-K candidates (``validated_ranking_width``): success rates within 4 mm to 16 mm
and 0.1 to 0.4 rad of each candidate, for the densities ``learn_grasps.py`` learns."""


RELIABILITY_POWER = 3.0
"""The power of the local success rate in a success's weight in the learned density, the one a
robot samples. On the same trials, acting on NBP's estimates (eight objects, 100 held-out
placements), its sampled grasps succeeded in 0.866 on average against 0.855 with the rate
itself (the bottle 0.85 against 0.79; docs/results.md)."""

EXPLORATION_POWER = 1.0
"""The same power in the density that learning draws its next trials from. Learning with the
cube too lowered the best rated of 10 from 0.914 to 0.882 on average: its trials crowd on
fewer grasps, and the success rates have fewer kinds of grasps to rank (docs/results.md)."""


@checked
def local_success_rates(
    trials: Trials,
    weights: torch.Tensor,
    sigma_t: float,
    sigma_r: float,
    prior: float = 1.0,
    at: torch.Tensor | None = None,
) -> torch.Tensor:
    """(M,) the success rate of the trials around M grasps (default: the successful ones).

    An importance-weighted kernel regression of the outcomes, shrunk towards the overall
    rate by ``prior`` pseudo-trials: a lone success scores (1 + prior * p) / (1 + prior),
    a success among failures less, one among successes more.

    Args:
        trials: all trials (N of them, S successful).
        weights: (N,) importance weights of the trials.
        sigma_t, sigma_r: kernel of the regression.
        prior: weight of the overall success rate, in trials.
        at: (M, 7) object-frame grasps to estimate the rate at (default: the S successful
            trials' grasps, in their order).

    Returns:
        (M,) rates in [0, 1], on the trials' device (the CPU).
    """
    check_at_least(0, prior=prior)
    check_positive(sigma_t=sigma_t, sigma_r=sigma_r)
    success = trials.success
    w = (weights / weights.mean()).float()
    at = trials.grasps[success] if at is None else at.to(trials.grasps)
    # SE3KDE normalises its weights: multiply back by their sums to get sums of w_j K_ij.
    tried = SE3KDE(trials.grasps, w, sigma_t, sigma_r).evaluate(at) * w.sum()
    won = (
        SE3KDE(trials.grasps[success], w[success], sigma_t, sigma_r).evaluate(at) * w[success].sum()
    )
    overall = w[success].sum() / w.sum()
    return ((won + prior * overall) / (tried + prior)).clamp(0.0, 1.0)


def trial_weights(trials: Trials, proposals: Sequence[SE3KDE], c_rel: float) -> torch.Tensor:
    """(N,) importance weights 1 / (q + c) of all trials, q the mixture of the proposals they
    were drawn from and c = ``c_rel`` times its mean over the trials."""
    q = mixture_proposal(trials, proposals)
    return importance_weights(q, c_rel * float(q.mean()))


@checked
def empirical_density(
    trials: Trials,
    proposals: Sequence[SE3KDE],
    c_rel: float = 1.0,
    sigma_t: float = 0.01,
    sigma_r: float = 0.25,
    kernel: str = "gaussian",
    reliability: float = RELIABILITY_POWER,
) -> SE3KDE | None:
    """The importance-weighted successes as a density (None without any success).

    Args:
        trials: all trials.
        proposals: the density each cycle drew from (``proposals[k]`` for cycle k).
        c_rel: c as a fraction of the mean mixture proposal density over the trials.
        sigma_t, sigma_r, kernel: kernel of the result.
        reliability: the power of the success rate around every success
            (``local_success_rates``) in its weight, so that draws favour grasps that succeed
            again over lucky ones, the more so the higher it is; 0 gives the paper's
            empirical density, which estimates the grasp affordance itself.

    Returns:
        an ``SE3KDE`` over the successful grasps with weights 1 / (q(g) + c), times the
        local success rates to the power ``reliability``.

    Raises:
        ValueError: ``reliability`` negative or NaN.
    """
    check_at_least(0, reliability=reliability, c_rel=c_rel)
    if not trials.success.any():
        return None
    w = trial_weights(trials, proposals, c_rel)
    keep = trials.success
    weights = w[keep].float()
    if reliability:
        k = RELIABILITY_WIDTH
        weights = weights * local_success_rates(trials, w, k * sigma_t, k * sigma_r) ** reliability
    return SE3KDE(trials.grasps[keep], weights, sigma_t, sigma_r, kernel=kernel)


@checked
def ranking_auc(
    rates: torch.Tensor, success: torch.Tensor, strata: torch.Tensor | None = None
) -> tuple[float, float] | None:
    """How well ``rates`` (N,) order the outcomes ``success`` (N,) bool, comparing each
    success only with the failures of its stratum (``strata`` (N,) int, default one).

    Returns:
        (auc, z): the chance that a success rates above a failure of its stratum (ties count
        half; 0.5 ranks by chance, the area under the ROC curve), and its z-score against
        chance under the Mann-Whitney null, the strata pooled as in van Elteren's test.
        None when no stratum has both a success and a failure.
    """
    strata = torch.zeros_like(success, dtype=torch.long) if strata is None else strata
    rates = rates.double()
    above = pairs = variance = 0.0
    for s in strata.unique():
        wins, losses = rates[(strata == s) & success], rates[(strata == s) & ~success]
        n1, n2 = len(wins), len(losses)
        if n1 == 0 or n2 == 0:
            continue
        d = wins[:, None] - losses[None, :]
        above += float((d > 0).sum() + 0.5 * (d == 0).sum())
        pairs += n1 * n2
        variance += n1 * n2 * (n1 + n2 + 1) / 12
    if pairs == 0:
        return None
    return above / pairs, (above - pairs / 2) / math.sqrt(variance)


@checked
def validated_ranking_width(
    trials: Trials,
    proposals: Sequence[SE3KDE],
    c_rel: float,
    sigma_t: float,
    sigma_r: float,
    widths: Sequence[float] = RANKING_WIDTHS,
    significance: float = 0.05,
) -> float | None:
    """The kernel width whose success rates rank grasps best, validated cycle by cycle.

    Each cycle after the first is held out in turn: the success rates of the cycles before it
    (``local_success_rates``, kernels ``width`` times (``sigma_t``, ``sigma_r``)) rate its
    grasps, and each width is scored by how well they order the held-out outcomes, pooled
    over the cycles (``ranking_auc``).

    Args:
        trials: all trials; ``trials.cycle`` indexes ``proposals``.
        proposals: the density each cycle drew from.
        c_rel, sigma_t, sigma_r: the learner's weight offset and kernel.
        widths: the candidate widths.
        significance: the chance of keeping a width that ranks no better than chance
            (one-sided, Bonferroni-corrected over ``widths``).

    Returns:
        the width of the highest z-score where it is significant, else None: a best-of-K draw
        then does best keeping its first candidate, a plain sample.
    """
    check_positive(significance=significance)
    held = torch.zeros(len(trials), dtype=torch.bool)
    rates = {k: torch.zeros(len(trials)) for k in widths}
    for c in range(1, len(proposals)):
        earlier, now = trials.cycle < c, trials.cycle == c
        if not now.any() or not trials.success[earlier].any():
            continue
        before = Trials(trials.grasps[earlier], trials.success[earlier], trials.cycle[earlier])
        w, at = trial_weights(before, proposals[:c], c_rel), trials.grasps[now]
        for k in widths:
            rates[k][now] = local_success_rates(before, w, k * sigma_t, k * sigma_r, at=at)
        held |= now
    scores = {}
    for k in widths:
        test = ranking_auc(rates[k][held], trials.success[held], trials.cycle[held])
        if test is not None:
            scores[k] = test[1]
    if not scores:
        return None
    best = max(scores, key=scores.get)
    critical = NormalDist().inv_cdf(1 - significance / len(widths))
    return best if scores[best] > critical else None
