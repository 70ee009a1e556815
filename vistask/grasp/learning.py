"""Learning empirical grasp densities by trial and error with importance sampling (paper 3.5).

One learning cycle: draw object-frame grasps g from the current proposal q, map them into the
world with the object pose, keep only reachable ones (redrawing the others), execute them,
and weight every success by 1 / (q(g) + c). The weighted successes form the *empirical*
grasp density, which becomes the next cycle's proposal. The offset c bounds the weight of
successes found where q is tiny (it keeps one lucky grasp from swallowing the density); here
c = ``c_rel`` times the mean of q over the trials, so it scales with q.

Every success is also weighted by a power of the success rate of the trials around it (an
importance-weighted kernel regression of the outcomes, ``local_success_rates``). The paper's
weights alone estimate the grasp affordance, where a grasp that succeeded once by luck weighs
as much as one that succeeds every time; drawing from it succeeds as often as the hypothesis's
successes did on average. With the rate itself, the next cycles draw near grasps that keep
succeeding while still trying every kind of grasp that worked; with its cube, the learned
density crowds on the most reliable ones, and is the one a robot should sample from. Where
the current proposal has no reachable grasp for a placement (it concentrated on the grasps of
one way the object lies), the trial draws from the hypothesis instead, and counts as its
draw.

Successes of all cycles are pooled. Cycle k drew its n_k trials from q_k, so together the
N trials were drawn from the mixture q(g) = sum_k (n_k / N) q_k(g), and that is the q in the
weights (the balance heuristic of multiple importance sampling). Dividing by each success's
own q_k instead would hand almost all the mass to the first cycle: the hypothesis is broad,
so its values are 10-100 times smaller than those of the later, concentrated proposals.

The simulator (or robot) is reached through a ``TrialRunner``: anything with ``num_envs``,
``reset(seeds) -> (B, 7) object poses`` and ``execute((B, 7) world grasps) -> ((B,) bool
successes, dict of (B,) diagnostics)``; ``vistask.envs.grasp_runners.VectorGraspTrials`` is
one for the robosuite arm. The poses ``reset`` gives are those the robot acts on: its own
estimates in the paper's setting, so that a grasp is recorded relative to the object *as
estimated* and pose errors become part of what the density learns.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch

from vistask.checks import check_at_least, checked
from vistask.grasp.importance import (
    EXPLORATION_POWER,
    RELIABILITY_POWER,
    Trials,
    empirical_density,
    local_success_rates,
    trial_weights,
    validated_ranking_width,
)
from vistask.grasp.reach import TrialRunner, Workspace, draw_reachable
from vistask.saving import load_state, save_state
from vistask.se3 import SE3KDE
from vistask.se3.kernels import check_bandwidth


@checked
@dataclass
class CycleStats:
    """Figures of one learning cycle."""

    cycle: int
    trials: int
    successes: int
    success_rate: float
    reachable_rate: float
    fallback_rate: float
    effective_sample_size: float
    particles: int
    seconds: float
    trials_per_minute: float


@checked
class GraspLearner:
    """Trial-and-error learning of an object-frame grasp density.

    Args:
        hypothesis: object-frame hypothesis density (the first proposal).
        workspace: reachability filter for the drawn grasps (None: no filter).
        c_rel: the weight offset c as a fraction of the mean proposal density at the trials.
        sigma_t, sigma_r: bandwidth of the empirical density (default: the hypothesis's).
        reliability: the power of the success rate around every success in the weights of
            the learned density, ``empirical``, the one a robot samples (see
            ``empirical_density``). 0 gives the paper's weights.
        exploration: the same power in the density the next cycle draws its trials from
            (default: the rate itself, or ``reliability`` where that is lower); a power below
            ``reliability`` keeps the trials on every kind of grasp that keeps succeeding,
            for the success rates (``success_rates``) to rank.
    """

    def __init__(
        self,
        hypothesis: SE3KDE,
        workspace: Workspace | None = None,
        c_rel: float = 1.0,
        sigma_t: float | None = None,
        sigma_r: float | None = None,
        reliability: float = RELIABILITY_POWER,
        exploration: float | None = None,
    ) -> None:
        if exploration is None:
            exploration = min(EXPLORATION_POWER, reliability)
        check_at_least(0, c_rel=c_rel, reliability=reliability, exploration=exploration)
        sigma_t = hypothesis.sigma_t if sigma_t is None else sigma_t
        sigma_r = hypothesis.sigma_r if sigma_r is None else sigma_r
        check_bandwidth(sigma_t, sigma_r)
        self.hypothesis = hypothesis
        self.workspace = workspace
        self.c_rel = c_rel
        self.sigma_t, self.sigma_r = sigma_t, sigma_r
        self.reliability = float(reliability)
        self.exploration = float(exploration)
        self.proposal = hypothesis
        self.proposals: list[SE3KDE] = []  # the density each cycle drew from
        self.trials = Trials()
        self.history: list[CycleStats] = []
        self._ranking: tuple[int, float | None] | None = None  # (trials, width) last found

    @property
    def empirical(self) -> SE3KDE | None:
        """The learned grasp density, to sample from (None before the first success)."""
        return self._density(self.reliability)

    def _explore(self) -> None:
        """Draw the next cycle from the successes weighted for exploration (once any)."""
        explored = self._density(self.exploration)
        if explored is not None:
            self.proposal = explored

    def _density(self, reliability: float) -> SE3KDE | None:
        density = empirical_density(
            self.trials,
            self.proposals,
            self.c_rel,
            self.sigma_t,
            self.sigma_r,
            reliability=reliability,
        )
        # The trials are kept on the CPU; the learned densities live where the hypothesis does.
        return None if density is None else density.to(self.hypothesis.device)

    def success_rates(self, grasps: torch.Tensor, width: float) -> torch.Tensor:
        """(M, 7) object-frame grasps -> (M,) the success rate of the trials around each.

        The kernel regression of ``local_success_rates`` over every trial so far (failures
        too), with kernels ``width`` times the empirical density's: how often grasps like
        them succeeded, where the density's value says how many successes lie near them."""
        if len(self.trials) == 0:
            raise ValueError("no trials yet: run a cycle before estimating success rates")
        w = trial_weights(self.trials, self.proposals, self.c_rel)
        sigma_t, sigma_r = width * self.sigma_t, width * self.sigma_r
        rates = local_success_rates(self.trials, w, sigma_t, sigma_r, at=grasps)
        return rates.to(grasps.device)

    @property
    def ranking_width(self) -> float | None:
        """The kernel width (times the empirical density's) at which ``rank`` rates grasps:
        the one whose success rates, from the trials of the cycles before each cycle, order
        that cycle's outcomes significantly better than chance (``validated_ranking_width``);
        None where none does, or before two cycles."""
        if len(self.history) < 2:
            return None
        if self._ranking is None or self._ranking[0] != len(self.trials):
            width = validated_ranking_width(
                self.trials, self.proposals, self.c_rel, self.sigma_t, self.sigma_r
            )
            self._ranking = (len(self.trials), width)
        return self._ranking[1]

    def rank(self, grasps: torch.Tensor) -> torch.Tensor:
        """(M, 7) object-frame grasps -> (M,) ratings for choosing the best of K candidates
        (``draw_reachable``'s ``score``): the success rates at ``ranking_width``, or zeros
        where it is None, so that the choice keeps the first candidate, a plain sample."""
        width = self.ranking_width
        if width is None:
            return torch.zeros(len(grasps), device=grasps.device)
        return self.success_rates(grasps, width)

    def run_cycle(
        self,
        runner: TrialRunner,
        n_trials: int,
        seeds: Sequence[int],
        generator: torch.Generator | None = None,
        progress: Callable[[int], None] | None = None,
        records: list[dict[str, Any]] | None = None,
    ) -> CycleStats:
        """Execute one cycle of ``n_trials`` grasps drawn from the current proposal.

        Args:
            runner: executes grasps, ``num_envs`` at a time.
            n_trials: trials in this cycle.
            seeds: at least as many object-placement seeds as trials.
            generator: random generator for drawing grasps.
            progress: called with the number of trials finished after each batch.
            records: if given, one record per trial is appended (see ``run_trials``).

        Returns:
            the cycle's figures; the proposal is replaced by the new empirical density
            weighted for exploration.
        """
        start = time.perf_counter()
        grasps, success, reach, from_fallback = run_trials(
            self.proposal,
            runner,
            n_trials,
            seeds,
            self.workspace,
            generator,
            progress,
            records=records,
            fallback=self.hypothesis,
        )
        # Grasps drawn from the hypothesis where the proposal had none in reach count as
        # draws of the hypothesis, the first cycle's proposal, in the importance weights.
        cycle = torch.where(from_fallback, 0, len(self.proposals))
        self.trials.add(grasps, success, cycle)
        self.proposals.append(self.proposal)
        self._explore()
        empirical = self.empirical
        seconds = time.perf_counter() - start
        stats = CycleStats(
            cycle=len(self.history),
            trials=len(success),
            successes=int(success.sum()),
            success_rate=float(success.float().mean()),
            reachable_rate=float(reach.float().mean()),
            fallback_rate=float(from_fallback.float().mean()),
            effective_sample_size=0.0 if empirical is None else empirical.effective_sample_size(),
            particles=0 if empirical is None else len(empirical),
            seconds=seconds,
            trials_per_minute=60.0 * len(success) / seconds,
        )
        self.history.append(stats)
        return stats

    def state_dict(self) -> dict[str, Any]:
        """Its settings and learned values as plain values and tensors (for ``save``)."""
        t = self.trials
        empirical = self.empirical
        return {
            "hypothesis": self.hypothesis.state_dict(),
            "empirical": None if empirical is None else empirical.state_dict(),
            "trials": {
                "grasps": t.grasps,
                "success": t.success,
                "cycle": t.cycle,
            },
            "proposals": [p.state_dict() for p in self.proposals],
            "c_rel": self.c_rel,
            "sigma_t": self.sigma_t,
            "sigma_r": self.sigma_r,
            "reliability": self.reliability,
            "exploration": self.exploration,
            "workspace": None if self.workspace is None else asdict(self.workspace),
            "history": [asdict(h) for h in self.history],
        }

    def save(self, path: str | Path) -> None:
        """Save the hypothesis, all trials (hence the empirical density) and the history."""
        save_state(path, "GraspLearner", self.state_dict())

    @classmethod
    def load(cls, path: str | Path) -> GraspLearner:
        """Load a learner written by ``save``, ready for its next cycle."""
        return cls.from_state_dict(load_state(path, "GraspLearner"))

    @classmethod
    def from_state_dict(cls, state: dict[str, Any]) -> GraspLearner:
        """The learner of ``state_dict()``: the same trials, proposals and history."""
        ws = state["workspace"]
        learner = cls(
            SE3KDE.from_state_dict(state["hypothesis"]),
            None if ws is None else Workspace(**{k: _untuple(v) for k, v in ws.items()}),
            c_rel=state["c_rel"],
            sigma_t=state["sigma_t"],
            sigma_r=state["sigma_r"],
            reliability=state["reliability"],
            exploration=state["exploration"],
        )
        learner.trials = Trials(**state["trials"])
        learner.proposals = [SE3KDE.from_state_dict(p) for p in state["proposals"]]
        learner.history = [CycleStats(**h) for h in state["history"]]
        learner._explore()
        return learner


def _untuple(v: Any) -> Any:
    return tuple(v) if isinstance(v, list) else v


def trial_seeds(generator: torch.Generator | None, n: int) -> list[int]:
    """One seed per trial, all derived from a single draw of ``generator``, so that the k-th
    trial's grasp is the same however the trials are batched over simulators."""
    device = generator.device if generator is not None else "cpu"
    base = int(torch.randint(2**62, (1,), generator=generator, device=device))
    return [base + k for k in range(n)]


RESET_FIELDS = ("object_pose", "estimated_pose", "pose_error_m", "pose_error_deg")
STEP_FIELDS = ("reason", "contact", "grasped", "lift_height")
"""Diagnostics of a runner's last reset (``last_reset_info``) and last execution
(``last_info``) that ``run_trials`` copies into its per-trial records, where present."""


@checked
def run_trials(
    density: SE3KDE,
    runner: TrialRunner,
    n_trials: int,
    seeds: Sequence[int],
    workspace: Workspace | None = None,
    generator: torch.Generator | None = None,
    progress: Callable[[int], None] | None = None,
    candidates: int = 1,
    records: list[dict[str, Any]] | None = None,
    fallback: SE3KDE | None = None,
    score: Callable[[torch.Tensor], torch.Tensor] | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Execute grasps drawn from an object-frame density on fresh object placements.

    Trial k places the objects with ``seeds[k]`` and draws its grasp with its own generator
    (``trial_seeds``), so the results for a given ``generator`` state do not depend on the
    runner's ``num_envs``. The last round is padded with repeats of its last placement when
    ``n_trials`` is not a multiple of ``num_envs``; the extra trials are not returned.

    Args:
        density: object-frame grasp density.
        runner: executes grasps, ``num_envs`` at a time.
        n_trials: number of trials.
        seeds: placement seeds, at least ``n_trials``.
        workspace: reachability filter (unreachable draws are redrawn; if none is found
            the first draw is executed and normally fails).
        generator: random generator for drawing grasps.
        progress: called with the number of trials finished after each batch.
        candidates, score: see ``draw_reachable`` (1 candidate: plain samples).
        records: if given, one dict per trial is appended: ``seed``, ``grasp`` (object
            frame), ``world_grasp``, ``reachable``, ``success``, and the runner's
            diagnostics named in ``RESET_FIELDS`` and ``STEP_FIELDS``, and ``fallback``.
        fallback: a density to draw from where ``density`` has no reachable grasp for a
            placement (a learned density that has concentrated on the grasps of one way
            the object lies may have none for another; the hypothesis still has).

    Returns:
        (N, 7) object-frame grasps as drawn (relative to the pose they were placed with),
        (N,) bool successes, (N,) bool reachable flags, (N,) bool drawn from ``fallback``.
    """
    B = runner.num_envs
    if len(seeds) < n_trials:
        raise ValueError(f"need {n_trials} placement seeds for {n_trials} trials, got {len(seeds)}")
    draw_seeds = trial_seeds(generator, math.ceil(n_trials / B) * B)
    device = density.points.device
    grasps, success, reach, from_fallback = [], [], [], []
    for start in range(0, n_trials, B):
        n = min(B, n_trials - start)
        batch = list(seeds[start : start + n])
        batch += batch[-1:] * (B - n)
        placed = runner.reset(batch).to(density.points)
        draws, used = [], torch.zeros(B, dtype=torch.bool)
        for j in range(B):
            g = torch.Generator(device).manual_seed(draw_seeds[start + j])
            pose = placed[j : j + 1]
            draw = draw_reachable(density, pose, workspace, g, candidates=candidates, score=score)
            if fallback is not None and not draw[2].all():
                draw = draw_reachable(
                    fallback, pose, workspace, g, candidates=candidates, score=score
                )
                used[j] = True
            draws.append(draw)
        local, world, ok = (torch.cat(parts) for parts in zip(*draws, strict=True))
        outcome, info = runner.execute(world)
        # Recorded relative to the pose the robot acted on (as a robot would); with
        # ground-truth poses this is the grasp relative to the object itself.
        grasps.append(local[:n])
        success.append(outcome.bool().cpu()[:n])
        reach.append(ok.cpu()[:n])
        from_fallback.append(used[:n])
        if records is not None:
            reset_info = getattr(runner, "last_reset_info", {})
            for j in range(n):
                record = {
                    "seed": int(batch[j]),
                    "grasp": local[j].tolist(),
                    "world_grasp": world[j].tolist(),
                    "reachable": bool(ok[j]),
                    "success": bool(outcome[j]),
                    "fallback": bool(used[j]),
                }
                record.update(_fields(reset_info, RESET_FIELDS, j))
                record.update(_fields(info, STEP_FIELDS, j))
                records.append(record)
        if progress is not None:
            progress(n)
    return torch.cat(grasps), torch.cat(success), torch.cat(reach), torch.cat(from_fallback)


def _fields(info: dict[str, Any], keys: Sequence[str], j: int) -> dict[str, Any]:
    """Entry ``j`` of each of ``keys`` in a batched info dict, as plain Python values."""
    out = {}
    for key in keys:
        if key in info:
            value = info[key][j]
            out[key] = value.tolist() if hasattr(value, "tolist") else value
    return out


@checked
def evaluate_density(
    density: SE3KDE,
    runner: TrialRunner,
    n_trials: int,
    seeds: Sequence[int],
    workspace: Workspace | None = None,
    generator: torch.Generator | None = None,
    progress: Callable[[int], None] | None = None,
    candidates: int = 1,
    records: list[dict[str, Any]] | None = None,
    fallback: SE3KDE | None = None,
    score: Callable[[torch.Tensor], torch.Tensor] | None = None,
) -> dict[str, float]:
    """Success rate of grasps drawn from ``density`` on the placements ``seeds``.

    ``candidates`` > 1 executes, per placement, the best of that many reachable draws by
    ``score`` (default: the likeliest; see ``draw_reachable``); 1 executes plain samples.
    ``records`` and ``fallback``: see ``run_trials``.

    Returns:
        ``success_rate``, ``trials``, ``reachable_rate``, ``fallback_rate``, ``seconds``,
        ``trials_per_minute``.
    """
    start = time.perf_counter()
    _, success, reach, from_fallback = run_trials(
        density,
        runner,
        n_trials,
        seeds,
        workspace,
        generator,
        progress=progress,
        candidates=candidates,
        records=records,
        fallback=fallback,
        score=score,
    )
    seconds = time.perf_counter() - start
    return {
        "success_rate": float(success.float().mean()),
        "trials": len(success),
        "reachable_rate": float(reach.float().mean()),
        "fallback_rate": float(from_fallback.float().mean()),
        "seconds": seconds,
        "trials_per_minute": 60.0 * len(success) / seconds,
    }
