"""Tree RLVC against BDD RLVC (compaction, paper section 2.5.2 and Fig. 9) on an env with an
oracle: classes, selected features, return against the oracle, test error on held-out percepts,
time; and the saw-tooth of classes and features per stage. Every run is also scored with new
percepts classed by the nearest percepts learned on (``RLVCAgent(nearest_seen=True)``).

Example:
    >>> summary = compare_compaction("vistask/PlaceNavigation-v0", seeds=[0, 1])
    >>> summary["bdd"]["test_error"]
"""

from __future__ import annotations

import time
from pathlib import Path

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from PIL import Image

import vistask.envs  # noqa: F401  (registers the environments)
from vistask.agents import Compaction, RLVCAgent
from vistask.envs.place_plots import draw_world, view_sheet
from vistask.experiments import statistics
from vistask.experiments.hyperparams import agent_kwargs, hyperparams_for
from vistask.experiments.tasks import PlaceTask, Task, task_for
from vistask.experiments.train_rlvc import agent_policy
from vistask.runs import (
    append_record,
    check_same_settings,
    print_table,
    read_records,
    run_dir,
    write_summary,
)

METHODS = ("tree", "bdd")
MEASURES = (
    "classes",
    "selected_features",
    "return_ratio",
    "test_error",
    "return_ratio_nearest_seen",
    "test_error_nearest_seen",
    "seconds",
)


def action_error(agent: RLVCAgent, percepts: np.ndarray, optimal: np.ndarray) -> float:
    """Share of percepts (N, H, W, 3) whose greedy action is not optimal ((N, A) bool)."""
    actions, _ = agent.predict(percepts)
    return float(1 - optimal[np.arange(len(actions)), actions].mean())


def run_method(
    method: str,
    env: gym.Env,
    task: Task,
    test_set: tuple[np.ndarray, np.ndarray],
    train_set: tuple[np.ndarray, np.ndarray] | None,
    interactions: int,
    seed: int,
    compaction: Compaction,
    agent_settings: dict,
    out: Path,
    progress: bool,
) -> tuple[dict, list[dict]]:
    """Learn one agent (``agent_settings``: ``RLVCAgent`` arguments; ``compaction`` for the
    BDD's); returns its measures and its per-stage (classes, features) history."""
    agent = RLVCAgent(
        env,
        compaction=compaction if method == "bdd" else False,
        seed=seed,
        tensorboard_log=out / "tensorboard",
        **agent_settings,
    )
    start = time.perf_counter()
    agent.learn(interactions, tb_log_name=f"{method}-seed{seed}", progress_bar=progress)
    seconds = time.perf_counter() - start
    agent.save(out / f"{method}-seed{seed}.pt")
    rlvc = agent.rlvc
    result = {
        "classes": rlvc.n_classes,
        "selected_features": len(rlvc.structure.selected_features),
        "return_ratio": task.evaluate(agent_policy(agent)).mean / task.oracle_return,
        "test_error": action_error(agent, *test_set),
        "seconds": seconds,
        "compaction_seconds": rlvc.timing.compaction,
        "stages": len(rlvc.history),
    }
    if train_set is not None:
        result["train_error"] = action_error(agent, *train_set)
    # The same classes with what ``nearest_seen=True`` adds when learning ends: one learning,
    # both ways of classing new percepts.
    rlvc.remember(agent.database)
    result |= {
        "return_ratio_nearest_seen": task.evaluate(agent_policy(agent)).mean / task.oracle_return,
        "test_error_nearest_seen": action_error(agent, *test_set),
    }
    history = [{"classes": r.classes, "features": r.selected_features} for r in rlvc.history]
    return result, history


def load_finished(out: Path, settings: dict) -> dict[tuple[str, int], tuple[dict, list[dict]]]:
    """The runs a stopped comparison left in ``out/runs.jsonl``, by (method, seed): their
    measures and histories. ``out`` must hold a comparison with the same ``settings``
    (``comparison.json``), so that resuming never mixes two comparisons."""
    check_same_settings(out / "comparison.json", settings)
    finished = {}
    for run in read_records(out / "runs.jsonl"):
        history = run.pop("history")
        finished[run.pop("method"), run.pop("seed")] = run, history
    return finished


def plot_sawtooth(histories: dict[str, list[list[dict]]], path: Path) -> Path:
    """Classes (left) and selected features (right) per stage, every seed, both methods."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    colours = {"tree": "tab:blue", "bdd": "tab:orange"}
    for method, runs in histories.items():
        for i, history in enumerate(runs):
            for ax, key in zip(axes, ("classes", "features"), strict=True):
                ax.plot(
                    [h[key] for h in history],
                    color=colours[method],
                    alpha=0.8,
                    lw=1,
                    label=method if i == 0 else None,
                )
    for ax, title in zip(axes, ("visual classes", "selected features"), strict=True):
        ax.set_xlabel("stage")
        ax.set_title(title)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def compare_compaction(
    env_id: str = "vistask/VisualMaze-v0",
    env_kwargs: dict | None = None,
    seeds: list[int] | tuple[int, ...] = (0,),
    methods: list[str] | tuple[str, ...] = METHODS,
    interactions: int = 30_000,
    compact_every: int | None = None,
    tolerance: float = 0.02,
    max_stages: int | None = None,
    contrast_threshold: float | None = None,
    out: str | Path | None = None,
    progress: bool = True,
) -> dict:
    """Learn tree RLVC and BDD RLVC with the same seeds on an env with an oracle.

    Both learn with the env's hyperparameters (``hyperparams_for``: its entry in the table,
    else ``RLVCAgent``'s defaults), without compaction; the BDD agent compacts when learning
    stops (and every ``compact_every`` stages if given) with ``tolerance``. Writes
    ``summary.json`` (per method: the mean of each measure over seeds, its IQM with a 95%
    interval, and the per-seed values; on place navigation also ``train_error``, the test
    error's measure on the training views),
    ``sawtooth.png`` and, for place navigation, ``world.png`` and ``views.png`` to ``out``.
    Each finished run is appended to ``runs.jsonl`` at once, its agent saved as
    ``<method>-seed<k>.pt``; calling again on the same ``out`` with the same settings runs
    only the methods and seeds that are missing.

    Args:
        env_id, env_kwargs: an env that ``task_for`` knows (the maze, its real-image option,
            place navigation).
        seeds: one run per method and seed.
        methods: ``tree``, ``bdd`` or both.
        interactions: interactions per run.
        compact_every, tolerance: the BDD agent's ``Compaction(every=, tolerance=)``.
        max_stages: both agents' stage cap (``RLVCAgent``'s ``max_stages``; default: the
            env's hyperparameters).
        contrast_threshold: both agents' SIFT detection threshold (default: the env's
            hyperparameters).
        out: output folder (default ``runs/compare_compaction-<time>``); an existing one
            with the same settings is resumed.
        progress: show progress bars.
    """
    env_kwargs = env_kwargs or {}
    if not methods or set(methods) - set(METHODS):
        raise ValueError(f"methods must be among {METHODS}, got {methods!r}")
    task = task_for(env_id, env_kwargs)
    if task is None or not hasattr(task, "test_set"):
        raise ValueError(
            f"{env_id} has no oracle test set: use vistask/VisualMaze-v0 (optionally with "
            '{"photo": "hubble_deep_field"}) or vistask/PlaceNavigation-v0'
        )
    out = run_dir("compare_compaction", out)
    env, test_set = gym.make(env_id, **env_kwargs), task.test_set()
    # Training percepts whose true states are known (place navigation's view bank): their
    # error against the test error tells a classifier that underfits from one that overfits.
    train_set = task.train_set() if hasattr(task, "train_set") else None
    measures = MEASURES + (("train_error",) if train_set is not None else ())
    compaction = Compaction(tolerance=tolerance, every=compact_every, during_learning=True)
    given = {"max_stages": max_stages, "contrast_threshold": contrast_threshold}
    overrides = {key: value for key, value in given.items() if value is not None}
    hyperparams = hyperparams_for(env_id, overrides)
    hyperparams.pop("compaction", None)  # the methods set it
    settings = {
        "env_id": env_id,
        "env_kwargs": env_kwargs,
        "interactions": interactions,
        "compact_every": compact_every,
        "tolerance": tolerance,
        "hyperparams": hyperparams,
    }
    finished = load_finished(out, settings)
    runs = {m: [] for m in methods}
    histories = {m: [] for m in methods}
    for seed in seeds:
        for method in methods:
            if (method, seed) in finished:
                result, history = finished[method, seed]
            else:
                result, history = run_method(
                    method,
                    env,
                    task,
                    test_set,
                    train_set,
                    interactions,
                    seed,
                    compaction,
                    agent_kwargs(hyperparams),
                    out,
                    progress,
                )
                record = {"method": method, "seed": seed, **result, "history": history}
                append_record(out / "runs.jsonl", record)
            runs[method].append({"seed": seed, **result})
            histories[method].append(history)
    summary = {**settings, "seeds": list(seeds)}
    for method in methods:
        # Runs of a comparison stopped before a measure existed lack it.
        known = [key for key in measures if all(key in r for r in runs[method])]
        values = {key: [r[key] for r in runs[method]] for key in known}
        means = {key: float(np.mean(v)) for key, v in values.items()}
        iqm = statistics.iqm_intervals(values)  # [iqm, low, high] per measure
        summary[method] = {**means, "iqm": iqm, "runs": runs[method]}
    if "bdd" in runs:
        summary["compaction_share_of_time"] = float(
            np.mean([r["compaction_seconds"] / r["seconds"] for r in runs["bdd"]])
        )
    summary["pictures"] = {"sawtooth": str(plot_sawtooth(histories, out / "sawtooth.png"))}
    if isinstance(task, PlaceTask):
        Image.fromarray(draw_world(task.env)).save(out / "world.png")
        state = task.starts[len(task.starts) // 2]
        Image.fromarray(view_sheet(task.env, state)).save(out / "views.png")
        summary["pictures"] |= {"world": str(out / "world.png"), "views": str(out / "views.png")}
    write_summary(out, summary)
    for method in methods:
        shown = {key: summary[method][key] for key in measures if key in summary[method]}
        print_table(shown, title=f"{method} RLVC")
    print(f"results in {out}")
    return summary
