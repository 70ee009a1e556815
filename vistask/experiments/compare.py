"""RLVC (with and without compound features) against Stable-Baselines3 DQN/PPO, tabular
Q-learning on the true state, and random actions; on an env with continuous actions, RLJC
against SB3 SAC/PPO and random actions: on the same interaction budgets, seeds and evaluation
starts (``scripts/compare_baselines.py``), on any env of image observations.

Every method is scored at every budget B (environment interactions) by its task's evaluation
(``tasks.py``): on an env with an oracle (the visual mazes, the visual mountain car, place
navigation), the mean discounted return from the same fixed starts with the same noise, and
its share of the oracle's; on any other env, the mean episode reward over the same seeded
episodes. RLVC
(and RLJC) learns from one fixed database, so its checkpoint at B is a fresh agent learned on B
interactions; the other learners train once per seed and are evaluated when they pass B.
These independent runs go side by side (``vistask.parallel``) and each lands in ``runs.jsonl`` as it
ends, so that a stopped comparison resumes. Curves are aggregated over seeds with rliable
(``statistics.py``): interquartile mean (IQM) with stratified-bootstrap confidence intervals,
performance profiles and probabilities of improvement.
"""

from __future__ import annotations

import time
from contextlib import nullcontext
from dataclasses import asdict
from pathlib import Path

from vistask.experiments.compare_results import (
    aggregate,
    final_statistics,
    format_cell,
    markdown_table,
    speedups,
    write_csv,
    write_pictures,
)
from vistask.experiments.compare_runs import (
    VISUAL_METHODS,
    RunResult,
    comparison_task,
    execute,
    merge_runs,
    run_specs,
    tabular_grid,
    write_eval_log,
)
from vistask.experiments.comparison import Comparison
from vistask.parallel import (
    Outcome,
    RunsFailed,
    cluster_address,
    last_line,
    map_runs,
    ray_session,
)
from vistask.runs import (
    append_record,
    check_same_settings,
    print_table,
    read_records,
    run_dir,
    write_summary,
)


# -- the whole comparison -----------------------------------------------------------------
def load_finished(out: Path, config: Comparison) -> list[RunResult]:
    """The runs already in ``out/runs.jsonl`` (none for a new folder). ``out`` must hold a
    comparison with the same settings (``comparison.json``), so that resuming never mixes two
    comparisons."""
    check_same_settings(out / "comparison.json", config.params())
    return [RunResult(**record) for record in read_records(out / "runs.jsonl")]


def compare(
    config: Comparison | None = None,
    out: str | Path | None = None,
    progress: bool = True,
    workers: int | None = None,
    address: str | None = None,
) -> dict:
    """Run every method with every seed, aggregate and write all outputs.

    The runs are independent (``RunSpec``) and go to ``vistask.parallel.map_runs``: side by
    side on this machine's cores by default (this process and worker processes), on a Ray
    cluster with ``address``, one after another in this process with ``workers=1``. Each
    finished run is appended to ``runs.jsonl`` at once; calling ``compare`` again on the same
    ``out`` with the same settings runs only what is missing (runs that failed or never ran).
    A run that fails is reported with its error (``summary["failed"]``) and the others go on.

    Writes under ``out`` (default ``runs/compare-<time>/``): ``comparison.json`` (settings),
    ``runs.jsonl``, ``curves.csv``, ``table.md``, ``summary.json``, rliable's pictures
    (``curves.png``, ``aggregates.png``, ``profiles.png``, ``improvement.png``),
    ``wallclock.png`` and
    ``tensorboard/`` (``<method>-seed<k>`` with ``eval/return`` against interactions for
    every method, ``seed<k>/<dqn|ppo|sac>-sb3_1`` with SB3's own training logs).

    Args:
        config: the comparison (default ``Comparison()``, the full run).
        out: run directory; an existing one with the same settings is resumed.
        progress: print one line per finished run.
        workers: runs side by side (default: all cores); 1 runs them in this process.
        address: a Ray cluster to run on (default: ``RAY_ADDRESS`` if set, else no Ray;
            ``"local"``: a Ray started here).

    Returns:
        The summary written to ``summary.json``.
    """
    config = config or Comparison()
    start = time.perf_counter()
    out = run_dir("compare", out)
    oracle_return = comparison_task(config).oracle_return  # None: no oracle
    units = load_finished(out, config)
    finished = {(r.method, r.seed, tuple(r.budgets)) for r in units}
    if units and progress:
        print(f"{len(units)} runs that an earlier call finished in {out} are kept", flush=True)
    failed: list[dict] = []

    def record(outcome: Outcome) -> None:
        spec = outcome.item[1]
        if not outcome.ok:
            failed.append({**asdict(spec), "error": outcome.error})
            if progress:
                print(
                    f"{spec.method} seed {spec.seed} {list(spec.budgets)} FAILED: "
                    f"{last_line(outcome.error)}",
                    flush=True,
                )
            return
        result, files = outcome.result
        for name, data in files.items():
            path = out / "tensorboard" / name
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
        append_record(out / "runs.jsonl", asdict(result))
        units.append(result)
        if progress:
            curve = " ".join(f"{r:.1f}" for r in result.returns)
            print(
                f"{spec.method} seed {spec.seed} at {list(spec.budgets)}: {curve} "
                f"({result.seconds:.0f} s)",
                flush=True,
            )

    # The tabular grid sized by RLVC's classes needs RLVC's runs first.
    phases = [list(config.methods)]
    if config.grid is None and "tabular" in config.methods:
        phases = [[m for m in config.methods if m != "tabular"], ["tabular"]]
    grid = config.grid
    # One Ray session for both phases; worker processes start fast enough to start per phase.
    session = nullcontext() if cluster_address(address) is None else ray_session(workers, address)
    with session:
        for phase in phases:
            if phase == ["tabular"] and grid is None:
                rlvc_runs = [
                    r for r in merge_runs(units, config.budgets) if r.method.startswith("rlvc")
                ]
                if not rlvc_runs:
                    failed.append(
                        {"method": "tabular", "error": "no RLVC run finished to size its grid"}
                    )
                    continue
                grid = tabular_grid(rlvc_runs)
            specs = [s for s in run_specs(config, phase, grid) if s.key not in finished]
            map_runs(execute, [(config, s) for s in specs], workers, address, record)

    order = {m: k for k, m in enumerate(config.methods)}
    results = sorted(merge_runs(units, config.budgets), key=lambda r: (order[r.method], r.seed))
    if not results:
        raise RunsFailed(
            "no method and seed finished all its budgets: "
            + "; ".join(f"{f.get('method')}: {last_line(f['error'])}" for f in failed)
        )
    for result in results:
        if result.method in VISUAL_METHODS:
            write_eval_log(out / "tensorboard", result)
    methods = aggregate(results, config.budgets, oracle_return)
    for m in methods.values():
        m["curve"]["budgets"] = list(config.budgets)
    learner = next((m for m in ("rlvc", "rljc") if m in methods), None)
    stats = final_statistics(methods, learner)
    write_csv(out / "curves.csv", methods, config.budgets)
    table = markdown_table(methods, oracle_return)
    (out / "table.md").write_text(table)
    write_pictures(out, methods, stats, config.budgets, oracle_return)

    summary = {
        "env_id": config.env_id,
        "config": config.params(),
        "oracle_return": oracle_return,
        "budgets": list(config.budgets),
        "tabular_grid": grid if "tabular" in config.methods else None,  # cells a dimension
        "methods": methods,
        "ratios": speedups(methods, config.budgets),
        "statistics": stats,
        "runs": [asdict(r) for r in results],
        "failed": failed,
        "seconds": time.perf_counter() - start,
    }
    write_summary(out, summary)
    print(f"Comparison on {config.env_id} -> {out}")
    print(table)
    if summary["ratios"]:
        print_table(
            {
                k: format_cell(v) if not isinstance(v, list) else str([format_cell(x) for x in v])
                for k, v in summary["ratios"].items()
            }
        )
    if failed:
        print(
            f"{len(failed)} runs failed (their errors in summary.json, 'failed'); once the "
            "cause is fixed, the same command runs them again and keeps the finished ones"
        )
    return summary
