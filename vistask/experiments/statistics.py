"""Aggregate statistics over seeds, from rliable (Agarwal et al., 2021).

Scores are arrays of one row per run (seed). rliable's stratified bootstrap resamples runs
within each task; the comparisons here have one task (one env), so it is the ordinary
bootstrap over seeds. Every function takes a ``seed`` and gives the same intervals for it:
rliable draws its resamples from NumPy's global generator, so that generator is seeded for
the call and restored afterwards.

rliable's bootstrap calls the statistic once per resample (2,000 times an interval), and its
own IQM and probability of improvement go through SciPy's argument checking at every call,
which made the statistics of a small comparison cost more than its runs. The bootstrap and the
pictures stay rliable's; the statistics are NumPy expressions of the same definitions
(``trimmed_mean``, ``improvement_probability``), checked against rliable's in the tests.

Example:
    >>> curves = iqm_curves({"rlvc": returns_rlvc, "dqn": returns_dqn})  # (seeds, budgets)
    >>> center, low, high = curves["rlvc"]
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np

RESAMPLES = 2000
CONFIDENCE = 0.95
METRICS = ("Median", "IQM", "Mean", "Optimality gap")


def trimmed_mean(x: np.ndarray, axis: int | None = None) -> np.ndarray:
    """Interquartile mean: the mean after cutting ``int(n / 4)`` values from each end along
    ``axis`` (all values with None), as ``rliable.metrics.aggregate_iqm`` (SciPy's
    ``trim_mean(x, 0.25)``)."""
    x = np.asarray(x, dtype=float)
    if axis is None:
        x, axis = x.ravel(), 0
    n = x.shape[axis]
    cut = int(0.25 * n)
    middle = np.take(np.sort(x, axis=axis), np.arange(cut, n - cut), axis=axis)
    return middle.mean(axis=axis)


def improvement_probability(x: np.ndarray, y: np.ndarray) -> float:
    """P(X > Y) + P(X = Y) / 2 averaged over tasks, for (runs, tasks) scores ``x`` and ``y``:
    ``rliable.metrics.probability_of_improvement`` (the Mann-Whitney U statistic over the
    pairs of runs)."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    greater = (x[:, None] > y[None]).mean(axis=(0, 1))
    ties = (x[:, None] == y[None]).mean(axis=(0, 1))
    return float(np.mean(greater + 0.5 * ties))


@contextmanager
def _seeded(seed: int) -> Iterator[None]:
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


def _intervals(
    scores: Mapping[str, np.ndarray], func: Callable[..., np.ndarray], seed: int
) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Point estimate and CI of ``func`` per method: (K,), (K,), (K,). ``func`` receives
    rliable's (runs, tasks, ...) layout: here (S, 1, ...)."""
    from rliable import library as rly

    out = {}
    with _seeded(seed):
        for name, runs in scores.items():
            runs = np.asarray(runs, dtype=float)[:, None]  # one task
            point = np.asarray(func(runs), dtype=float)
            if len(runs) < 2 or np.all(runs == runs[0]):  # nothing to resample
                out[name] = (point, point.copy(), point.copy())
                continue
            _, ci = rly.get_interval_estimates(
                {name: runs}, func, reps=RESAMPLES, confidence_interval_size=CONFIDENCE
            )
            low, high = ci[name]
            out[name] = (point, np.minimum(low, point), np.maximum(high, point))
    return out


def iqm_curves(
    scores: Mapping[str, np.ndarray], seed: int = 0
) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Interquartile mean over seeds at every budget, with its 95% bootstrap interval.

    Args:
        scores: per method, (S, B) scores of S seeds at B budgets.
        seed: seed of the bootstrap resamples.

    Returns:
        per method, (B,) IQM, (B,) lower and (B,) upper bounds (equal to the IQM with one
        seed, where there is nothing to resample).
    """
    for name, runs in scores.items():
        if np.ndim(runs) != 2:
            raise ValueError(f"{name}: scores must be (seeds, budgets), got {np.shape(runs)}")

    return _intervals(scores, lambda runs: trimmed_mean(runs[:, 0], axis=0), seed)


def iqm_intervals(scores: Mapping[str, np.ndarray], seed: int = 0) -> dict[str, list[float]]:
    """IQM over seeds of each named measure, with its 95% interval.

    Args:
        scores: per measure (or method), (S,) values of S seeds.
        seed: seed of the bootstrap resamples.

    Returns:
        per name, ``[iqm, low, high]``.
    """
    columns = {name: np.asarray(v, dtype=float)[:, None] for name, v in scores.items()}
    return {
        name: [float(center[0]), float(low[0]), float(high[0])]
        for name, (center, low, high) in iqm_curves(columns, seed).items()
    }


def aggregates_and_profiles(
    scores: Mapping[str, np.ndarray], taus: Sequence[float], seed: int = 0
) -> tuple[dict[str, dict[str, list[float]]], dict[str, tuple[np.ndarray, ...]]]:
    """``aggregate_metrics`` and ``performance_profiles`` from one bootstrap per method (each
    resample gives both), at half the cost of the two."""
    taus = np.asarray(taus, dtype=float)

    def metrics_and_profile(runs: np.ndarray) -> np.ndarray:
        # rliable's aggregate_median, _iqm, _mean and _optimality_gap (gamma 1), then the
        # fraction of runs above each tau
        four = [
            np.median(runs),
            trimmed_mean(runs),
            np.mean(runs),
            np.mean(1 - np.minimum(runs, 1)),
        ]
        return np.concatenate([four, (runs[..., None] > taus).mean(axis=(0, 1))])

    aggregates, profiles = {}, {}
    for name, (point, low, high) in _intervals(scores, metrics_and_profile, seed).items():
        aggregates[name] = {
            metric: [float(point[k]), float(low[k]), float(high[k])]
            for k, metric in enumerate(METRICS)
        }
        n = len(METRICS)
        profiles[name] = (point[n:], low[n:], high[n:])
    return aggregates, profiles


def aggregate_metrics(
    scores: Mapping[str, np.ndarray], seed: int = 0
) -> dict[str, dict[str, list[float]]]:
    """Median, IQM, mean and optimality gap of normalised final scores, with intervals.

    Args:
        scores: per method, (S,) scores of S seeds normalised so that 1 is the target
            (here the oracle's return).
        seed: seed of the bootstrap resamples.

    Returns:
        per method and metric (``METRICS``), ``[estimate, low, high]``.
    """
    return aggregates_and_profiles(scores, [], seed)[0]


def performance_profiles(
    scores: Mapping[str, np.ndarray], taus: Sequence[float], seed: int = 0
) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Fraction of runs whose normalised score exceeds each tau, with intervals.

    Args:
        scores: per method, (S,) normalised scores.
        taus: (T,) thresholds.
        seed: seed of the bootstrap resamples.

    Returns:
        per method, (T,) fractions, (T,) lower and (T,) upper bounds.
    """
    return aggregates_and_profiles(scores, taus, seed)[1]


def improvement_probabilities(
    scores: Mapping[str, np.ndarray], pairs: Sequence[tuple[str, str]], seed: int = 0
) -> dict[str, list[float]]:
    """P(X > Y): the probability that a run of X scores above a run of Y, with intervals
    from resampling both methods' runs independently.

    Args:
        scores: per method, (S,) scores.
        pairs: (X, Y) method names.
        seed: seed of the bootstrap resamples.

    Returns:
        per pair ``"X,Y"``, ``[estimate, low, high]``.
    """
    from rliable import library as rly

    out = {}
    with _seeded(seed):
        for x, y in pairs:
            sx = np.asarray(scores[x], dtype=float)[:, None]
            sy = np.asarray(scores[y], dtype=float)[:, None]
            point = improvement_probability(sx, sy)
            if min(len(sx), len(sy)) < 2:
                out[f"{x},{y}"] = [point, point, point]
                continue
            _, ci = rly.get_interval_estimates(
                {"pair": [sx, sy]},
                improvement_probability,
                reps=RESAMPLES,
                confidence_interval_size=CONFIDENCE,
            )
            low, high = np.ravel(ci["pair"])
            out[f"{x},{y}"] = [point, min(float(low), point), max(float(high), point)]
    return out


# -- pictures (rliable's own plots) ---------------------------------------------------------
def _save(fig, path: Path) -> None:
    fig.savefig(path, dpi=120, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)


def method_colors(methods: Sequence[str]) -> dict[str, tuple]:
    """A colour per method, rliable's palette in the order given: pass it to every picture
    of one comparison so that a method keeps its colour."""
    import seaborn as sns

    palette = sns.color_palette("colorblind", max(10, len(methods)))
    return {m: palette[i] for i, m in enumerate(methods)}


def plot_aggregates(
    path: Path,
    aggregates: Mapping[str, Mapping[str, list[float]]],
    xlabel: str = "return / oracle",
    colors: Mapping[str, tuple] | None = None,
) -> None:
    """Rliable's interval plot of ``aggregate_metrics``' output (the metrics it holds), one
    colour per method (``method_colors``)."""
    import matplotlib

    matplotlib.use("Agg")
    from rliable import plot_utils

    metrics = [k for k in METRICS if k in next(iter(aggregates.values()))]
    points = {m: np.array([v[k][0] for k in metrics]) for m, v in aggregates.items()}
    cis = {
        m: np.array([[v[k][1] for k in metrics], [v[k][2] for k in metrics]])
        for m, v in aggregates.items()
    }
    # The label's height is a share of the figure, whose height follows the methods.
    below = -1.8 / len(points)
    fig, _ = plot_utils.plot_interval_estimates(
        points, cis, metric_names=metrics, xlabel=xlabel, xlabel_y_coordinate=below, colors=colors
    )
    _save(fig, path)


def plot_profiles(
    path: Path,
    profiles: Mapping[str, tuple[np.ndarray, ...]],
    taus: Sequence[float],
    score: str = "return / oracle",
    colors: Mapping[str, tuple] | None = None,
) -> None:
    """Rliable's performance-profile plot of ``performance_profiles``' output."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from rliable import plot_utils

    fig, ax = plt.subplots(figsize=(7, 4.5))
    plot_utils.plot_performance_profiles(
        {m: p[0] for m, p in profiles.items()},
        np.asarray(taus),
        performance_profile_cis={m: np.stack([p[1], p[2]]) for m, p in profiles.items()},
        xlabel=rf"{score} ($\tau$)",
        colors=colors,
        ax=ax,
    )
    # One line a method, in order (the bands around them are not legend entries).
    ax.legend(ax.get_lines()[: len(profiles)], list(profiles), fontsize="small", loc="lower left")
    _save(fig, path)


def plot_sample_efficiency(
    path: Path,
    budgets: Sequence[int],
    curves: Mapping[str, tuple[np.ndarray, ...]],
    oracle: float | None = None,
    colors: Mapping[str, tuple] | None = None,
) -> None:
    """Rliable's sample-efficiency plot of ``iqm_curves``' output (log x), with the oracle's
    return and 90% of it as dashed and dotted lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from rliable import plot_utils

    fig, ax = plt.subplots(figsize=(7, 4.5))
    plot_utils.plot_sample_efficiency_curve(
        np.asarray(budgets),
        {m: c[0] for m, c in curves.items()},
        {m: np.stack([c[1], c[2]]) for m, c in curves.items()},
        xlabel="environment interactions",
        ylabel="IQM return",
        labelsize="medium",
        ticklabelsize="medium",
        colors=colors,
        ax=ax,
    )
    if oracle is not None:
        ax.axhline(oracle, color="k", linestyle="--", label="oracle (true state)")
        ax.axhline(0.9 * oracle, color="k", linestyle=":", label="90% of oracle")
    ax.set_xscale("log")
    ax.legend(fontsize="small")
    _save(fig, path)


def plot_improvement(path: Path, probabilities: Mapping[str, list[float]]) -> None:
    """Rliable's probability-of-improvement plot of ``improvement_probabilities``' output."""
    import matplotlib

    matplotlib.use("Agg")
    from rliable import plot_utils

    ax = plot_utils.plot_probability_of_improvement(
        {pair: np.array([p[0]]) for pair, p in probabilities.items()},
        {pair: np.array([[p[1]], [p[2]]]) for pair, p in probabilities.items()},
        figsize=(5, 0.5 + 0.45 * len(probabilities)),
    )
    _save(ax.figure, path)


def success_interval(successes: int, trials: int) -> list[float]:
    """95% Wilson interval [low, high] of a success rate of ``successes`` in ``trials``."""
    from scipy import stats

    ci = stats.binomtest(successes, trials).proportion_ci(method="wilson")
    return [float(ci.low), float(ci.high)]
