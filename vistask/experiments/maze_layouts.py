"""RLVC's default configuration on random maze layouts (``scripts/bench_maze_layouts.py``):
one configuration for every layout, no per-layout tuning."""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vistask.experiments.train_rlvc import train_rlvc
from vistask.parallel import map_runs
from vistask.runs import run_dir, write_summary


def _layout_run(job: tuple[int, int, int, Path]) -> dict:
    """One layout's run (in this process, a worker process or a Ray worker)."""
    layout_seed, interactions, seed, out = job
    run = train_rlvc(
        env_kwargs={"layout_seed": layout_seed},
        interactions=interactions,
        seed=seed,
        out=out / f"layout-{layout_seed}",
        progress=False,
    )
    keys = ("return_ratio", "classes", "selected_features", "seconds")
    return {"layout_seed": layout_seed, **{k: run[k] for k in keys}}


def bench_maze_layouts(
    layout_seeds: Sequence[int] = tuple(range(1, 11)),
    interactions: int = 40_000,
    seed: int = 0,
    out: str | Path | None = None,
    workers: int | None = 1,
    address: str | None = None,
) -> dict:
    """Train RLVC with its defaults on ``VisualMaze-v0(layout_seed=k)`` for every k and score
    each against its own oracle; each run lands in ``out/layout-<k>``.

    Args:
        layout_seeds: the layouts.
        interactions: interactions of each run.
        seed: the agent's seed.
        out: run directory (default ``runs/bench_maze_layouts-<time>``).
        workers: runs side by side (``vistask.parallel.map_runs``: 1 runs them one after
            another in this process; None: all cores).
        address: a Ray cluster to run on (default: ``RAY_ADDRESS`` if set, else no Ray).

    Returns:
        The summary written to ``out/summary.json``: ``layouts``, a list of
        ``{layout_seed, return_ratio, classes, selected_features, seconds}``, and their mean
        and minimum return ratio.
    """
    start = time.perf_counter()
    out = run_dir("bench_maze_layouts", out)
    jobs = [(int(k), interactions, seed, out) for k in layout_seeds]
    outcomes = map_runs(_layout_run, jobs, workers, address)
    failed = [o for o in outcomes if not o.ok]
    if failed:
        raise RuntimeError("layout runs failed:\n" + "\n".join(o.error for o in failed))
    layouts = sorted((o.result for o in outcomes), key=lambda r: r["layout_seed"])
    ratios = np.array([layout["return_ratio"] for layout in layouts])
    summary = {
        "layouts": layouts,
        "mean_return_ratio": float(ratios.mean()),
        "min_return_ratio": float(ratios.min()),
        "interactions": interactions,
        "seed": seed,
        "seconds": time.perf_counter() - start,
    }
    write_summary(out, summary)
    print(f"RLVC on {len(layouts)} maze layouts -> {out}")
    print("| layout_seed | return / oracle | classes | selected features | seconds |")
    print("|---:|---:|---:|---:|---:|")
    for layout in layouts:
        print(
            f"| {layout['layout_seed']} | {layout['return_ratio']:.3f} | {layout['classes']} "
            f"| {layout['selected_features']} | {layout['seconds']:.1f} |"
        )
    print(f"mean {summary['mean_return_ratio']:.3f}, min {summary['min_return_ratio']:.3f}")
    return summary
