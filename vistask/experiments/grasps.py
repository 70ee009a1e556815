"""The grasp-learning experiment behind ``scripts/learn_grasps.py``.

Per object: learn its object model from its own views, build the hypothesis density
(feature-induced from the model's patches, or from a scripted expert's demonstrations),
measure its success on held-out placements, learn an empirical density in cycles of trials,
measure that on the same held-out placements, and save densities, per-trial records,
TensorBoard scalars and pictures.

Every trial sees for itself by default: it renders the scene, estimates the object's pose
with NBP on the learned model (``vistask.envs.estimated_pose.EstimatedPose``), and acts on that
estimate; the simulator's true pose only scores the estimate. ``pose_source="true"`` acts on
the true poses instead (the ablation).

The robosuite environment is imported inside the functions: the rest of ``vistask.grasp``
does not need a simulator.
"""

from __future__ import annotations

import json
import statistics
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch

from vistask.checks import check_at_least, check_positive
from vistask.experiments.pose_scenes import (
    SUCCESS_ROTATION_DEG,
    SUCCESS_TRANSLATION_M,
    draw_estimate,
    learn_object_model,
)
from vistask.experiments.statistics import success_interval
from vistask.grasp.hypothesis import (
    demonstration_density,
    feature_hypothesis_density,
    scripted_teacher_grasps,
)
from vistask.grasp.importance import RELIABILITY_POWER
from vistask.grasp.learning import GraspLearner, evaluate_density
from vistask.grasp.plots import density_figure
from vistask.objects import ObjectModel
from vistask.parallel import cluster_address
from vistask.runs import check_same_settings, tensorboard, write_summary
from vistask.saving import load_state, save_state
from vistask.se3 import SE3KDE

CHECKPOINT = "GraspExperimentCheckpoint"  # the kind of file of an object's last cycle

# Placement seeds: learning and evaluation never share a placement. The held-out placements
# are the same for every run, so that runs are compared on one test; the learning placements
# depend on the run's seed and the cycle (at most 80 cycles of 100,000 trials each).
LEARN_SEED_BASE = 1_000_000
EVAL_SEED_BASE = 9_000_000
CYCLE_STRIDE = 100_000
SEED_STRIDE = 10_000_000


def learning_placements(seed: int, cycle: int, n: int) -> range:
    """Placement seeds of the ``n`` trials of learning cycle ``cycle`` of a run seeded ``seed``
    (>= 0): the same whatever the objects named, never one of another seed's or cycle's, or
    a held-out one (``EVAL_SEED_BASE`` onwards, below ``LEARN_SEED_BASE + SEED_STRIDE``).

    >>> learning_placements(0, 1, 3)
    range(1100000, 1100003)
    >>> learning_placements(2, 0, 2)
    range(21000000, 21000002)
    """
    base = LEARN_SEED_BASE + SEED_STRIDE * seed + CYCLE_STRIDE * cycle
    return range(base, base + n)


BEST_OF = 10
"""The "best of 10" evaluation executes the best of this many reachable draws: for the learned
density the one whose neighbours among the learning trials succeeded most often, at the kernel
width validated on the learning cycles, or the first, the plain draw, where no width ranks
their outcomes significantly better than chance (``GraspLearner.rank``); for the hypothesis
the likeliest."""

HYPOTHESES = ("feature", "demo")
POSE_SOURCES = ("estimate", "true")
DEFAULT_OBJECTS = (
    "box",
    "cereal",
    "milk",
    "can",
    "bottle",
    "bread",
    "lemon",
    "hammer",
    "square_nut",
    "round_nut",
)


def hypothesis_density(
    source: str,
    bounds: torch.Tensor,
    sigma_t: float,
    sigma_r: float,
    model: ObjectModel,
    generator,
) -> SE3KDE:
    """The object-frame hypothesis density from ``source`` ("feature": pairs of the object
    model's patches; "demo": the scripted teacher's grasps from the object's ``bounds``),
    with bandwidth (sigma_t, sigma_r)."""
    if source == "feature":
        return feature_hypothesis_density(model.patches, sigma_t, sigma_r, generator=generator)
    if source == "demo":
        teacher = scripted_teacher_grasps(bounds)
        return demonstration_density(teacher, sigma_t=sigma_t, sigma_r=sigma_r, generator=generator)
    raise ValueError(f"unknown hypothesis source {source!r}; use 'feature' or 'demo'")


def pose_failure_share(records: Sequence[dict[str, Any]]) -> float | None:
    """Among failed trials, the share whose pose estimate was off by more than the pose
    benchmark's success limits (2 cm or 15 degrees); None without estimates or failures."""
    failed = [r for r in records if not r["success"] and "pose_error_m" in r]
    if not failed:
        return None
    off = [
        r["pose_error_m"] >= SUCCESS_TRANSLATION_M or r["pose_error_deg"] >= SUCCESS_ROTATION_DEG
        for r in failed
    ]
    return sum(off) / len(off)


class GraspExperiment:
    """Learn grasp densities by trial and error on a robosuite Panda, object by object.

    ``GraspExperiment(objects=("box",), cycles=2).run(out)``. The arguments are kept as
    attributes of the same names.

    Args:
        objects: object kinds: presets, robosuite object classes or MJCF files
            (``vistask.envs.objects.object_spec``).
        hypothesis: "feature" (patch pairs) or "demo" (scripted expert + noise).
        pose_source: "estimate" (every trial estimates the object's pose from its cameras
            with NBP and acts on that) or "true" (the simulator's poses: the ablation).
        cycles: learning cycles per object.
        trials_per_cycle: trials per cycle (cycles * trials_per_cycle is the budget).
        eval_trials: held-out trials for each of the four evaluations (hypothesis and
            empirical densities, sampled and best of ``BEST_OF``).
        n_distractors: other objects on the table in every trial.
        tip_probability: chance that an object that may tip lies on a side.
        num_envs: simulators running trials side by side (local processes, a single one in
            this process, or Ray actors with ``address``); the results do not depend on it.
        sigma_t, sigma_r: bandwidth of the hypothesis density.
        empirical_sigma_t, empirical_sigma_r: bandwidth of the empirical density; smaller
            than the hypothesis's because its particles are already noisy successful draws,
            and a wide kernel would add that noise again every cycle (the box's scripted
            top-down grasp, blurred by 1 cm and 0.25 rad, succeeds in 26 of 40 placements;
            by 5 mm and 0.15 rad in 37 of 40). Learned with 2 mm and 0.05 rad, sampled
            grasps of the box, bottle and can succeeded 0.04-0.05 more often than with 3 mm
            and 0.08 rad.
        c_rel: importance-weight offset relative to the mean proposal density.
        reliability: the power of the local success rate in every success's weight in the
            learned density (``GraspLearner``): higher concentrates it on the grasps that
            succeed most often; 0 gives the paper's weights. Learning draws its trials with
            the rate itself, or this power where it is lower.
        seed: random seed (>= 0) of the grasp draws and the learning placements
            (``learning_placements``); the held-out placements are the same for every seed.
        address: a Ray cluster to run the simulators on as actors (``RayGraspTrials``;
            default ``RAY_ADDRESS``); None runs them as local processes, a single one in
            this process (``VectorGraspTrials``, which started faster than local Ray actors:
            see ``scripts/bench_parallel.py``).

    Raises:
        ValueError: no object, a hypothesis or pose source not among ``HYPOTHESES`` /
            ``POSE_SOURCES``, a count below 1, a bandwidth not positive, or c_rel or seed
            negative.
    """

    def __init__(
        self,
        objects: Sequence[str] = DEFAULT_OBJECTS,
        hypothesis: str = "feature",
        pose_source: str = "estimate",
        cycles: int = 5,
        trials_per_cycle: int = 60,
        eval_trials: int = 100,
        n_distractors: int = 2,
        tip_probability: float = 0.3,
        num_envs: int = 2,
        sigma_t: float = 0.01,
        sigma_r: float = 0.25,
        empirical_sigma_t: float = 0.002,
        empirical_sigma_r: float = 0.05,
        c_rel: float = 1.0,
        reliability: float = RELIABILITY_POWER,
        seed: int = 0,
        address: str | None = None,
    ) -> None:
        if not objects or isinstance(objects, str):
            raise ValueError(f"objects must list at least one object kind, got {objects!r}")
        from vistask.envs.objects import MAX_DISTRACTORS, distinct_object_specs

        distinct_object_specs("objects", objects)
        if n_distractors > MAX_DISTRACTORS:
            raise ValueError(f"n_distractors must be in 0..{MAX_DISTRACTORS}, got {n_distractors}")
        if hypothesis not in HYPOTHESES:
            raise ValueError(f"hypothesis must be one of {HYPOTHESES}, got {hypothesis!r}")
        if pose_source not in POSE_SOURCES:
            raise ValueError(f"pose_source must be one of {POSE_SOURCES}, got {pose_source!r}")
        check_at_least(
            1,
            cycles=cycles,
            trials_per_cycle=trials_per_cycle,
            eval_trials=eval_trials,
            num_envs=num_envs,
        )
        check_positive(
            sigma_t=sigma_t,
            sigma_r=sigma_r,
            empirical_sigma_t=empirical_sigma_t,
            empirical_sigma_r=empirical_sigma_r,
        )
        check_at_least(
            0, c_rel=c_rel, reliability=reliability, n_distractors=n_distractors, seed=seed
        )
        if not 0.0 <= tip_probability <= 1.0:
            raise ValueError(f"tip_probability must be in [0, 1], got {tip_probability}")
        self.objects = tuple(str(o) for o in objects)
        self.hypothesis = hypothesis
        self.pose_source = pose_source
        self.cycles = cycles
        self.trials_per_cycle = trials_per_cycle
        self.eval_trials = eval_trials
        self.n_distractors = n_distractors
        self.tip_probability = tip_probability
        self.num_envs = num_envs
        self.sigma_t = sigma_t
        self.sigma_r = sigma_r
        self.empirical_sigma_t = empirical_sigma_t
        self.empirical_sigma_r = empirical_sigma_r
        self.c_rel = c_rel
        self.reliability = reliability
        self.seed = seed
        self.address = address

    def settings(self) -> dict[str, Any]:
        """The arguments that decide the results (not ``num_envs`` and ``address``, which
        decide only where the trials run)."""
        return {k: v for k, v in vars(self).items() if k not in ("num_envs", "address")}

    def env_kwargs(self) -> dict[str, Any]:
        """``GraspTrialEnv`` arguments of every trial."""
        return {"n_distractors": self.n_distractors, "tip_probability": self.tip_probability}

    def _runner(self, kind: str, model: ObjectModel | None):
        from vistask.envs.grasp_runners import RayGraspTrials, VectorGraspTrials

        if cluster_address(self.address) is None:
            return VectorGraspTrials(kind, self.num_envs, model, **self.env_kwargs())
        return RayGraspTrials(kind, self.num_envs, self.address, model, **self.env_kwargs())

    def learn_object(
        self, kind: str, model: ObjectModel, out: Path, writer=None, progress=None
    ) -> dict[str, Any]:
        """Run hypothesis evaluation, learning and empirical evaluation for one object.

        Args:
            kind: object kind.
            model: its object model (the hypothesis's patches; the pose estimates).
            out: directory for this object's files (densities, learner, records, pictures).
            writer: optional TensorBoard ``SummaryWriter`` (scalars under the object's name).
            progress: optional tqdm bar advanced by one per trial.

        Returns:
            the object's summary (see ``summarize_object``).
        """
        out.mkdir(parents=True, exist_ok=True)
        name = model.name
        generator = torch.Generator().manual_seed(self.seed)
        start = time.perf_counter()
        runner = self._runner(kind, model if self.pose_source == "estimate" else None)
        try:
            bounds = torch.as_tensor(runner.object_bounds, dtype=torch.float32)
            step = (lambda n: progress.update(n)) if progress is not None else None
            eval_seeds = range(EVAL_SEED_BASE, EVAL_SEED_BASE + self.eval_trials)
            records: list[dict[str, Any]] = []

            def evaluate(
                density: SE3KDE, phase: str, fallback: SE3KDE | None = None, score=None
            ) -> None:
                """Plain draws and best-of-K draws (the best by ``score``, default the
                likeliest) on the same held-out placements. Both draw from the same seeds, so
                that a best of K keeping its first candidate executes the plain draw."""
                state = generator.get_state()
                for suffix, k in (("", 1), (f"_best_of_{BEST_OF}", BEST_OF)):
                    generator.set_state(state)
                    found: list[dict[str, Any]] = []
                    evaluate_density(
                        density,
                        runner,
                        self.eval_trials,
                        eval_seeds,
                        runner.workspace,
                        generator,
                        step,
                        candidates=k,
                        records=found,
                        fallback=fallback,
                        score=score if k > 1 else None,
                    )
                    records.extend({"phase": phase + suffix, **f} for f in found)

            checkpoint = out / "checkpoint.pt"
            if checkpoint.exists():  # resume after the last finished cycle
                saved = load_state(checkpoint, CHECKPOINT)
                learner = GraspLearner.from_state_dict(saved["learner"])
                hypothesis, records = learner.hypothesis, saved["records"]
                generator.set_state(saved["generator"])
                if step is not None:
                    step(2 * self.eval_trials + len(learner.trials))
            else:
                hypothesis = hypothesis_density(
                    self.hypothesis, bounds, self.sigma_t, self.sigma_r, model, generator
                )
                hypothesis.save(out / "hypothesis.pt")
                evaluate(hypothesis, "hypothesis")
                learner = GraspLearner(
                    hypothesis,
                    runner.workspace,
                    c_rel=self.c_rel,
                    sigma_t=self.empirical_sigma_t,
                    sigma_r=self.empirical_sigma_r,
                    reliability=self.reliability,
                )
            n = self.trials_per_cycle
            for k in range(len(learner.history), self.cycles):
                found = []
                placements = learning_placements(self.seed, k, n)
                stats = learner.run_cycle(runner, n, placements, generator, step, records=found)
                records.extend({"phase": "learning", "cycle": k, **f} for f in found)
                # Everything the next cycle needs, so that a stop loses at most this cycle.
                state = {
                    "learner": learner.state_dict(),
                    "generator": generator.get_state(),
                    "records": records,
                }
                save_state(checkpoint, CHECKPOINT, state)
                if writer is not None:
                    for key in ("success_rate", "effective_sample_size", "trials", "particles"):
                        writer.add_scalar(f"{name}/{key}", getattr(stats, key), k)
                    writer.add_scalar(f"{name}/cumulative_trials", len(learner.trials), k)
                    errors = [f["pose_error_m"] for f in found if "pose_error_m" in f]
                    if errors:
                        writer.add_scalar(
                            f"{name}/pose_error_cm", 100 * statistics.fmean(errors), k
                        )
            learner.save(out / "learner.pt")
            empirical = learner.empirical
            if empirical is not None:
                empirical.save(out / "empirical.pt")
                # As in learning: the hypothesis where the learned density reaches nothing.
                # Its best of K: the candidate whose neighbours among the trials succeeded
                # most often, where the learning cycles validate such a ranking.
                evaluate(empirical, "empirical", hypothesis, learner.rank)
            density_figure(
                [("hypothesis", hypothesis), ("empirical", empirical)],
                model.patches.positions,
                model.patches.colors[:, 0],
                out / "densities.png",
                title=name,
            )
        finally:
            runner.close()
        with (out / "trials.jsonl").open("w") as f:
            f.writelines(json.dumps(r) + "\n" for r in records)
        summary = summarize_object(records, learner, self)
        summary["seconds"] = time.perf_counter() - start
        if writer is not None:
            for key in ("hypothesis_success", "empirical_success", f"best_of_{BEST_OF}_success"):
                writer.add_scalar(f"{name}/{key}", summary[key], 0)
            for step, r in enumerate(records):  # every trial, in the order they ran
                writer.add_scalar(f"{name}/trials/success", float(r["success"]), step)
                if "pose_error_m" in r:
                    writer.add_scalar(f"{name}/trials/pose_error_cm", 100 * r["pose_error_m"], step)
                    writer.add_scalar(f"{name}/trials/pose_error_deg", r["pose_error_deg"], step)
        return summary

    def run(self, out: Path, pictures: int = 3) -> dict[str, Any]:
        """All objects; writes ``out/summary.json`` (the settings under ``config``, the
        figures per object under ``objects``), per object its files in ``out/<name>/``, and
        TensorBoard logs.

        The object models are learned first, before any robot simulator runs in this
        process (``out/<name>/model.pt``). A folder that a stopped run left is resumed:
        objects already finished (``<name>/summary.json``) are kept, the one in progress
        continues after its last finished cycle (``<name>/checkpoint.pt``), with the results
        of a run straight through. The settings must be those of the stopped run
        (``config.json``), but for the objects: each object's trials are the same whatever
        the others, so a finished run given more objects learns only the new ones.

        Args:
            out: the run's folder.
            pictures: per object, held-out scenes drawn with the estimated and the true pose
                (``<name>/pose_<seed>.png``).
        """
        from tqdm import tqdm

        from vistask.envs.hand_fit import warn_misfits
        from vistask.envs.objects import check_same_object, object_name, object_spec

        out.mkdir(parents=True, exist_ok=True)
        check_same_settings(out / "config.json", self.settings(), free=("objects",))
        names = {kind: object_name(kind) for kind in self.objects}
        for kind, name in names.items():
            check_same_object(out / name, kind)
            warn_misfits(object_spec(kind), self.tip_probability)
        models = {}
        for kind, name in names.items():
            path = out / name / "model.pt"
            if path.exists():
                models[kind] = ObjectModel.load(path)
            else:
                models[kind] = learn_object_model(kind, self.tip_probability > 0)
                path.parent.mkdir(parents=True, exist_ok=True)
                models[kind].save(path)
        per_object = self.cycles * self.trials_per_cycle + 4 * self.eval_trials
        writer = tensorboard(out)
        results: dict[str, Any] = {}
        try:
            with tqdm(total=per_object * len(self.objects), unit="trial") as bar:
                for kind, name in names.items():
                    bar.set_description(name)
                    done = out / name / "summary.json"
                    if done.exists():
                        results[name] = json.loads(done.read_text())
                        bar.update(per_object)
                        continue
                    results[name] = self.learn_object(kind, models[kind], out / name, writer, bar)
                    write_summary(done, results[name])
        finally:
            writer.close()
        if pictures:
            for kind, name in names.items():
                seeds = range(EVAL_SEED_BASE, EVAL_SEED_BASE + pictures)
                pose_pictures(kind, models[kind], seeds, out / name, self.env_kwargs())
        summary = {"config": dict(vars(self)), "objects": results}
        write_summary(out / "summary.json", summary)
        success_figure(results, out / "success.png")
        return summary


def summarize_object(
    records: Sequence[dict[str, Any]], learner: GraspLearner, experiment: GraspExperiment
) -> dict[str, Any]:
    """An object's summary from its per-trial records.

    Returns:
        ``hypothesis_success``, ``hypothesis_best_of_10_success``, ``empirical_success``,
        ``best_of_10_success`` (held-out success rates) with 95% Wilson intervals under the
        same names plus ``_ci``; ``trials`` (learning), ``pose_source``,
        ``mean_pose_error_cm`` and ``mean_pose_error_deg`` over every trial (None with true
        poses), ``pose_failure_share`` (of the failed held-out trials of the learned
        density, those whose pose estimate was off: see ``pose_failure_share``),
        ``failure_reasons`` of those trials, ``fallback_share`` (of the learned density's
        sampled held-out trials, those drawn from the hypothesis because the learned density
        had no reachable grasp), ``learning_success``, ``trials_per_minute``,
        ``ranking_width`` (``GraspLearner.ranking_width``: None, the best of 10 is a sample),
        ``empirical_particles``, ``empirical_ess`` and the per-cycle figures.
    """
    summary: dict[str, Any] = {
        "hypothesis_source": experiment.hypothesis,
        "pose_source": experiment.pose_source,
    }
    best = f"_best_of_{BEST_OF}"
    phases = {
        "hypothesis_success": "hypothesis",
        f"hypothesis{best}_success": f"hypothesis{best}",
        "empirical_success": "empirical",
        f"best_of_{BEST_OF}_success": f"empirical{best}",
    }
    for key, phase in phases.items():
        rows = [r for r in records if r["phase"] == phase]
        wins = sum(r["success"] for r in rows)
        summary[key] = wins / len(rows) if rows else 0.0
        summary[f"{key}_ci"] = success_interval(wins, len(rows)) if rows else [0.0, 0.0]
    errors = [r for r in records if "pose_error_m" in r]
    summary["mean_pose_error_cm"] = (
        100 * statistics.fmean(r["pose_error_m"] for r in errors) if errors else None
    )
    summary["mean_pose_error_deg"] = (
        statistics.fmean(r["pose_error_deg"] for r in errors) if errors else None
    )
    held_out = [r for r in records if r["phase"] == "empirical"]
    summary["pose_failure_share"] = pose_failure_share(held_out)
    reasons = [r.get("reason", "") for r in held_out if not r["success"]]
    summary["failure_reasons"] = {k: reasons.count(k) for k in sorted(set(reasons))}
    summary["fallback_share"] = (
        sum(r.get("fallback", False) for r in held_out) / len(held_out) if held_out else 0.0
    )
    learn_seconds = sum(h.seconds for h in learner.history)
    empirical = learner.empirical
    summary.update(
        trials=len(learner.trials),
        trials_per_minute=60.0 * len(learner.trials) / learn_seconds,
        eval_trials_per_measure=experiment.eval_trials,
        learning_success=float(learner.trials.success.float().mean()),
        ranking_width=learner.ranking_width,
        empirical_particles=0 if empirical is None else len(empirical),
        empirical_ess=0.0 if empirical is None else empirical.effective_sample_size(),
        cycles=[asdict(h) for h in learner.history],
    )
    return summary


def success_figure(objects: dict[str, dict[str, Any]], path: Path) -> None:
    """Bars of held-out success per object, before (hypothesis) and after learning
    (empirical), sampled and best of ``BEST_OF``, with their 95% intervals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    keys = [
        ("hypothesis_success", "hypothesis, sampled"),
        (f"hypothesis_best_of_{BEST_OF}_success", f"hypothesis, best of {BEST_OF}"),
        ("empirical_success", "learned, sampled"),
        (f"best_of_{BEST_OF}_success", f"learned, best of {BEST_OF}"),
    ]
    names = list(objects)
    x = np.arange(len(names))
    width = 0.8 / len(keys)
    fig, ax = plt.subplots(figsize=(1.6 * len(names) + 2, 3.6))
    for i, (key, label) in enumerate(keys):
        values = np.array([objects[n][key] for n in names])
        ci = np.array([objects[n][f"{key}_ci"] for n in names]).T
        ax.bar(x + (i - 1.5) * width, values, width, label=label)
        ax.errorbar(
            x + (i - 1.5) * width,
            values,
            [values - ci[0], ci[1] - values],
            fmt="none",
            ecolor="k",
            lw=0.8,
        )
    ax.set_xticks(x, names)
    ax.set_ylim(0, 1)
    ax.set_ylabel("success on held-out placements")
    # Above the axes: bars near 1 leave no room inside.
    ax.legend(fontsize=7, ncol=len(keys), loc="lower center", bbox_to_anchor=(0.5, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def pose_pictures(
    kind: str, model: ObjectModel, seeds: Sequence[int], out: Path, env_kwargs: dict[str, Any]
) -> list[Path]:
    """Per placement seed, ``out/pose_<seed>.png``: the first camera's image with the
    model drawn at the estimated pose (left) and at the true pose (right)."""
    import cv2
    import numpy as np

    from vistask.envs.grasp_runners import make_trial_env
    from vistask.envs.grasp_trial import observation_views

    env = make_trial_env(kind, model, **env_kwargs)
    paths = []
    try:
        for seed in seeds:
            obs, info = env.reset(seed=seed)
            view = next(iter(observation_views(obs, env.unwrapped.cameras).values()))
            panels = [
                draw_estimate(view, model, torch.as_tensor(info[key]))
                for key in ("estimated_pose", "object_pose")
            ]
            path = out / f"pose_{seed}.png"
            cv2.imwrite(str(path), np.concatenate(panels, axis=1)[:, :, ::-1])
            paths.append(path)
    finally:
        env.close()
    return paths


def format_table(summary: dict[str, Any]) -> str:
    """A text table of the per-object headline figures."""
    best = f"best of {BEST_OF}"
    width = max(8, *map(len, summary["objects"]))
    rows = [
        f"{'':<{width + 9}} {'hypothesis':^21} {'empirical':^21}",
        f"{'object':<{width}} {'poses':<8} {'sampled':>10} {best:>10} {'sampled':>10} {best:>10} "
        f"{'trials':>6} {'pose err':>9} {'trials/min':>10}",
    ]
    for name, r in summary["objects"].items():
        error = r["mean_pose_error_cm"]
        error_text = "-" if error is None else f"{error:.2f} cm"
        rows.append(
            f"{name:<{width}} {r['pose_source']:<8} {r['hypothesis_success']:>10.2f} "
            f"{r[f'hypothesis_best_of_{BEST_OF}_success']:>10.2f} "
            f"{r['empirical_success']:>10.2f} {r[f'best_of_{BEST_OF}_success']:>10.2f} "
            f"{r['trials']:>6d} {error_text:>9} {r['trials_per_minute']:>10.1f}"
        )
    return "\n".join(rows)
