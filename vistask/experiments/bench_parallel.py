"""Runs side by side (``scripts/bench_parallel.py``): the quick comparison with one worker and
with W worker processes and W Ray workers, grasp trials in gymnasium's ``AsyncVectorEnv``
processes and in Ray actors with one and with W workers, and one RLVC run, and SIFT alone,
on one thread and on W threads.

Every configuration runs the same work, one configuration after another, so the speed-ups are
ratios measured in one run; each row also says whether its results equal the one-worker
run's, value for value.
"""

from __future__ import annotations

import functools
import os
import time
from collections.abc import Sequence
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from vistask.agents import RLVCAgent
from vistask.experiments.compare import compare
from vistask.experiments.comparison import Comparison
from vistask.features import SiftExtractor
from vistask.grasp import demonstration_density, run_trials, scripted_teacher_grasps
from vistask.parallel import worker_threads
from vistask.rlvc import collect
from vistask.runs import run_dir, write_summary


def _returns(summary: dict) -> list:
    return [(r["method"], r["seed"], r["returns"]) for r in summary["runs"]]


def bench_comparison(workers: Sequence[int], out: Path) -> list[dict]:
    """``Comparison.quick()`` with each worker count: one worker in this process on one thread,
    as each worker runs, so that the results can be equal; more workers as processes and as
    the tasks of a Ray started for them."""
    rows, reference = [], None
    runs = [("in process", 1, None)] if 1 in workers else []
    for runner, address in (("processes", None), ("ray", "local")):
        runs += [(runner, n, address) for n in workers if n > 1]
    for runner, n, address in runs:
        with worker_threads():
            t0 = time.perf_counter()
            summary = compare(Comparison.quick(), out / f"compare-{runner}-{n}", False, n, address)
            seconds = time.perf_counter() - t0
        reference = reference or _returns(summary)
        rows.append(
            {
                "work": "quick comparison",
                "runner": runner,
                "workers": n,
                "seconds": seconds,
                "same_results": _returns(summary) == reference,
            }
        )
    return rows


def bench_grasp_trials(
    workers: Sequence[int], trials: int, object_kind: str = "box", seed: int = 0
) -> list[dict]:
    """``trials`` grasp trials (placements 0..trials-1, grasps from the scripted teacher's
    density) with each runner and worker count; seconds exclude starting the simulators."""
    from vistask.envs.grasp_runners import RayGraspTrials, VectorGraspTrials

    rows, reference = [], None
    processes = functools.partial(VectorGraspTrials, asynchronous=True)  # even for one
    for name, make in (("processes", processes), ("ray", RayGraspTrials)):
        for n in workers:
            t0 = time.perf_counter()
            runner = make(object_kind, n)
            try:
                start = time.perf_counter() - t0
                bounds = torch.as_tensor(runner.object_bounds, dtype=torch.float32)
                generator = torch.Generator().manual_seed(seed)
                teacher = scripted_teacher_grasps(bounds)
                density = demonstration_density(teacher, generator=generator)
                t1 = time.perf_counter()
                _, success, _, _ = run_trials(
                    density, runner, trials, range(trials), runner.workspace, generator
                )
                seconds = time.perf_counter() - t1
            finally:
                runner.close()
            reference = success if reference is None else reference
            rows.append(
                {
                    "work": f"{trials} grasp trials",
                    "runner": name,
                    "workers": n,
                    "seconds": seconds,
                    "start_seconds": start,
                    "trials_per_minute": 60.0 * trials / seconds,
                    "success_rate": float(success.float().mean()),
                    "same_results": bool(torch.equal(success, reference)),
                }
            )
    return rows


def bench_one_run(
    workers: Sequence[int], interactions: int = 40_000, views: int = 4096
) -> list[dict]:
    """One ``RLVCAgent`` run on the maze (its defaults, seed 0; ``train_rlvc.py``'s run) with
    torch, OpenCV and SIFT's batches on each thread count: seconds of ``learn``, and whether
    the classes and their Q equal the fewest threads' run. Then SIFT alone on ``views`` maze
    views of a random walk, on each thread count: what threads give the run's largest part."""
    rows, reference = [], None
    for n in workers:
        with worker_threads(n):
            agent = RLVCAgent(gym.make("vistask/VisualMaze-v0"), seed=0)
            t0 = time.perf_counter()
            agent.learn(interactions)
            seconds = time.perf_counter() - t0
        learned = agent.rlvc.n_classes, agent.rlvc.q
        reference = reference or learned
        rows.append(
            {
                "work": "one RLVC run",
                "runner": "threads",
                "workers": n,
                "seconds": seconds,
                "classes": learned[0],
                "same_results": learned[0] == reference[0]
                and torch.equal(learned[1], reference[1]),
            }
        )
    return rows + _sift_alone(workers, views)


def _sift_alone(workers: Sequence[int], views: int) -> list[dict]:
    """``SiftExtractor.batch`` of ``views`` maze views on each thread count: seconds, and
    whether every keypoint equals the fewest threads' run."""
    # Blocked moves add no view: twice the interactions give enough.
    images = list(collect(gym.make("vistask/VisualMaze-v0"), 2 * views, seed=0).percepts[:views])
    rows, reference = [], None
    for n in workers:
        with worker_threads(n):
            extractor = SiftExtractor(threads=n)
            t0 = time.perf_counter()
            detected = extractor.batch(images)
            seconds = time.perf_counter() - t0
        arrays = [array for k in detected for array in (k.xy, k.descriptors)]
        reference = reference or arrays
        rows.append(
            {
                "work": f"SIFT of {len(images)} views",
                "runner": "threads",
                "workers": n,
                "seconds": seconds,
                "same_results": len(arrays) == len(reference)
                and all(np.array_equal(a, b) for a, b in zip(arrays, reference, strict=True)),
            }
        )
    return rows


def bench_parallel(
    workers: Sequence[int] | None = None,
    trials: int = 200,
    parts: Sequence[str] = ("comparison", "grasps", "one_run"),
    out: str | Path | None = None,
) -> dict:
    """Run the benchmarks in ``parts``, print the table, write ``summary.json``.

    Args:
        workers: worker counts (default 1 and all cores); the first is the reference.
        trials: grasp trials per configuration.
        parts: any of "comparison", "grasps" and "one_run".
        out: output folder (default ``runs/bench_parallel-<time>``).
    """
    out = run_dir("bench_parallel", out)
    workers = tuple(workers or sorted({1, os.cpu_count() or 1}))
    rows = []
    if "comparison" in parts:
        rows += bench_comparison(workers, out)
    if "grasps" in parts:
        rows += bench_grasp_trials(workers, trials)
    if "one_run" in parts:
        rows += bench_one_run(workers)
    for row in rows:  # against the same work on the same runner (or in process), fewest workers
        same = [
            r
            for r in rows
            if r["work"] == row["work"] and r["runner"] in (row["runner"], "in process")
        ]
        row["speedup"] = min(same, key=lambda r: r["workers"])["seconds"] / row["seconds"]
    summary = {"workers": workers, "cpus": os.cpu_count(), "rows": rows}
    write_summary(out, summary)
    print(f"{'work':18s} {'runner':10s} {'workers':>7s} {'seconds':>8s} {'speed-up':>8s} same")
    for r in rows:
        print(
            f"{r['work']:18s} {r['runner']:10s} {r['workers']:7d} {r['seconds']:8.1f} "
            f"{r['speedup']:8.2f} {r['same_results']}"
        )
    print(f"-> {out}")
    return summary
