"""RLJC against four-action RLVC on the continuous-direction maze over seeds
(``scripts/bench_rljc.py``): per seed, ``train_rljc``'s figures; over seeds, how often RLJC's
greedy return beats RLVC's on the same starts, its ratio to the 32-direction oracle, the joint
classes beside RLVC's classes x 4, and the time of a whole run."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vistask.experiments import statistics
from vistask.experiments.train_rljc import train_rljc
from vistask.runs import run_dir, write_summary

COLUMNS = (
    "rljc_return",
    "rlvc_discrete_return",
    "return_ratio",
    "joint_classes",
    "rlvc_classes_x4",
    "perceptual_cells",
    "rljc_seconds",
    "seconds",
)


def bench_rljc(
    seeds: int = 5,
    interactions: int = 60_000,
    env_kwargs: dict | None = None,
    out: str | Path | None = None,
    progress: bool = False,
) -> dict:
    """Run ``train_rljc`` on ``vistask/VisualMazeContinuous-v0`` for seeds 0..seeds-1 (each
    in ``out/seed<k>``, pictures for seed 0), print a table and write ``summary.json``."""
    out = run_dir("bench_rljc", out)
    runs = []
    for seed in range(seeds):
        summary = train_rljc(
            env_kwargs=env_kwargs,
            interactions=interactions,
            seed=seed,
            out=out / f"seed{seed}",
            progress=progress,
            pictures=seed == 0,
        )
        runs.append({key: summary[key] for key in COLUMNS} | {"seed": seed})
    table = {key: np.array([run[key] for run in runs], dtype=float) for key in COLUMNS}
    result = {
        "interactions": interactions,
        "env_kwargs": env_kwargs or {},
        "runs": runs,
        "rljc_beats_rlvc": int((table["rljc_return"] > table["rlvc_discrete_return"]).sum()),
        "seeds": seeds,
        "mean": {key: float(values.mean()) for key, values in table.items()},
        "iqm": statistics.iqm_intervals(table),  # [iqm, low, high] per column
        "min_return_ratio": float(table["return_ratio"].min()),
        "max_seconds": float(table["seconds"].max()),
    }
    write_summary(out, result)
    print_bench(result, out)
    return result


def print_bench(result: dict, out: Path) -> None:
    """Print the per-seed table and the means, with the folder it was written to."""
    header = ["seed", *COLUMNS]
    print(f"RLJC vs four-action RLVC, {result['interactions']} interactions -> {out}")
    print(" | ".join(header))
    for run in result["runs"]:
        print(" | ".join(f"{run[key]:.4g}" if key != "seed" else str(run[key]) for key in header))
    print(" | ".join(["mean", *(f"{result['mean'][key]:.4g}" for key in COLUMNS)]))
    print(
        f"RLJC beats RLVC in {result['rljc_beats_rlvc']} of {result['seeds']} seeds; "
        f"return ratio min {result['min_return_ratio']:.3f}; "
        f"longest run {result['max_seconds']:.0f} s"
    )
