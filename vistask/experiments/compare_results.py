"""A comparison's results: curves aggregated over seeds (interactions to a share of the
oracle's return, speed-ups), tables, rliable's statistics and pictures."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from vistask.experiments import statistics
from vistask.experiments.compare_runs import RunResult
from vistask.experiments.comparison import THRESHOLDS


# -- aggregation --------------------------------------------------------------------------
def interactions_to(budgets: Sequence[int], curve: np.ndarray, target: float) -> int | None:
    """The first budget at which ``curve`` reaches ``target`` (None if it never does)."""
    hits = np.flatnonzero(np.asarray(curve) >= target)
    return int(budgets[hits[0]]) if len(hits) else None


def aggregate(
    results: list[RunResult], budgets: Sequence[int], oracle_return: float | None
) -> dict[str, dict]:
    """Per method: IQM curve with its stratified-bootstrap CI (rliable), interactions to each
    threshold of the oracle's return (from the IQM, and the interval given by the CI's upper
    and lower curves; None without an oracle), final return and seconds."""
    methods = list(dict.fromkeys(r.method for r in results))
    scores = {m: np.array([r.returns for r in results if r.method == m]) for m in methods}
    curves = statistics.iqm_curves(scores)  # (S, B) -> IQM and CI per budget
    out = {}
    for method in methods:
        runs = [r for r in results if r.method == method]
        values = scores[method]
        center, low, high = curves[method]
        curve = {"iqm": center, "ci_low": low, "ci_high": high, "per_seed": values}
        if all(r.seconds_at is not None for r in runs):
            curve["train_seconds"] = np.median([r.seconds_at for r in runs], axis=0)
        entry = {
            "curve": curve,
            "final_return": float(center[-1]),
            "final_ci": [float(low[-1]), float(high[-1])],
            "oracle_return": oracle_return,
            "final_ratio": None if oracle_return is None else float(center[-1] / oracle_return),
            "seconds": float(sum(r.seconds for r in runs)),
            "train_seconds": float(sum(r.train_seconds for r in runs)),
            "seeds": [r.seed for r in runs],
        }
        for frac in THRESHOLDS if oracle_return is not None else ():
            pct = round(frac * 100)
            entry[f"interactions_to_{pct}pct"] = interactions_to(
                budgets, center, frac * oracle_return
            )
            # Optimistic (upper curve) and pessimistic (lower curve) budgets; None = never.
            entry[f"interactions_to_{pct}pct_ci"] = [
                interactions_to(budgets, high, frac * oracle_return),
                interactions_to(budgets, low, frac * oracle_return),
            ]
        out[method] = entry
    return out


def speedups(methods: dict[str, dict], budgets: Sequence[int]) -> dict[str, object]:
    """Best SB3 interactions-to-threshold divided by the visual learner's (RLVC, or RLJC on
    continuous actions), per threshold.

    ``sb3_over_<learner>_<pct>pct`` is None when either never reaches the threshold; when the
    learner does and no SB3 baseline does, ``..._lower_bound`` (max budget / the learner's)
    bounds it. ``..._ci`` is the interval from the methods' CI curves: [pessimistic SB3 /
    optimistic learner ... ] ordered low to high (None where a bound is never reached).
    """
    out: dict[str, object] = {}
    learner = next((m for m in ("rlvc", "rljc") if m in methods), None)
    if learner is None or "interactions_to_90pct" not in methods[learner]:  # no oracle
        return out
    sb3 = [methods[m] for m in ("dqn", "ppo", "sac") if m in methods]
    for frac in THRESHOLDS:
        key = f"interactions_to_{round(frac * 100)}pct"
        name = f"sb3_over_{learner}_{round(frac * 100)}pct"
        ours = methods[learner][key]
        reached = [m[key] for m in sb3 if m[key] is not None]
        out[name] = min(reached) / ours if ours and reached else None
        if ours and sb3 and not reached:
            out[name + "_lower_bound"] = max(budgets) / ours
        ours_fast, ours_slow = methods[learner][key + "_ci"]
        sb3_fast = [m[key + "_ci"][0] for m in sb3 if m[key + "_ci"][0] is not None]
        sb3_slow = [m[key + "_ci"][1] for m in sb3 if m[key + "_ci"][1] is not None]
        low = min(sb3_fast) / ours_slow if sb3_fast and ours_slow else None
        high = min(sb3_slow) / ours_fast if sb3_slow and ours_fast else None
        out[name + "_ci"] = [low, high]
    return out


# -- outputs ------------------------------------------------------------------------------
def format_cell(value) -> str:
    """A table cell: ``never`` for None, a number as it prints."""
    if value is None:
        return "never"
    return f"{value:.3g}" if isinstance(value, float) else str(value)


def markdown_table(methods: dict[str, dict], oracle_return: float | None) -> str:
    """One row per method: interactions to 90% / 75% of the oracle (with one), final
    return, seconds."""
    if oracle_return is None:
        lines = [
            "Mean episode reward over seeded episodes (the env has no oracle)",
            "",
            "| method | final return (IQM [95% CI]) | seconds |",
            "|---|---|---|",
        ]
        for name, m in methods.items():
            lo, hi = m["final_ci"]
            lines.append(
                f"| {name} | {m['final_return']:.2f} [{lo:.2f}, {hi:.2f}] | {m['seconds']:.0f} |"
            )
        return "\n".join(lines) + "\n"
    lines = [
        f"Oracle mean discounted return: {oracle_return:.2f}",
        "",
        "| method | interactions to 90% oracle | interactions to 75% oracle "
        "| final return (IQM [95% CI]) | final / oracle | seconds |",
        "|---|---|---|---|---|---|",
    ]
    for name, m in methods.items():
        lo, hi = m["final_ci"]
        lines.append(
            f"| {name} | {format_cell(m['interactions_to_90pct'])}"
            f" | {format_cell(m['interactions_to_75pct'])}"
            f" | {m['final_return']:.2f} [{lo:.2f}, {hi:.2f}] | {m['final_ratio']:.3f}"
            f" | {m['seconds']:.0f} |"
        )
    return "\n".join(lines) + "\n"


def write_csv(path: Path, methods: dict[str, dict], budgets: Sequence[int]) -> None:
    """Long format: method, interactions, iqm, ci_low, ci_high, mean, then one column per seed."""
    n_seeds = max(len(m["seeds"]) for m in methods.values())
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(
            ["method", "interactions", "iqm", "ci_low", "ci_high", "mean"]
            + [f"seed_{k}" for k in range(n_seeds)]
        )
        for name, m in methods.items():
            c = m["curve"]
            for j, budget in enumerate(budgets):
                per_seed = c["per_seed"][:, j]
                row = [name, budget, c["iqm"][j], c["ci_low"][j], c["ci_high"][j]]
                writer.writerow([*row, per_seed.mean(), *per_seed])


PROFILE_TAUS = np.linspace(0.0, 1.2, 25)  # thresholds on return / oracle


def final_statistics(methods: dict[str, dict], learner: str | None) -> dict[str, object]:
    """Rliable's view of the final returns as fractions of the oracle's (the returns
    themselves without an oracle): median, IQM, mean and optimality gap (with an oracle) with
    intervals, performance profiles, and the probability that a ``learner`` run beats a run of
    each other method."""
    oracle = next(iter(methods.values()))["oracle_return"]
    scores = {name: m["curve"]["per_seed"][:, -1] / (oracle or 1.0) for name, m in methods.items()}
    taus = PROFILE_TAUS
    if oracle is None:  # thresholds over the returns met
        finals = np.concatenate(list(scores.values()))
        taus = np.linspace(min(0.0, finals.min()), finals.max(), len(PROFILE_TAUS))
    aggregates, profiles = statistics.aggregates_and_profiles(scores, taus)
    if oracle is None:  # the gap to a return of 1 means nothing without an oracle
        for metrics in aggregates.values():
            metrics.pop("Optimality gap", None)
    pairs = [(learner, other) for other in methods if other != learner] if learner else []
    return {
        "aggregates": aggregates,
        "profiles": {
            "taus": taus,
            **{
                name: {"fraction": p[0], "ci_low": p[1], "ci_high": p[2]}
                for name, p in profiles.items()
            },
        },
        "improvement": statistics.improvement_probabilities(scores, pairs),
    }


def write_pictures(
    out: Path, methods: dict[str, dict], stats: dict, budgets, oracle: float | None
) -> None:
    """Rliable's plots: ``curves.png`` (IQM return against interactions, log x, with 95%
    intervals), ``aggregates.png``, ``profiles.png`` and ``improvement.png``; and
    ``wallclock.png``, the return against training seconds."""
    curves = {
        name: (np.array(c["iqm"]), np.array(c["ci_low"]), np.array(c["ci_high"]))
        for name, c in ((n, m["curve"]) for n, m in methods.items())
    }
    colors = statistics.method_colors(list(methods))
    statistics.plot_sample_efficiency(out / "curves.png", budgets, curves, oracle, colors)
    score = "return / oracle" if oracle is not None else "episode reward"
    statistics.plot_aggregates(out / "aggregates.png", stats["aggregates"], score, colors)
    profiles = {
        name: (np.array(p["fraction"]), np.array(p["ci_low"]), np.array(p["ci_high"]))
        for name, p in stats["profiles"].items()
        if name != "taus"
    }
    taus = stats["profiles"]["taus"]
    statistics.plot_profiles(out / "profiles.png", profiles, taus, score, colors)
    plot_wallclock(out / "wallclock.png", methods, oracle, colors)
    if stats["improvement"]:
        statistics.plot_improvement(out / "improvement.png", stats["improvement"])


def plot_wallclock(
    path: Path, methods: dict[str, dict], oracle: float | None, colors: dict[str, tuple]
) -> None:
    """IQM return against the median training seconds behind it (log x), per method that
    trains (the random baseline does not), in each method's colour."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name, m in methods.items():
        seconds = m["curve"].get("train_seconds")
        if seconds is None or not np.all(np.asarray(seconds) > 0):
            continue
        ax.plot(seconds, m["curve"]["iqm"], marker="o", label=name, color=colors[name])
    if oracle is not None:
        ax.axhline(oracle, color="k", linestyle="--", label="oracle (true state)")
        ax.axhline(0.9 * oracle, color="k", linestyle=":", label="90% of oracle")
    ax.set_xscale("log")
    ax.set_xlabel("training seconds (median over seeds; one CPU thread a run)")
    ax.set_ylabel("IQM return")
    ax.legend(fontsize="small")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
