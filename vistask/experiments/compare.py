"""RLVC (with and without compound features) against Stable-Baselines3 DQN/PPO, tabular
Q-learning on the true state, and random actions; on an env with continuous actions, RLJC
against SB3 SAC/PPO and random actions: on the same interaction budgets, seeds and evaluation
starts (``scripts/compare_baselines.py``), on an env with an oracle (the visual mazes, the
visual mountain car: ``tasks.py``).

Every method is scored at every budget B (environment interactions) by its task's evaluation:
the mean discounted return from the same fixed starts with the same noise. RLVC
(and RLJC) learns from one fixed database, so its checkpoint at B is a fresh agent learned on B
interactions; the other learners train once per seed and are evaluated when they pass B.
Curves are aggregated over seeds with the interquartile mean (IQM) and percentile-bootstrap
confidence intervals.
"""

from __future__ import annotations

import csv
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
from scipy import stats

from vistask.agents import RLJCAgent, RLVCAgent, TabularQAgent
from vistask.checks import check_at_least
from vistask.envs.maze_oracle import Policy
from vistask.experiments.tasks import GridCells, Task, task_for
from vistask.rlvc import random_policy
from vistask.runs import print_table, run_dir, tensorboard, write_summary

DISCRETE_METHODS = ("rlvc", "rlvc_compounds", "dqn", "ppo", "tabular", "random")
CONTINUOUS_METHODS = ("rljc", "sac", "ppo", "random")
METHODS = tuple(dict.fromkeys(DISCRETE_METHODS + CONTINUOUS_METHODS))
DEFAULT_BUDGETS = (1_000, 2_000, 5_000, 10_000, 20_000, 50_000, 100_000)
QUICK_BUDGETS = (300, 1_000)
THRESHOLDS = (0.9, 0.75)  # fractions of the oracle's return; 0.9 is the target


# -- configuration ------------------------------------------------------------------------
class Comparison:
    """What a comparison runs: methods, budgets, seeds, the env and the baselines' settings.

    Example:
        >>> summary = compare(Comparison(methods=("rlvc", "tabular"), seeds=3), out="runs/c")

    Args:
        env_id, env_kwargs: the environment (``gym.make`` arguments): one with an oracle
            (``tasks.task_for``).
        methods: subset of ``DISCRETE_METHODS`` for an env with discrete actions, of
            ``CONTINUOUS_METHODS`` for continuous ones (None: all of them).
        budgets: increasing interaction budgets at which every method is evaluated.
        seeds: number of seeds (seed k uses ``seed0 + k``).
        seed0: first seed.
        eval_starts: number of fixed evaluation start positions.
        grid: cells per dimension of the tabular baseline's true-state grid (None: as many
            cells as RLVC's classes at the largest budget, the paper's "equivalent number of
            states"; RLVC then runs first).
        dqn_kwargs, ppo_kwargs, sac_kwargs: extra SB3 constructor arguments (override the
            defaults).
        device: torch device of the SB3 networks.
    """

    def __init__(
        self,
        env_id: str = "vistask/VisualMaze-v0",
        env_kwargs: dict | None = None,
        methods: Sequence[str] | None = None,
        budgets: Sequence[int] = DEFAULT_BUDGETS,
        seeds: int = 5,
        seed0: int = 0,
        eval_starts: int = 100,
        grid: int | None = 10,
        dqn_kwargs: dict | None = None,
        ppo_kwargs: dict | None = None,
        sac_kwargs: dict | None = None,
        device: str = "cpu",
    ) -> None:
        env = gym.make(env_id, **(env_kwargs or {}))
        continuous = isinstance(env.action_space, gym.spaces.Box)
        env.close()
        allowed = CONTINUOUS_METHODS if continuous else DISCRETE_METHODS
        methods = allowed if methods is None else tuple(methods)
        budgets = tuple(int(b) for b in budgets)
        unknown = set(methods) - set(allowed)
        if unknown or not methods:
            kind = "continuous" if continuous else "discrete"
            raise ValueError(
                f"{env_id} has {kind} actions: methods must be a non-empty subset of "
                f"{allowed}, got {methods}"
            )
        if not budgets or min(budgets) < 1 or list(budgets) != sorted(set(budgets)):
            raise ValueError(f"budgets must be strictly increasing positive ints, got {budgets}")
        check_at_least(1, seeds=seeds, eval_starts=eval_starts)
        if grid is not None:
            check_at_least(1, grid=grid)
        elif "tabular" in methods and not any(m.startswith("rlvc") for m in methods):
            raise ValueError(
                "grid=None sizes the tabular grid by RLVC's classes: add an rlvc method"
            )
        self.env_id, self.env_kwargs = env_id, dict(env_kwargs or {})
        self.methods, self.budgets, self.seeds, self.seed0 = methods, budgets, seeds, seed0
        self.eval_starts, self.grid, self.device = eval_starts, grid, device
        self.dqn_kwargs, self.ppo_kwargs = dict(dqn_kwargs or {}), dict(ppo_kwargs or {})
        self.sac_kwargs = dict(sac_kwargs or {})

    def params(self) -> dict:
        """The constructor's arguments (written to ``summary.json``)."""
        return dict(vars(self))

    @classmethod
    def quick(cls, **overrides) -> Comparison:
        """Tiny budgets for tests: two seeds, small SB3 buffers and rollouts, 256 words."""
        small = {
            "budgets": QUICK_BUDGETS,
            "seeds": 2,
            "eval_starts": 20,
            "dqn_kwargs": {"learning_starts": 100, "buffer_size": 1_000, "train_freq": 8},
            "ppo_kwargs": {"n_steps": 128, "batch_size": 64, "n_epochs": 2},
            "sac_kwargs": {"learning_starts": 100, "buffer_size": 1_000, "batch_size": 32},
        }
        return cls(**{**small, **overrides})

    def sb3_kwargs(self, method: str) -> dict:
        """Constructor arguments of the SB3 baseline ``method`` ("dqn", "ppo" or "sac")."""
        # Replay memory of 64x64x3 images: cap it (SB3's default 1M would need 12 GB).
        replay = {
            "buffer_size": min(50_000, max(self.budgets)),
            "learning_starts": min(1_000, max(self.budgets) // 10),
        }
        if method == "dqn":
            return {**replay, "exploration_fraction": 0.2, **self.dqn_kwargs}
        if method == "sac":
            # SB3's default, a batch of 256 images every interaction, takes 137 ms a step on a
            # 2-core CPU (2.3 hours a seed at 60,000); a batch of 64 every 4 steps takes 12 ms.
            cpu = {"batch_size": 64, "train_freq": 4}
            return {**replay, **cpu, **self.sac_kwargs}
        if method == "ppo":
            return {"n_steps": 512, "batch_size": 64, **self.ppo_kwargs}
        raise ValueError(f"no SB3 baseline called {method!r}")


# -- one run: (method, seed) -> returns at every budget -----------------------------------
@dataclass
class RunResult:
    """Mean evaluation return of one (method, seed) at every budget, and its cost."""

    method: str
    seed: int
    budgets: list[int]
    returns: list[float]
    train_seconds: float
    seconds: float
    classes: list[int] | None = None  # RLVC's (RLJC's joint) classes at each budget


# evaluate(policy) -> mean discounted return from the fixed starts; log(budget, value).
Evaluate = Callable[[Policy], float]
Log = Callable[[int, float], None]


def _random_policy(seed: int, space: gym.spaces.Space) -> Policy:
    rng, policy = np.random.default_rng(seed), random_policy(space)
    return lambda percepts, positions: policy(percepts, rng)


def _model_policy(model) -> Policy:
    """An SB3 model (or anything with ``predict``) on percepts, batched."""
    return lambda percepts, positions: model.predict(percepts, deterministic=True)[0]


def run_visual(
    config: Comparison, method: str, seed: int, evaluate: Evaluate, log: Log
) -> tuple[list[float], float, list[int]]:
    """A fresh RLVCAgent ("rlvc", "rlvc_compounds") or RLJCAgent ("rljc") per budget: they
    learn from a fixed database of B interactions.

    Every ``run_*`` returns the evaluation return at each budget and the training seconds
    (evaluation excluded); ``log`` receives each (budget, return) as it is measured. RLVC and
    RLJC also return their number of classes at each budget.
    """
    returns, train, classes = [], 0.0, []
    for budget in config.budgets:
        env = gym.make(config.env_id, **config.env_kwargs)
        t0 = time.perf_counter()
        if method == "rljc":
            agent = RLJCAgent(env, seed=seed)
        else:
            agent = RLVCAgent(env, compounds=method == "rlvc_compounds", seed=seed)
        agent.learn(budget, progress_bar=False)
        train += time.perf_counter() - t0
        returns.append(evaluate(lambda percepts, positions, a=agent: a.predict(percepts)[0]))
        classes.append(agent.learner.n_classes)
        log(budget, returns[-1])
    return returns, train, classes


def run_tabular(
    config: Comparison, seed: int, evaluate: Evaluate, log: Log, task: Task, grid: int
) -> tuple[list[float], float]:
    """Q-learning on true-state grid cells, trained once and evaluated at every budget."""
    env = GridCells(gym.make(config.env_id, **config.env_kwargs), task, grid)
    agent = TabularQAgent(env, seed=seed)
    policy = lambda percepts, states: agent.predict(task.cells(states, grid))[0]  # noqa: E731
    returns, train = [], 0.0
    for budget in config.budgets:
        t0 = time.perf_counter()
        agent.learn(budget - agent.num_timesteps, reset_num_timesteps=False)
        train += time.perf_counter() - t0
        returns.append(evaluate(policy))
        log(budget, returns[-1])
    return returns, train


def run_random(
    config: Comparison, seed: int, evaluate: Evaluate, log: Log, task: Task
) -> tuple[list[float], float]:
    """Uniformly random actions: no learning, the same score at every budget up to noise."""
    returns = []
    for budget in config.budgets:
        returns.append(evaluate(_random_policy(seed + budget, task.env.action_space)))
        log(budget, returns[-1])
    return returns, 0.0


def run_sb3(
    config: Comparison, method: str, seed: int, evaluate: Evaluate, log: Log, tb_dir: Path
) -> tuple[list[float], float]:
    """SB3 DQN, PPO or SAC with ``CnnPolicy`` on the raw percepts, one ``learn`` call whose
    callback evaluates the current policy when it passes each budget."""
    from stable_baselines3 import DQN, PPO, SAC
    from stable_baselines3.common.callbacks import BaseCallback

    budgets, returns = list(config.budgets), []
    eval_seconds = [0.0]

    class EvaluateAtBudgets(BaseCallback):
        def _on_step(self) -> bool:
            while len(returns) < len(budgets) and self.num_timesteps >= budgets[len(returns)]:
                t0 = time.perf_counter()
                returns.append(evaluate(_model_policy(self.model)))
                eval_seconds[0] += time.perf_counter() - t0
                log(budgets[len(returns) - 1], returns[-1])
            return len(returns) < len(budgets)

    cls = {"dqn": DQN, "ppo": PPO, "sac": SAC}[method]
    env = gym.make(config.env_id, **config.env_kwargs)
    model = cls(
        "CnnPolicy",
        env,
        seed=seed,
        device=config.device,
        tensorboard_log=str(tb_dir),
        verbose=0,
        **config.sb3_kwargs(method),
    )
    t0 = time.perf_counter()
    model.learn(
        total_timesteps=max(budgets), callback=EvaluateAtBudgets(), tb_log_name=f"{method}-sb3"
    )
    return returns, time.perf_counter() - t0 - eval_seconds[0]


def run_method(
    config: Comparison, method: str, seed: int, task: Task, tb_root: Path, grid: int
) -> RunResult:
    """Train and evaluate ``method`` with ``seed`` (the tabular baseline on a ``grid`` per
    dimension); logs ``eval/return`` against interactions to ``tb_root/<method>-seed<seed>``."""

    def evaluate(policy: Policy) -> float:
        return task.evaluate(policy).mean

    writer = tensorboard(tb_root / f"{method}-seed{seed}")

    def log(budget: int, value: float) -> None:
        writer.add_scalar("eval/return", value, budget)
        writer.flush()

    t0, classes = time.perf_counter(), None
    if method in ("dqn", "ppo", "sac"):
        returns, train = run_sb3(config, method, seed, evaluate, log, tb_root / f"seed{seed}")
    elif method.startswith(("rlvc", "rljc")):
        returns, train, classes = run_visual(config, method, seed, evaluate, log)
    elif method == "tabular":
        returns, train = run_tabular(config, seed, evaluate, log, task, grid)
    else:
        returns, train = run_random(config, seed, evaluate, log, task)
    writer.close()
    if len(returns) != len(config.budgets):
        raise RuntimeError(f"{method} produced {len(returns)} of {len(config.budgets)} returns")
    seconds = time.perf_counter() - t0
    return RunResult(method, seed, list(config.budgets), returns, train, seconds, classes)


def tabular_grid(results: list[RunResult]) -> int:
    """Cells per dimension giving the tabular baseline as many cells as RLVC's classes (the
    median over seeds at the largest budget; RLVC with compounds if it ran)."""
    runs = [r for r in results if r.method == "rlvc_compounds"] or [
        r for r in results if r.method.startswith("rlvc")
    ]
    if not runs:
        raise ValueError("grid=None matches RLVC's classes: include an rlvc method")
    return max(1, round(float(np.sqrt(np.median([r.classes[-1] for r in runs])))))


# -- aggregation --------------------------------------------------------------------------
def iqm(values: np.ndarray, axis: int = 0) -> np.ndarray:
    """Interquartile mean: the mean of the middle 50% along ``axis``."""
    return stats.trim_mean(values, 0.25, axis=axis)


def iqm_ci(
    values: np.ndarray, confidence: float = 0.95, resamples: int = 2000, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """IQM over seeds and its percentile-bootstrap confidence interval, per budget.

    Args:
        values: (S, B) returns of S seeds at B budgets.

    Returns:
        (B,) IQM, (B,) lower and (B,) upper bounds (equal to the IQM with one seed, where
        there is nothing to resample).
    """
    values = np.asarray(values, dtype=float)
    if values.ndim != 2:
        raise ValueError(f"values must be (seeds, budgets), got shape {values.shape}")
    center = iqm(values)
    if len(values) < 2 or np.all(values == values[0]):
        return center, center.copy(), center.copy()
    res = stats.bootstrap(
        (values,),
        iqm,
        axis=0,
        confidence_level=confidence,
        n_resamples=resamples,
        method="percentile",
        rng=np.random.default_rng(seed),
    )
    low, high = res.confidence_interval
    return center, np.minimum(low, center), np.maximum(high, center)


def interactions_to(budgets: Sequence[int], curve: np.ndarray, target: float) -> int | None:
    """The first budget at which ``curve`` reaches ``target`` (None if it never does)."""
    hits = np.flatnonzero(np.asarray(curve) >= target)
    return int(budgets[hits[0]]) if len(hits) else None


def aggregate(
    results: list[RunResult], budgets: Sequence[int], oracle_return: float
) -> dict[str, dict]:
    """Per method: IQM curve with CI, interactions to each threshold (from the IQM, and the
    interval given by the CI's upper and lower curves), final return and seconds."""
    methods = list(dict.fromkeys(r.method for r in results))
    out = {}
    for method in methods:
        runs = [r for r in results if r.method == method]
        values = np.array([r.returns for r in runs])  # (S, B)
        center, low, high = iqm_ci(values)
        entry = {
            "curve": {"iqm": center, "ci_low": low, "ci_high": high, "per_seed": values},
            "final_return": float(center[-1]),
            "final_ci": [float(low[-1]), float(high[-1])],
            "oracle_return": oracle_return,
            "final_ratio": float(center[-1] / oracle_return),
            "seconds": float(sum(r.seconds for r in runs)),
            "train_seconds": float(sum(r.train_seconds for r in runs)),
            "seeds": [r.seed for r in runs],
        }
        for frac in THRESHOLDS:
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
    if learner is None:
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
def _fmt(value) -> str:
    if value is None:
        return "never"
    return f"{value:.3g}" if isinstance(value, float) else str(value)


def markdown_table(methods: dict[str, dict], oracle_return: float) -> str:
    """One row per method: interactions to 90% / 75% of the oracle, final return, seconds."""
    lines = [
        f"Oracle mean discounted return: {oracle_return:.2f}",
        "",
        "| method | interactions to 90% oracle | interactions to 75% oracle (extra) "
        "| final return (IQM [95% CI]) | final / oracle | seconds |",
        "|---|---|---|---|---|---|",
    ]
    for name, m in methods.items():
        lo, hi = m["final_ci"]
        lines.append(
            f"| {name} | {_fmt(m['interactions_to_90pct'])} | {_fmt(m['interactions_to_75pct'])}"
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


def plot_curves(path: Path, methods: dict[str, dict], budgets: Sequence[int], oracle: float):
    """IQM return against interactions (log x), 95% CI bands, oracle and 90% lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name, m in methods.items():
        c = m["curve"]
        (line,) = ax.plot(budgets, c["iqm"], marker="o", label=name)
        ax.fill_between(budgets, c["ci_low"], c["ci_high"], color=line.get_color(), alpha=0.2)
    ax.axhline(oracle, color="k", linestyle="--", label="oracle (true state)")
    ax.axhline(0.9 * oracle, color="k", linestyle=":", label="90% of oracle")
    ax.set_xscale("log")
    ax.set_xlabel("environment interactions")
    ax.set_ylabel("mean discounted return (IQM over seeds)")
    ax.legend(fontsize="small")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# -- the whole comparison -----------------------------------------------------------------
def compare(
    config: Comparison | None = None, out: str | Path | None = None, progress: bool = True
) -> dict:
    """Run every method with every seed, aggregate and write all outputs.

    Writes under ``out`` (default ``runs/compare-<time>/``): ``curves.csv``, ``table.md``,
    ``curves.png``, ``summary.json``, ``runs.jsonl`` (each run as it ends) and ``tensorboard/``
    (``<method>-seed<k>`` with ``eval/return`` against interactions for every method,
    ``seed<k>/<dqn|ppo>-sb3_1`` with SB3's own training logs).

    Args:
        config: the comparison (default ``Comparison()``, the full run).
        out: run directory.
        progress: print one line per finished run.

    Returns:
        The summary written to ``summary.json``.
    """
    config = config or Comparison()
    start = time.perf_counter()
    out = run_dir("compare", out)
    task = task_for(config.env_id, config.env_kwargs, config.eval_starts)
    if task is None:
        raise TypeError(
            f"the comparison scores policies against an oracle, and {config.env_id} has none: "
            "use vistask/VisualMaze-v0 or vistask/VisualMountainCar-v0"
        )
    oracle_return = task.oracle_return
    methods = list(config.methods)
    if config.grid is None and "tabular" in methods:  # its grid follows RLVC's classes
        rlvc_first = sorted(methods, key=lambda m: not m.startswith("rlvc"))
        methods = rlvc_first

    results, grid = [], config.grid
    for method in methods:
        if method == "tabular" and grid is None:
            grid = tabular_grid(results)
        for k in range(config.seeds):
            result = run_method(config, method, config.seed0 + k, task, out / "tensorboard", grid)
            results.append(result)
            with open(out / "runs.jsonl", "a") as runs:  # kept if a later run fails
                runs.write(json.dumps(asdict(result)) + "\n")
            if progress:
                curve = " ".join(f"{r:.1f}" for r in result.returns)
                print(f"{method} seed {result.seed}: {curve} ({result.seconds:.0f} s)", flush=True)

    methods = aggregate(results, config.budgets, oracle_return)
    for m in methods.values():
        m["curve"]["budgets"] = list(config.budgets)
    write_csv(out / "curves.csv", methods, config.budgets)
    table = markdown_table(methods, oracle_return)
    (out / "table.md").write_text(table)
    plot_curves(out / "curves.png", methods, config.budgets, oracle_return)

    summary = {
        "env_id": config.env_id,
        "config": config.params(),
        "oracle_return": oracle_return,
        "budgets": list(config.budgets),
        "tabular_grid": grid,
        "methods": methods,
        "ratios": speedups(methods, config.budgets),
        "runs": [asdict(r) for r in results],
        "seconds": time.perf_counter() - start,
    }
    write_summary(out, summary)
    print(f"Comparison on {config.env_id} -> {out}")
    print(table)
    if summary["ratios"]:
        print_table(
            {
                k: _fmt(v) if not isinstance(v, list) else str([_fmt(x) for x in v])
                for k, v in summary["ratios"].items()
            }
        )
    return summary
