"""How well a learned grasp density's best-of-K draw is ranked, behind
``scripts/bench_grasp_ranking.py``.

For an object that ``scripts/learn_grasps.py`` finished, every one of the K candidates its
best-of-K evaluation drew on each held-out placement is executed on that placement, acting
on the pose the run estimated there (recorded in ``trials.jsonl``). With all outcomes known,
any ranking of the candidates can be scored at once: here the success rates of the learning
trials (``local_success_rates``) at several kernel widths, against picking the first
candidate, the average candidate, and the best any ranking could do (some candidate
succeeds), and the learner's own choice (``GraspLearner.rank``: the width validated on its
learning cycles, or the first candidate). Trials are deterministic for a placement and a grasp,
so that choice scores what the run's own best-of-K evaluation measured.

The outcomes are kept in ``<object>/candidates.pt`` of the run, so that ranking again costs
no simulation.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from functools import partial
from pathlib import Path
from typing import Any

import torch

from vistask.experiments.grasps import BEST_OF, CHECKPOINT, EVAL_SEED_BASE
from vistask.grasp.importance import RANKING_WIDTHS
from vistask.grasp.learning import GraspLearner, trial_seeds
from vistask.grasp.reach import draw_candidates
from vistask.runs import write_summary
from vistask.saving import load_state, save_state

CANDIDATES = "GraspCandidateOutcomes"  # the kind of file of an object's candidate outcomes


def best_of_k_draws(
    learner: GraspLearner, generator_state: torch.Tensor, poses: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The K candidates per placement that the run's best-of-K evaluation of the learned
    density drew, in its order.

    ``GraspExperiment.learn_object`` evaluates the learned density after the last cycle,
    sampled and then best of K, both from the same seeds, one per trial drawn from the run's
    generator (``trial_seeds``); the trial's own generator then draws its candidates, from
    the hypothesis where the learned density has none in reach (as ``run_trials``).

    Args:
        learner: the learner of the run's checkpoint.
        generator_state: the run's generator state after the last cycle (the checkpoint's).
        poses: (P, 7) the poses acted on at the held-out placements, in order.

    Returns:
        (P, K, 7) object-frame candidates, (P, K, 7) world candidates, (P, K) bool reachable.
    """
    generator = torch.Generator()
    generator.set_state(generator_state)
    seeds = trial_seeds(generator, len(poses))
    draws = []
    for pose, seed in zip(poses, seeds, strict=True):
        g = torch.Generator().manual_seed(seed)
        for density in (learner.empirical, learner.hypothesis):
            drawn = draw_candidates(density, pose[None], learner.workspace, g, candidates=BEST_OF)
            if drawn[2].any():
                break
        draws.append([part[:, 0] for part in drawn])  # (K, .) of this placement
    local, world, ok = (torch.stack(parts) for parts in zip(*draws, strict=True))
    return local, world, ok


def candidate_outcomes(
    folder: Path, kind: str, checkpoint: dict[str, Any], placements: int | None = None
) -> dict[str, Any]:
    """Execute every best-of-K candidate of a finished object's held-out placements.

    Args:
        folder: the object's folder in a ``learn_grasps.py`` run (``trials.jsonl``); the
            outcomes are saved there as ``candidates.pt`` and reused.
        kind: the object kind to simulate (as given to ``learn_grasps.py``).
        checkpoint: the state of the object's ``checkpoint.pt`` (its learner and generator).
        placements: the first this many held-out placements (default: all).

    Returns:
        ``local`` (P, K, 7) candidates, ``ok`` (P, K) reachable, ``success`` (P, K) bool,
        ``seeds`` (P,) placement seeds.
    """
    from vistask.envs.grasp_runners import VectorGraspTrials

    cached = folder / "candidates.pt"
    if cached.exists():
        saved = load_state(cached, CANDIDATES)
        if placements is None or len(saved["seeds"]) >= placements:
            return {k: v[:placements] for k, v in saved.items()}
    learner = GraspLearner.from_state_dict(checkpoint["learner"])
    config = json.loads((folder.parent / "config.json").read_text())
    estimates = {}
    with (folder / "trials.jsonl").open() as f:
        for line in f:
            record = json.loads(line)
            if record["phase"] == "empirical":
                estimates[record["seed"]] = record.get("estimated_pose", record["object_pose"])
    if not estimates:
        raise ValueError(f"{folder} has no held-out trials of a learned density: finish the run")
    seeds = sorted(estimates)[:placements]
    poses = torch.tensor([estimates[s] for s in seeds], dtype=torch.float32)
    local, world, ok = best_of_k_draws(learner, checkpoint["generator"], poses)
    env_kwargs = {k: config[k] for k in ("n_distractors", "tip_probability")}
    runner = VectorGraspTrials(kind, 2, None, **env_kwargs)
    success = torch.zeros(ok.shape, dtype=torch.bool)
    try:
        from tqdm import tqdm

        for i in tqdm(range(len(seeds)), desc=folder.name, unit="placement"):
            for j in range(0, BEST_OF, 2):  # two candidates at a time, each on a new reset
                pair = world[i, j : j + 2]
                runner.reset([seeds[i], seeds[i]])
                outcome = runner.execute(pair.expand(2, 7) if len(pair) == 1 else pair)[0]
                success[i, j : j + 2] = outcome[: len(pair)]
    finally:
        runner.close()
    result = {"local": local, "ok": ok, "success": success, "seeds": torch.tensor(seeds)}
    save_state(cached, CANDIDATES, result)
    return result


def ranked_success(
    learner: GraspLearner, outcomes: dict[str, Any], widths: Sequence[float] = RANKING_WIDTHS
) -> dict[str, float]:
    """Best-of-K success when the candidates are ranked by the learning trials' success rates
    at each of ``widths`` (times the density's kernels), the learner's own ranking
    (``GraspLearner.rank``), and three references: the first candidate, the average
    candidate, and any candidate (the best a ranking could do)."""
    local, ok, success = outcomes["local"], outcomes["ok"], outcomes["success"]
    rows = torch.arange(len(success))
    rankings = {f"width {k:g}": partial(learner.success_rates, width=k) for k in widths}
    rankings["validated"] = learner.rank
    result = {}
    for name, rate in rankings.items():
        rates = rate(local.reshape(-1, 7)).view(ok.shape)
        pick = torch.where(ok, rates, -1.0).argmax(dim=1)
        result[name] = _rate(success[rows, pick])
    result["first"] = _rate(success[:, 0])
    result["mean"] = _rate(success)
    result["any"] = _rate(success.any(dim=1))
    return result


def _rate(success: torch.Tensor) -> float:
    return round(success.double().mean().item(), 4)


def bench_grasp_ranking(
    runs: Sequence[Path], placements: int | None = None, out: Path | None = None
) -> dict[str, dict[str, float]]:
    """Rank the best-of-K candidates of every finished object in ``runs``; print a table
    and write it as JSON (``out``, default ``<first run>/ranking.json``).

    Returns:
        per ``<run>/<object>`` the figures of ``ranked_success``.
    """
    from vistask.envs.objects import object_name

    table = {}
    for run in runs:
        kinds = json.loads((run / "config.json").read_text())["objects"]
        for kind in kinds:
            folder = run / object_name(kind)
            if not (folder / "trials.jsonl").exists():
                continue
            checkpoint = load_state(folder / "checkpoint.pt", CHECKPOINT)
            outcomes = candidate_outcomes(folder, kind, checkpoint, placements)
            learner = GraspLearner.from_state_dict(checkpoint["learner"])
            table[f"{run.name}/{folder.name}"] = ranked_success(learner, outcomes)
    if not table:
        raise ValueError(f"no finished object in {[str(r) for r in runs]}")
    names = list(next(iter(table.values())))
    print(f"{'best of ' + str(BEST_OF):34s}" + "".join(f"{n:>10s}" for n in names))
    for key, row in table.items():
        print(f"{key:34s}" + "".join(f"{row[n]:10.2f}" for n in names))
    path = out or runs[0] / "ranking.json"
    write_summary(path, {"placements": placements, "held_out_seed_base": EVAL_SEED_BASE, **table})
    print(f"wrote {path}")
    return table
