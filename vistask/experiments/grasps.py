"""The grasp-learning experiment behind ``scripts/learn_grasps.py``.

Per object: build the hypothesis density (feature-induced from the object's patches, or from
a scripted expert's demonstrations), measure its success on held-out object placements,
learn an empirical density in cycles of trials, measure that on the same held-out
placements, and save densities, TensorBoard scalars and pictures. Object poses are the
simulator's ground truth (the NBP path is the ``pose_fn`` hook of ``GraspLearner``).

The robosuite environment is imported inside the functions: the rest of ``vistask.grasp``
does not need a simulator.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch

from vistask.checks import check_at_least, check_positive
from vistask.grasp.hypothesis import (
    demonstration_density,
    feature_hypothesis_density,
    scripted_teacher_grasps,
)
from vistask.grasp.learning import GraspLearner, evaluate_density
from vistask.grasp.plots import density_figure
from vistask.parallel import cluster_address
from vistask.runs import check_same_settings, tensorboard, write_summary
from vistask.saving import load_state, save_state
from vistask.se3 import SE3KDE

CHECKPOINT = "GraspExperimentCheckpoint"  # the kind of file of an object's last cycle

# Placement seeds: learning and evaluation never share a placement.
LEARN_SEED_BASE = 1_000_000
EVAL_SEED_BASE = 9_000_000


def object_patches_for(kind: str):
    """Object-frame patches of ``kind`` from the tabletop front end (None if unavailable)."""
    from vistask.envs.tabletop import OBJECTS, object_patches

    if kind not in OBJECTS:
        return None
    return object_patches(kind, voxel=0.004)


HYPOTHESES = ("feature", "demo")


def hypothesis_density(
    kind: str,
    source: str,
    bounds: torch.Tensor,
    sigma_t: float,
    sigma_r: float,
    patches,
    generator,
) -> SE3KDE:
    """The object-frame hypothesis density of ``kind`` from ``source`` ("feature": pairs of
    ``patches``; "demo": the scripted teacher's grasps from the object's ``bounds``), with
    bandwidth (sigma_t, sigma_r)."""
    if source == "feature":
        if patches is None:
            raise ValueError(f"no patches for {kind!r}: use the 'demo' hypothesis")
        return feature_hypothesis_density(patches, sigma_t, sigma_r, generator=generator)
    if source == "demo":
        teacher = scripted_teacher_grasps(bounds)
        return demonstration_density(teacher, sigma_t=sigma_t, sigma_r=sigma_r, generator=generator)
    raise ValueError(f"unknown hypothesis source {source!r}; use 'feature' or 'demo'")


class GraspExperiment:
    """Learn grasp densities by trial and error on a robosuite Panda, object by object.

    ``GraspExperiment(objects=("box",), cycles=2).run(out)``. The arguments are kept as
    attributes of the same names.

    Args:
        objects: object kinds (``vistask.envs.grasp_trial.GRASP_OBJECTS``).
        hypothesis: "feature" (patch pairs) or "demo" (scripted expert + noise).
        cycles: learning cycles per object.
        trials_per_cycle: trials per cycle (cycles * trials_per_cycle is the budget).
        eval_trials: held-out trials for each of the hypothesis and empirical densities.
        num_envs: simulators running trials side by side (local processes, or Ray actors
            with ``address``); the results do not depend on it.
        sigma_t, sigma_r: bandwidth of the hypothesis density.
        empirical_sigma_t, empirical_sigma_r: bandwidth of the empirical density; smaller
            than the hypothesis's because its particles are already noisy successful draws,
            and a wide kernel would add that noise again every cycle.
        c_rel: importance-weight offset relative to the mean proposal density.
        candidates: the "best of K" evaluation executes the likeliest of this many reachable
            draws (both densities are also evaluated on plain draws).
        seed: random seed of grasp draws.
        address: a Ray cluster to run the simulators on as actors (``RayGraspTrials``;
            default ``RAY_ADDRESS``); None runs them as local processes
            (``VectorGraspTrials``, which started faster than local Ray actors: see
            ``scripts/bench_parallel.py``).

    Raises:
        ValueError: no object, a hypothesis source other than ``HYPOTHESES``, a count below 1,
            a bandwidth not positive, or c_rel negative.
    """

    def __init__(
        self,
        objects: Sequence[str] = ("box", "can", "bread"),
        hypothesis: str = "feature",
        cycles: int = 5,
        trials_per_cycle: int = 60,
        eval_trials: int = 100,
        num_envs: int = 2,
        sigma_t: float = 0.01,
        sigma_r: float = 0.25,
        empirical_sigma_t: float = 0.005,
        empirical_sigma_r: float = 0.15,
        c_rel: float = 1.0,
        candidates: int = 10,
        seed: int = 0,
        address: str | None = None,
    ) -> None:
        if not objects:
            raise ValueError(f"objects must name at least one object kind, got {objects!r}")
        if hypothesis not in HYPOTHESES:
            raise ValueError(f"hypothesis must be one of {HYPOTHESES}, got {hypothesis!r}")
        check_at_least(
            1,
            cycles=cycles,
            trials_per_cycle=trials_per_cycle,
            eval_trials=eval_trials,
            num_envs=num_envs,
            candidates=candidates,
        )
        check_positive(
            sigma_t=sigma_t,
            sigma_r=sigma_r,
            empirical_sigma_t=empirical_sigma_t,
            empirical_sigma_r=empirical_sigma_r,
        )
        check_at_least(0, c_rel=c_rel)
        self.objects = tuple(objects)
        self.hypothesis = hypothesis
        self.cycles = cycles
        self.trials_per_cycle = trials_per_cycle
        self.eval_trials = eval_trials
        self.num_envs = num_envs
        self.sigma_t = sigma_t
        self.sigma_r = sigma_r
        self.empirical_sigma_t = empirical_sigma_t
        self.empirical_sigma_r = empirical_sigma_r
        self.c_rel = c_rel
        self.candidates = candidates
        self.seed = seed
        self.address = address

    def settings(self) -> dict[str, Any]:
        """The arguments that decide the results (not ``num_envs`` and ``address``, which
        decide only where the trials run)."""
        return {k: v for k, v in vars(self).items() if k not in ("num_envs", "address")}

    def learn_object(self, kind: str, out: Path, writer=None, progress=None) -> dict[str, Any]:
        """Run hypothesis evaluation, learning and empirical evaluation for one object.

        Args:
            kind: object kind.
            out: directory for this object's files (densities, learner, pictures).
            writer: optional TensorBoard ``SummaryWriter`` (scalars under ``kind/``).
            progress: optional tqdm bar advanced by one per trial.

        Returns:
            the object's summary: ``hypothesis_success`` and ``empirical_success`` (plain
            draws), ``hypothesis_best_of_k_success`` and ``empirical_best_of_k_success`` (the
            likeliest of ``candidates`` reachable draws), all on the same ``eval_trials``
            held-out placements; ``trials`` and ``trials_per_minute`` of learning; per-cycle
            figures.
        """
        from vistask.envs.grasp_trial import RayGraspTrials, VectorGraspTrials

        out.mkdir(parents=True, exist_ok=True)
        generator = torch.Generator().manual_seed(self.seed)
        start = time.perf_counter()
        if cluster_address(self.address) is None:
            runner = VectorGraspTrials(kind, self.num_envs)
        else:
            runner = RayGraspTrials(kind, self.num_envs, self.address)
        try:
            bounds = torch.as_tensor(runner.object_bounds, dtype=torch.float32)
            patches = object_patches_for(kind)
            step = (lambda n: progress.update(n)) if progress is not None else None
            eval_seeds = range(EVAL_SEED_BASE, EVAL_SEED_BASE + self.eval_trials)

            def evaluate(density: SE3KDE) -> dict[str, float]:
                """Plain draws and best-of-K draws on the same held-out placements."""
                figures = {}
                for name, k in (("sample", 1), ("best", self.candidates)):
                    r = evaluate_density(
                        density,
                        runner,
                        self.eval_trials,
                        eval_seeds,
                        runner.workspace,
                        generator,
                        step,
                        candidates=k,
                    )
                    figures[name] = r["success_rate"]
                return figures

            checkpoint = out / "checkpoint.pt"
            if checkpoint.exists():  # resume after the last finished cycle
                saved = load_state(checkpoint, CHECKPOINT)
                learner = GraspLearner.from_state_dict(saved["learner"])
                hypothesis, hyp_eval = learner.hypothesis, saved["hypothesis_eval"]
                generator.set_state(saved["generator"])
                if step is not None:
                    step(2 * self.eval_trials + len(learner.trials))
            else:
                hypothesis = hypothesis_density(
                    kind, self.hypothesis, bounds, self.sigma_t, self.sigma_r, patches, generator
                )
                hypothesis.save(out / "hypothesis.pt")
                hyp_eval = evaluate(hypothesis)
                learner = GraspLearner(
                    hypothesis,
                    runner.workspace,
                    c_rel=self.c_rel,
                    sigma_t=self.empirical_sigma_t,
                    sigma_r=self.empirical_sigma_r,
                )
            n = self.trials_per_cycle
            for k in range(len(learner.history), self.cycles):
                base = LEARN_SEED_BASE + 100_000 * k
                stats = learner.run_cycle(runner, n, range(base, base + n), generator, step)
                # Everything the next cycle needs, so that a stop loses at most this cycle.
                state = {
                    "learner": learner.state_dict(),
                    "generator": generator.get_state(),
                    "hypothesis_eval": hyp_eval,
                }
                save_state(checkpoint, CHECKPOINT, state)
                if writer is not None:
                    for name in ("success_rate", "effective_sample_size", "trials", "particles"):
                        writer.add_scalar(f"{kind}/{name}", getattr(stats, name), k)
                    writer.add_scalar(f"{kind}/cumulative_trials", len(learner.trials), k)
            learner.save(out / "learner.pt")
            empirical = learner.empirical
            if empirical is None:
                emp_eval = {"sample": 0.0, "best": 0.0}
            else:
                empirical.save(out / "empirical.pt")
                emp_eval = evaluate(empirical)
            points = None if patches is None else patches.positions
            colors = None if patches is None else patches.colors[:, 0]
            density_figure(
                [("hypothesis", hypothesis), ("empirical", empirical)],
                points,
                colors,
                out / "densities.png",
                title=kind,
            )
        finally:
            runner.close()
        learn_seconds = sum(h.seconds for h in learner.history)
        summary = {
            "hypothesis_source": self.hypothesis,
            "hypothesis_success": hyp_eval["sample"],
            "empirical_success": emp_eval["sample"],
            "hypothesis_best_of_k_success": hyp_eval["best"],
            "empirical_best_of_k_success": emp_eval["best"],
            "trials": len(learner.trials),
            "trials_per_minute": 60.0 * len(learner.trials) / learn_seconds,
            "eval_trials_per_measure": self.eval_trials,
            "learning_success": float(learner.trials.success.float().mean()),
            "empirical_particles": 0 if empirical is None else len(empirical),
            "empirical_ess": 0.0 if empirical is None else empirical.effective_sample_size(),
            "cycles": [asdict(h) for h in learner.history],
            "seconds": time.perf_counter() - start,
        }
        if writer is not None:
            writer.add_scalar(f"{kind}/hypothesis_success", summary["hypothesis_success"], 0)
            writer.add_scalar(f"{kind}/empirical_success", summary["empirical_success"], 0)
        return summary

    def run(self, out: Path) -> dict[str, Any]:
        """All objects; writes ``out/summary.json`` (the settings under ``config``, the
        figures per object under ``objects``) and TensorBoard logs.

        A folder that a stopped run left is resumed: objects already finished
        (``<object>/summary.json``) are kept, the one in progress continues after its last
        finished cycle (``<object>/checkpoint.pt``), with the results of a run straight
        through. The settings must be those of the stopped run (``config.json``).
        """
        from tqdm import tqdm

        out.mkdir(parents=True, exist_ok=True)
        check_same_settings(out / "config.json", self.settings())
        per_object = self.cycles * self.trials_per_cycle + 4 * self.eval_trials
        writer = tensorboard(out)
        results: dict[str, Any] = {}
        try:
            with tqdm(total=per_object * len(self.objects), unit="trial") as bar:
                for kind in self.objects:
                    bar.set_description(kind)
                    done = out / kind / "summary.json"
                    if done.exists():
                        results[kind] = json.loads(done.read_text())
                        bar.update(per_object)
                        continue
                    results[kind] = self.learn_object(kind, out / kind, writer, bar)
                    write_summary(done, results[kind])
        finally:
            writer.close()
        summary = {"config": dict(vars(self)), "objects": results}
        write_summary(out / "summary.json", summary)
        return summary


def format_table(summary: dict[str, Any]) -> str:
    """A text table of the per-object headline figures."""
    k = summary["config"]["candidates"]
    best = f"best of {k}"
    rows = [
        f"{'':<17} {'hypothesis':^21} {'empirical':^21}",
        f"{'object':<8} {'source':<8} {'sampled':>10} {best:>10} {'sampled':>10} {best:>10} "
        f"{'trials':>6} {'trials/min':>10} {'seconds':>8}",
    ]
    for kind, r in summary["objects"].items():
        rows.append(
            f"{kind:<8} {r['hypothesis_source']:<8} {r['hypothesis_success']:>10.2f} "
            f"{r['hypothesis_best_of_k_success']:>10.2f} {r['empirical_success']:>10.2f} "
            f"{r['empirical_best_of_k_success']:>10.2f} {r['trials']:>6d} "
            f"{r['trials_per_minute']:>10.1f} {r['seconds']:>8.1f}"
        )
    return "\n".join(rows)


def nbp_grasp_trials(
    kind: str,
    density: SE3KDE,
    n_trials: int,
    candidates: int = 10,
    cameras: tuple[str, ...] = ("front", "left", "right"),
    image_size: int = 256,
    seed: int = 0,
    patches=None,
) -> dict[str, Any]:
    """Grasp with the pose from NBP instead of the ground truth (the paper's full pipeline).

    Per held-out placement: render the scene, extract its patches, estimate the object pose
    with NBP on a model learned from the object's patches (``vistask.objects``), compute the
    instance grasp density by eq. (8) from that pose and ``density``, execute the likeliest
    of ``candidates`` reachable draws. ``patches`` (object frame) default to
    ``object_patches_for(kind)``; pass them when several objects run in one process, since
    the tabletop renderer must not run after a robot environment's GL context was made.

    Returns:
        ``success_rate``, ``trials``, ``median_translation_error`` (m),
        ``median_rotation_error`` (degrees, modulo the object's symmetry),
        ``seconds_per_trial``.
    """
    from vistask.envs.grasp_trial import GraspTrialEnv
    from vistask.envs.tabletop import object_symmetry
    from vistask.grasp.density import instance_grasp_density
    from vistask.grasp.learning import draw_reachable
    from vistask.objects import NBP, ObjectModel
    from vistask.se3 import identity_poses
    from vistask.vision import pose_error

    patches = object_patches_for(kind) if patches is None else patches
    if patches is None:
        raise ValueError(f"no object patches for {kind!r}")
    model = ObjectModel.learn(patches, name=kind)
    nbp = NBP()
    env = GraspTrialEnv(kind, cameras=cameras, image_size=image_size)
    generator = torch.Generator().manual_seed(seed)
    successes, errors_t, errors_r = [], [], []
    start = time.perf_counter()
    try:
        for k in range(n_trials):
            obs, info = env.reset(seed=EVAL_SEED_BASE + k)
            scene = env.patches(obs, label=None)
            # Drop the table plane and everything far from it: NBP gets the clutter above.
            scene = scene.in_box(torch.tensor([-0.4, -0.4, 0.805]), torch.tensor([0.4, 0.4, 1.3]))
            estimate = nbp.infer(model, scene, seed=seed + k).pose.float()
            truth = torch.as_tensor(info["object_pose"], dtype=torch.float32)
            err_t, err_r = pose_error(estimate, truth, object_symmetry(kind))
            errors_t.append(float(err_t))
            errors_r.append(float(err_r))
            belief = SE3KDE(estimate[None], sigma_t=0.002, sigma_r=0.02)
            world = instance_grasp_density(belief, density, n=500, generator=generator)
            _, grasp, _ = draw_reachable(
                world, identity_poses(1), env.workspace, generator, candidates=candidates
            )
            _, reward, _, _, _ = env.step(grasp[0].double().numpy())
            successes.append(reward)
    finally:
        env.close()
    return {
        "success_rate": float(torch.tensor(successes).mean()),
        "trials": n_trials,
        "median_translation_error": float(torch.tensor(errors_t).median()),
        "median_rotation_error": float(torch.tensor(errors_r).median()),
        "seconds_per_trial": (time.perf_counter() - start) / n_trials,
    }


def run_nbp(out: Path, objects: tuple[str, ...], n_trials: int, candidates: int = 10) -> dict:
    """``nbp_grasp_trials`` with each object's learned ``out/<object>/empirical.pt``.

    Adds an ``nbp`` entry per object to ``out/summary.json`` (when it exists) and returns
    the results.
    """
    all_patches = {kind: object_patches_for(kind) for kind in objects}  # before any robot GL
    results = {}
    for kind in objects:
        density = SE3KDE.load(out / kind / "empirical.pt")
        results[kind] = nbp_grasp_trials(
            kind, density, n_trials, candidates, patches=all_patches[kind]
        )
    path = out / "summary.json"
    if path.exists():
        summary = json.loads(path.read_text())
        for kind, r in results.items():
            summary["objects"].setdefault(kind, {})["nbp"] = r
        write_summary(path, summary)
    return results


def format_nbp_table(results: dict[str, dict[str, Any]]) -> str:
    """A text table of ``run_nbp`` results."""
    rows = [f"{'object':<8} {'NBP success':>11} {'trials':>6} {'t err (m)':>9} {'r err (deg)':>11}"]
    for kind, r in results.items():
        rows.append(
            f"{kind:<8} {r['success_rate']:>11.2f} {r['trials']:>6d} "
            f"{r['median_translation_error']:>9.3f} {r['median_rotation_error']:>11.1f}"
        )
    return "\n".join(rows)
