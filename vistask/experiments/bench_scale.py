"""One RLVC run at growing budgets (``scripts/bench_scale.py``): seconds by phase, peak resident
memory of the process tree, classes, features and return per budget, and how time and memory
grow with the interactions (the exponent b of a fitted ``cost = a * interactions ** b``).

Each run goes in a fresh process, so that its memory is its own and no run inherits another's
heap or caches.
"""

from __future__ import annotations

import copy
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

import vistask.envs  # noqa: F401  (registers the envs in the fresh process)
from vistask.agents import RLVCAgent
from vistask.experiments.hyperparams import agent_kwargs, hyperparams_for
from vistask.experiments.tasks import task_for
from vistask.experiments.train_rlvc import agent_policy
from vistask.memory import PeakMemory
from vistask.parallel import RunsFailed, last_line, map_runs, worker_threads
from vistask.rlvc import collect
from vistask.runs import append_record, check_same_settings, read_records, run_dir, write_summary

# Per env: the budgets and the env settings of its README line (place navigation: the paper's
# Figs. 8-9 run of compare_compaction.py); the agent takes the env's hyperparameters (BDD).
ENVS = {
    "vistask/VisualMaze-v0": {
        "budgets": (40_000, 80_000, 160_000, 320_000),
        "env_kwargs": {},
    },
    "vistask/PlaceNavigation-v0": {
        "budgets": (75_000, 150_000, 300_000, 600_000),
        "env_kwargs": {"views_per_state": 512},
    },
}
PHASES = ("collect", "features", "split", "compaction", "q", "evaluation", "other")
PREDICT_BATCH = 64  # percepts a predict call
PREDICT_BATCHES = 20


def predict_ms_per_percept(agent: RLVCAgent, env: gym.Env, seed: int) -> float:
    """Milliseconds a percept of ``agent.predict`` on one core, on batches of 64 views it never
    saw (fresh episodes), keypoints and words included (the extractor's caches emptied before
    each)."""
    views = collect(env, PREDICT_BATCH * PREDICT_BATCHES, seed=10**6 + seed).percepts
    extractor, seconds = agent.extractor, 0.0
    # A blocked move adds no percept: the batches are those the views fill.
    starts = range(0, len(views) - PREDICT_BATCH + 1, PREDICT_BATCH)
    with worker_threads(1):
        for start in starts:
            # Copies start with empty caches: the words' and, for panels, SIFT's views'.
            agent.extractor = copy.copy(extractor)
            agent.extractor.keypoints = copy.copy(extractor.keypoints)
            agent.extractor.keypoints.threads = 1  # SIFT's batches in this thread
            batch = np.stack(views[start : start + PREDICT_BATCH])
            t0 = time.perf_counter()
            agent.predict(batch)
            seconds += time.perf_counter() - t0
    agent.extractor = extractor
    return 1e3 * seconds / (PREDICT_BATCH * len(starts))


def scale_run(env_id: str, budget: int, seed: int = 0) -> dict:
    """One run of ``RLVCAgent`` with ``ENVS[env_id]``'s settings on ``budget`` interactions:
    seconds by phase, peak memory (MB), classes, features, return ratio, predict speed."""
    settings = ENVS[env_id]
    env = gym.make(env_id, **settings["env_kwargs"])
    task = task_for(env_id, settings["env_kwargs"])
    with PeakMemory() as memory:
        start = time.perf_counter()
        agent = RLVCAgent(env, seed=seed, **agent_kwargs(hyperparams_for(env_id))).learn(budget)
        learned = time.perf_counter()
        return_ratio = task.evaluate(agent_policy(agent)).mean / task.oracle_return
        evaluated = time.perf_counter()
    rlvc, timing = agent.rlvc, agent.timing
    phases = {
        "collect": timing["collect"],
        "features": timing["extract"] + timing["vocabulary"],
        "split": rlvc.timing.split,
        "compaction": rlvc.timing.compaction,
        "q": rlvc.timing.solve,
        "evaluation": evaluated - learned,
    }
    phases["other"] = evaluated - start - sum(phases.values())
    return {
        "seconds": evaluated - start,
        "seconds_by_phase": phases,
        "peak_rss_mb": memory.peak_mb,
        "classes": rlvc.n_classes,
        "features": len(rlvc.structure.selected_features),
        "return_ratio": return_ratio,
        "predict_ms_per_percept": predict_ms_per_percept(agent, env, seed),
    }


def _fresh_process_run(item: tuple[str, int, int]) -> dict:
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(1, mp_context=context) as pool:
        return pool.submit(scale_run, *item).result()


def growth_exponent(budgets: list[int], costs: list[float]) -> float:
    """The exponent b of the least-squares fit ``log cost = log a + b log budget``."""
    return float(np.polyfit(np.log(budgets), np.log(costs), 1)[0])


def bench_scale(
    envs: list[str] | tuple[str, ...] = tuple(ENVS),
    budgets: dict[str, list[int]] | None = None,
    seed: int = 0,
    workers: int = 1,
    address: str | None = None,
    out: str | Path | None = None,
) -> dict:
    """Run ``scale_run`` for every env and budget, print a table, write ``summary.json``
    (``summary[env][str(budget)]``, ``summary[env]["time_exponent"]``,
    ``["memory_exponent"]``, ``["predict_ms_per_percept"]`` at the largest budget) and
    ``scale.png``. Finished runs are kept in ``runs.jsonl``: the same call on the same ``out``
    runs only the missing ones.

    Args:
        envs: env ids among ``ENVS``.
        budgets: interactions per env id (default: ``ENVS``' budgets).
        seed: the agent's seed.
        workers: runs side by side (default 1: a run's time is its own; more share cores).
        address: Ray cluster to run on (see ``vistask.parallel.map_runs``).
        out: output folder (default ``runs/bench_scale-<time>``).
    """
    unknown = set(envs) - set(ENVS)
    if unknown:
        raise ValueError(f"envs must be among {sorted(ENVS)}, got {sorted(unknown)}")
    budgets = {env: list((budgets or {}).get(env, ENVS[env]["budgets"])) for env in envs}
    out = run_dir("bench_scale", out)
    check_same_settings(out / "settings.json", {"seed": seed})
    done = {(r["env_id"], r["budget"]): r for r in read_records(out / "runs.jsonl")}
    items = [(env, b, seed) for env in envs for b in budgets[env] if (env, b) not in done]

    failed = []

    def record(outcome) -> None:
        if not outcome.ok:
            failed.append(f"{outcome.item[0]} at {outcome.item[1]}: {last_line(outcome.error)}")
            print(f"failed: {failed[-1]}")
            return
        env_id, budget, _ = outcome.item
        done[env_id, budget] = {"env_id": env_id, "budget": budget, **outcome.result}
        append_record(out / "runs.jsonl", done[env_id, budget])

    map_runs(_fresh_process_run, items, workers, address, record)
    if failed and not done:
        raise RunsFailed.of(failed, every=True)
    summary = {"seed": seed}
    for env in envs:
        runs = [done[env, b] for b in sorted(budgets[env]) if (env, b) in done]
        if not runs:
            continue
        sizes = [r["budget"] for r in runs]
        summary[env] = {str(r["budget"]): _measures(r) for r in runs}
        if len(runs) > 1:
            summary[env]["time_exponent"] = growth_exponent(sizes, [r["seconds"] for r in runs])
            memory = [r["peak_rss_mb"] for r in runs]
            summary[env]["memory_exponent"] = growth_exponent(sizes, memory)
            summary[env]["memory_exponent_largest"] = growth_exponent(sizes[-2:], memory[-2:])
        summary[env]["predict_ms_per_percept"] = runs[-1]["predict_ms_per_percept"]
    summary["pictures"] = {"scale": str(plot_scale(summary, out / "scale.png"))}
    write_summary(out, summary)
    print_scale(summary, out)
    if failed:  # after what finished is written: the same command runs the rest again
        raise RunsFailed.of(failed)
    return summary


def _measures(run: dict) -> dict:
    return {k: v for k, v in run.items() if k not in ("env_id", "budget")}


def _runs(summary: dict, env: str) -> tuple[list[int], list[dict]]:
    sizes = sorted(int(k) for k in summary[env] if k.isdigit())
    return sizes, [summary[env][str(b)] for b in sizes]


def plot_scale(summary: dict, path: Path) -> Path:
    """Seconds and peak memory against interactions (log-log) per env, and the seconds of
    each phase at each env's largest budget."""
    envs = [env for env in ENVS if env in summary]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for env in envs:
        sizes, runs = _runs(summary, env)
        name = env.split("/")[-1]
        for ax, key in ((axes[0], "seconds"), (axes[1], "peak_rss_mb")):
            values = [r[key] for r in runs]
            (line,) = ax.loglog(sizes, values, "o-", label=name)
            # Proportional growth from the smallest budget, for the eye.
            ax.loglog(sizes, [values[0] * b / sizes[0] for b in sizes], ":", color=line.get_color())
    for ax in axes[:2]:
        # Ticks at 1, 2 and 5 a decade, as thousands: the log axis's own labels run together.
        ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x / 1000:g}k"))
        ax.xaxis.set_minor_formatter(NullFormatter())
    axes[0].set(xlabel="interactions", ylabel="seconds", title="time of one run (dotted: x1)")
    axes[1].set(xlabel="interactions", ylabel="peak resident MB", title="memory (dotted: x1)")
    bottom = np.zeros(len(envs))
    for phase in PHASES:
        values = np.array([_runs(summary, e)[1][-1]["seconds_by_phase"][phase] for e in envs])
        axes[2].bar([e.split("/")[-1] for e in envs], values, bottom=bottom, label=phase)
        bottom += values
    axes[2].set(ylabel="seconds", title="phases at the largest budget")
    for ax in axes:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def print_scale(summary: dict, out: Path) -> None:
    """Print one row per env and budget, then each env's exponents."""
    print(f"RLVC at growing budgets -> {out}")
    header = ["env", "interactions", "seconds", *PHASES, "peak MB", "classes", "return ratio"]
    print(" | ".join(header))
    for env in ENVS:
        if env not in summary:
            continue
        for size, run in zip(*_runs(summary, env), strict=True):
            phases = [f"{run['seconds_by_phase'][p]:.0f}" for p in PHASES]
            print(
                f"{env} | {size} | {run['seconds']:.0f} | {' | '.join(phases)} | "
                f"{run['peak_rss_mb']:.0f} | {run['classes']} | {run['return_ratio']:.3f}"
            )
        shown = {
            k: summary[env][k] for k in ("time_exponent", "memory_exponent") if k in summary[env]
        }
        exponents = ", ".join(f"{k} {v:.2f}" for k, v in shown.items())
        print(
            f"{env}: {exponents}; predict {summary[env]['predict_ms_per_percept']:.2f} ms a percept"
        )
