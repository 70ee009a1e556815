"""RLVC's default configuration on random maze layouts (``scripts/bench_maze_layouts.py``):
one configuration for every layout, no per-layout tuning."""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vistask.experiments.train_rlvc import train_rlvc
from vistask.runs import run_dir, write_summary


def bench_maze_layouts(
    layout_seeds: Sequence[int] = tuple(range(1, 11)),
    interactions: int = 30_000,
    seed: int = 0,
    out: str | Path | None = None,
    progress: bool = False,
) -> dict:
    """Train RLVC with its defaults on ``VisualMaze-v0(layout_seed=k)`` for every k and score
    each against its own oracle; each run lands in ``out/layout-<k>``.

    Returns:
        The summary written to ``out/summary.json``: ``layouts``, a list of
        ``{layout_seed, return_ratio, classes, selected_features, seconds}``, and their mean
        and minimum return ratio.
    """
    start = time.perf_counter()
    out = run_dir("bench_maze_layouts", out)
    layouts = []
    for k in layout_seeds:
        run = train_rlvc(
            env_kwargs={"layout_seed": int(k)},
            interactions=interactions,
            seed=seed,
            out=out / f"layout-{k}",
            progress=progress,
        )
        layouts.append(
            {
                "layout_seed": int(k),
                "return_ratio": run["return_ratio"],
                "classes": run["classes"],
                "selected_features": run["selected_features"],
                "seconds": run["seconds"],
            }
        )
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
