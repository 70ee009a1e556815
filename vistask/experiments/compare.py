"""RLVC (with and without compound features) against Stable-Baselines3 DQN/PPO, tabular
Q-learning on the true state, and random actions; on an env with continuous actions, RLJC
against SB3 SAC/PPO and random actions: on the same interaction budgets, seeds and evaluation
starts (``scripts/compare_baselines.py``), on an env with an oracle (the visual mazes, the
visual mountain car: ``tasks.py``).

Every method is scored at every budget B (environment interactions) by its task's evaluation:
the mean discounted return from the same fixed starts with the same noise. RLVC
(and RLJC) learns from one fixed database, so its checkpoint at B is a fresh agent learned on B
interactions; the other learners train once per seed and are evaluated when they pass B.
These independent runs go side by side (``vistask.parallel``) and each lands in ``runs.jsonl`` as it
ends, so that a stopped comparison resumes. Curves are aggregated over seeds with rliable
(``statistics.py``): interquartile mean (IQM) with stratified-bootstrap confidence intervals,
performance profiles and probabilities of improvement.
"""

from __future__ import annotations

import csv
import functools
import json
import tempfile
import time
from collections.abc import Callable, Sequence
from contextlib import nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

from vistask.agents import RLJCAgent, RLVCAgent, TabularQAgent
from vistask.checks import check_at_least
from vistask.envs.maze_oracle import Policy
from vistask.experiments import statistics
from vistask.experiments.tasks import GridCells, Task, task_for
from vistask.parallel import Outcome, cluster_address, map_runs, ray_session
from vistask.rlvc import random_policy
from vistask.runs import (
    append_record,
    check_same_settings,
    print_table,
    read_records,
    run_dir,
    tensorboard,
    write_summary,
)

DISCRETE_METHODS = ("rlvc", "rlvc_compounds", "dqn", "ppo", "tabular", "random")
CONTINUOUS_METHODS = ("rljc", "sac", "ppo", "random")
METHODS = tuple(dict.fromkeys(DISCRETE_METHODS + CONTINUOUS_METHODS))
DEFAULT_BUDGETS = (1_000, 2_000, 5_000, 10_000, 20_000, 50_000, 100_000, 200_000, 300_000)
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
            defaults, which are rl-zoo3's tuned settings for Atari images where it has them:
            see ``sb3_kwargs``).
        ppo_envs: environments PPO collects from side by side (rl-zoo3's Atari setting: 8).
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
        ppo_envs: int = 8,
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
        check_at_least(1, seeds=seeds, eval_starts=eval_starts, ppo_envs=ppo_envs)
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
        self.ppo_envs = ppo_envs

    def params(self) -> dict:
        """The constructor's arguments (written to ``summary.json``)."""
        return dict(vars(self))

    @classmethod
    def quick(cls, **overrides) -> Comparison:
        """Tiny budgets for tests: two seeds, small SB3 buffers and rollouts."""
        small = {
            "budgets": QUICK_BUDGETS,
            "seeds": 2,
            "eval_starts": 20,
            "dqn_kwargs": {"learning_starts": 100, "buffer_size": 1_000, "train_freq": 8},
            "ppo_kwargs": {"n_steps": 32, "batch_size": 64, "n_epochs": 2},
            "sac_kwargs": {"learning_starts": 100, "buffer_size": 1_000, "batch_size": 32},
        }
        return cls(**{**small, **overrides})

    def sb3_kwargs(self, method: str) -> dict:
        """Constructor arguments of the SB3 baseline ``method`` ("dqn", "ppo" or "sac").

        DQN and PPO take rl-zoo3's hyperparameters for Atari's images (its ``dqn.yml`` and
        ``ppo.yml``), scaled where they assume 10 million steps: DQN starts learning after
        a tenth of the largest budget instead of 100,000 steps. SAC has no Atari setting;
        it gets SB3's defaults with a cheaper update schedule for the CPU.
        """
        largest = max(self.budgets)
        if method == "dqn":
            zoo = {
                "buffer_size": min(100_000, largest),
                "learning_rate": 1e-4,
                "batch_size": 32,
                "learning_starts": min(100_000, largest // 10),
                "target_update_interval": 1_000,
                "train_freq": 4,
                "gradient_steps": 1,
                "exploration_fraction": 0.1,
                "exploration_final_eps": 0.01,
            }
            return {**zoo, **self.dqn_kwargs}
        if method == "ppo":
            zoo = {
                "n_steps": 128,
                "n_epochs": 4,
                "batch_size": 256,
                "learning_rate": _linear(2.5e-4),
                "clip_range": _linear(0.1),
                "vf_coef": 0.5,
                "ent_coef": 0.01,
            }
            return {**zoo, **self.ppo_kwargs}
        if method == "sac":
            # SB3's default, a batch of 256 images every interaction, takes 137 ms a step on a
            # 2-core CPU (2.3 hours a seed at 60,000); a batch of 64 every 4 steps takes 12 ms.
            replay = {
                "buffer_size": min(50_000, largest),
                "learning_starts": min(1_000, largest // 10),
            }
            return {**replay, "batch_size": 64, "train_freq": 4, **self.sac_kwargs}
        raise ValueError(f"no SB3 baseline called {method!r}")


def _linear(start: float) -> Callable[[float], float]:
    """rl-zoo3's ``lin_<start>``: decays linearly to 0 over the run (SB3 passes the progress
    remaining, 1 -> 0)."""
    return lambda progress_remaining: progress_remaining * start


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
    # Training seconds behind each budget's policy (evaluation excluded): the x of the
    # return-against-wall-clock curves.
    seconds_at: list[float] | None = None


# evaluate(policy) -> mean discounted return from the fixed starts;
# log(budget, value, training seconds behind the policy evaluated).
Evaluate = Callable[[Policy], float]
Log = Callable[[int, float, float], None]


def _random_policy(seed: int, space: gym.spaces.Space) -> Policy:
    rng, policy = np.random.default_rng(seed), random_policy(space)
    return lambda percepts, positions: policy(percepts, rng)


def _model_policy(model) -> Policy:
    """An SB3 model (or anything with ``predict``) on percepts, batched."""
    return lambda percepts, positions: model.predict(percepts, deterministic=True)[0]


def run_visual(
    config: Comparison,
    method: str,
    seed: int,
    budgets: Sequence[int],
    evaluate: Evaluate,
    log: Log,
) -> tuple[list[float], list[float], list[int]]:
    """A fresh RLVCAgent ("rlvc", "rlvc_compounds") or RLJCAgent ("rljc") per budget: they
    learn from a fixed database of B interactions.

    Every ``run_*`` returns the evaluation return at each budget and the training seconds
    behind each (evaluation excluded); ``log`` receives each (budget, return, seconds) as it
    is measured. RLVC and RLJC also return their number of classes at each budget.
    """
    returns, seconds, classes = [], [], []
    for budget in budgets:
        env = gym.make(config.env_id, **config.env_kwargs)
        t0 = time.perf_counter()
        if method == "rljc":
            agent = RLJCAgent(env, seed=seed)
        else:
            agent = RLVCAgent(env, compounds=method == "rlvc_compounds", seed=seed)
        agent.learn(budget, progress_bar=False)
        seconds.append(time.perf_counter() - t0)
        returns.append(evaluate(lambda percepts, positions, a=agent: a.predict(percepts)[0]))
        classes.append(agent.learner.n_classes)
        log(budget, returns[-1], seconds[-1])
    return returns, seconds, classes


def run_tabular(
    config: Comparison,
    seed: int,
    budgets: Sequence[int],
    evaluate: Evaluate,
    log: Log,
    task: Task,
    grid: int,
) -> tuple[list[float], list[float]]:
    """Q-learning on true-state grid cells, trained once and evaluated at every budget."""
    env = GridCells(gym.make(config.env_id, **config.env_kwargs), task, grid)
    agent = TabularQAgent(env, seed=seed)
    policy = lambda percepts, states: agent.predict(task.cells(states, grid))[0]  # noqa: E731
    returns, seconds, train = [], [], 0.0
    for budget in budgets:
        t0 = time.perf_counter()
        agent.learn(budget - agent.num_timesteps, reset_num_timesteps=False)
        train += time.perf_counter() - t0
        seconds.append(train)
        returns.append(evaluate(policy))
        log(budget, returns[-1], train)
    return returns, seconds


def run_random(
    seed: int, budgets: Sequence[int], evaluate: Evaluate, log: Log, task: Task
) -> tuple[list[float], list[float]]:
    """Uniformly random actions: no learning, the same score at every budget up to noise."""
    returns = []
    for budget in budgets:
        returns.append(evaluate(_random_policy(seed + budget, task.env.action_space)))
        log(budget, returns[-1], 0.0)
    return returns, [0.0] * len(returns)


def run_sb3(
    config: Comparison,
    method: str,
    seed: int,
    budgets: Sequence[int],
    evaluate: Evaluate,
    log: Log,
    tb_dir: Path,
) -> tuple[list[float], list[float]]:
    """SB3 DQN, PPO or SAC with ``CnnPolicy`` on the raw percepts, one ``learn`` call whose
    callback evaluates the current policy when it passes each budget."""
    from stable_baselines3 import DQN, PPO, SAC
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env

    budgets, returns, seconds = list(budgets), [], []
    clock = {"start": 0.0, "evaluating": 0.0}

    class EvaluateAtBudgets(BaseCallback):
        def _on_step(self) -> bool:
            while len(returns) < len(budgets) and self.num_timesteps >= budgets[len(returns)]:
                t0 = time.perf_counter()
                seconds.append(t0 - clock["start"] - clock["evaluating"])
                returns.append(evaluate(_model_policy(self.model)))
                clock["evaluating"] += time.perf_counter() - t0
                log(budgets[len(returns) - 1], returns[-1], seconds[-1])
            return len(returns) < len(budgets)

    cls = {"dqn": DQN, "ppo": PPO, "sac": SAC}[method]
    if method == "ppo":
        env = make_vec_env(
            config.env_id, n_envs=config.ppo_envs, seed=seed, env_kwargs=config.env_kwargs
        )
    else:
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
    clock["start"] = time.perf_counter()
    model.learn(
        total_timesteps=max(budgets), callback=EvaluateAtBudgets(), tb_log_name=f"{method}-sb3"
    )
    return returns, seconds


VISUAL_METHODS = ("rlvc", "rlvc_compounds", "rljc")  # a fresh agent per budget


@dataclass(frozen=True)
class RunSpec:
    """One independent run: ``method`` with ``seed`` evaluated at ``budgets`` (one budget
    for the visual learners, which learn afresh per budget; all budgets for the others,
    which train once); the tabular baseline on a ``grid`` per dimension."""

    method: str
    seed: int
    budgets: tuple[int, ...]
    grid: int | None = None

    @property
    def key(self) -> tuple[str, int, tuple[int, ...]]:
        return (self.method, self.seed, self.budgets)


def run_specs(config: Comparison, methods: Sequence[str], grid: int | None) -> list[RunSpec]:
    """The independent runs of ``methods``: per seed, one per budget for the visual
    learners, one for all budgets otherwise. The longest come first (the deep baselines, then
    the largest budgets), so that the runs finishing last are short ones."""
    specs = []
    for method in methods:
        for seed in range(config.seed0, config.seed0 + config.seeds):
            if method in VISUAL_METHODS:
                specs += [RunSpec(method, seed, (b,)) for b in config.budgets]
            else:
                specs.append(RunSpec(method, seed, config.budgets, grid))
    return sorted(specs, key=lambda s: (s.method not in ("dqn", "ppo", "sac"), -max(s.budgets)))


def run_method(config: Comparison, spec: RunSpec, task: Task, tb_root: Path) -> RunResult:
    """Train and evaluate one ``spec``; logs ``eval/return`` against interactions to
    ``tb_root/<method>-seed<seed>``."""
    method, seed, budgets = spec.method, spec.seed, spec.budgets

    def evaluate(policy: Policy) -> float:
        return task.evaluate(policy).mean

    writer = tensorboard(tb_root / f"{method}-seed{seed}")

    def log(budget: int, value: float, seconds: float) -> None:
        writer.add_scalar("eval/return", value, budget)
        writer.add_scalar("eval/train_seconds", seconds, budget)
        writer.flush()

    t0, classes = time.perf_counter(), None
    if method in ("dqn", "ppo", "sac"):
        sb3_logs = tb_root / f"seed{seed}"
        returns, at = run_sb3(config, method, seed, budgets, evaluate, log, sb3_logs)
    elif method in VISUAL_METHODS:
        returns, at, classes = run_visual(config, method, seed, budgets, evaluate, log)
    elif method == "tabular":
        returns, at = run_tabular(config, seed, budgets, evaluate, log, task, spec.grid)
    else:
        returns, at = run_random(seed, budgets, evaluate, log, task)
    writer.close()
    if len(returns) != len(budgets):
        raise RuntimeError(f"{method} produced {len(returns)} of {len(budgets)} returns")
    # A visual learner's budgets are separate agents; the others train one agent on.
    train = sum(at) if method in VISUAL_METHODS else at[-1]
    seconds = time.perf_counter() - t0
    return RunResult(method, seed, list(budgets), returns, train, seconds, classes, at)


def _task(config: Comparison) -> Task | None:
    """The comparison's task, built once per process (the oracle's solution takes a while)."""
    return _cached_task(
        config.env_id, json.dumps(config.env_kwargs, sort_keys=True), config.eval_starts
    )


@functools.lru_cache(maxsize=4)
def _cached_task(env_id: str, env_kwargs: str, eval_starts: int) -> Task | None:
    return task_for(env_id, json.loads(env_kwargs), eval_starts)


def execute(job: tuple[Comparison, RunSpec]) -> tuple[RunResult, dict[str, bytes]]:
    """One run wherever it executes (this process, a worker process, a Ray cluster's node):
    its result and its TensorBoard files (path under ``tensorboard/`` -> bytes), which the
    caller writes into the comparison's folder."""
    config, spec = job
    task = _task(config)
    with tempfile.TemporaryDirectory() as tmp:
        result = run_method(config, spec, task, Path(tmp))
        files = {
            str(f.relative_to(tmp)): f.read_bytes() for f in Path(tmp).rglob("*") if f.is_file()
        }
    return result, files


def merge_runs(units: Sequence[RunResult], budgets: Sequence[int]) -> list[RunResult]:
    """Per (method, seed), the runs of its budgets joined into one covering ``budgets``;
    pairs with a budget missing (a run that failed) are left out."""
    groups: dict[tuple[str, int], list[RunResult]] = {}
    for r in units:
        groups.setdefault((r.method, r.seed), []).append(r)
    merged = []
    for (method, seed), runs in groups.items():
        at = {}  # budget -> (return, classes, training seconds)
        for r in runs:
            for j, b in enumerate(r.budgets):
                at[b] = (r.returns[j], _item(r.classes, j), _item(r.seconds_at, j))
        if set(at) != set(budgets):
            continue
        returns, classes, seconds = (list(v) for v in zip(*(at[b] for b in budgets), strict=True))
        merged.append(
            RunResult(
                method,
                seed,
                list(budgets),
                returns,
                sum(r.train_seconds for r in runs),
                sum(r.seconds for r in runs),
                None if classes[0] is None else classes,
                None if seconds[0] is None else seconds,
            )
        )
    return merged


def _item(values: list | None, j: int):
    return None if values is None else values[j]


def tabular_grid(results: list[RunResult]) -> int:
    """Cells per dimension giving the tabular baseline as many cells as RLVC's classes (the
    median over seeds at the largest budget; RLVC with compounds if it ran)."""
    runs = [r for r in results if r.method == "rlvc_compounds"] or [
        r for r in results if r.method == "rlvc"
    ]
    if not runs:
        raise ValueError("grid=None matches RLVC's classes: include an rlvc method")
    return max(1, round(float(np.sqrt(np.median([r.classes[-1] for r in runs])))))


# -- aggregation --------------------------------------------------------------------------
def interactions_to(budgets: Sequence[int], curve: np.ndarray, target: float) -> int | None:
    """The first budget at which ``curve`` reaches ``target`` (None if it never does)."""
    hits = np.flatnonzero(np.asarray(curve) >= target)
    return int(budgets[hits[0]]) if len(hits) else None


def aggregate(
    results: list[RunResult], budgets: Sequence[int], oracle_return: float
) -> dict[str, dict]:
    """Per method: IQM curve with its stratified-bootstrap CI (rliable), interactions to each
    threshold (from the IQM, and the interval given by the CI's upper and lower curves),
    final return and seconds."""
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


PROFILE_TAUS = np.linspace(0.0, 1.2, 25)  # thresholds on return / oracle


def final_statistics(methods: dict[str, dict], learner: str | None) -> dict[str, object]:
    """rliable's view of the final returns as fractions of the oracle's: median, IQM, mean
    and optimality gap with intervals, performance profiles, and the probability that a
    ``learner`` run beats a run of each other method."""
    scores = {
        name: m["curve"]["per_seed"][:, -1] / m["oracle_return"] for name, m in methods.items()
    }
    aggregates, profiles = statistics.aggregates_and_profiles(scores, PROFILE_TAUS)
    pairs = [(learner, other) for other in methods if other != learner] if learner else []
    return {
        "aggregates": aggregates,
        "profiles": {
            "taus": PROFILE_TAUS,
            **{
                name: {"fraction": p[0], "ci_low": p[1], "ci_high": p[2]}
                for name, p in profiles.items()
            },
        },
        "improvement": statistics.improvement_probabilities(scores, pairs),
    }


def write_pictures(out: Path, methods: dict[str, dict], stats: dict, budgets, oracle: float):
    """rliable's plots: ``curves.png`` (IQM return against interactions, log x, with 95%
    intervals), ``aggregates.png``, ``profiles.png`` and ``improvement.png``; and
    ``wallclock.png``, the return against training seconds."""
    curves = {
        name: (np.array(c["iqm"]), np.array(c["ci_low"]), np.array(c["ci_high"]))
        for name, c in ((n, m["curve"]) for n, m in methods.items())
    }
    statistics.plot_sample_efficiency(out / "curves.png", budgets, curves, oracle)
    statistics.plot_aggregates(out / "aggregates.png", stats["aggregates"])
    profiles = {
        name: (np.array(p["fraction"]), np.array(p["ci_low"]), np.array(p["ci_high"]))
        for name, p in stats["profiles"].items()
        if name != "taus"
    }
    statistics.plot_profiles(out / "profiles.png", profiles, PROFILE_TAUS)
    plot_wallclock(out / "wallclock.png", methods, oracle)
    if stats["improvement"]:
        statistics.plot_improvement(out / "improvement.png", stats["improvement"])


def plot_wallclock(path: Path, methods: dict[str, dict], oracle: float) -> None:
    """IQM return against the median training seconds behind it (log x), per method that
    trains (the random baseline does not)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name, m in methods.items():
        seconds = m["curve"].get("train_seconds")
        if seconds is None or not np.all(np.asarray(seconds) > 0):
            continue
        ax.plot(seconds, m["curve"]["iqm"], marker="o", label=name)
    ax.axhline(oracle, color="k", linestyle="--", label="oracle (true state)")
    ax.axhline(0.9 * oracle, color="k", linestyle=":", label="90% of oracle")
    ax.set_xscale("log")
    ax.set_xlabel("training seconds (median over seeds; one CPU thread a run)")
    ax.set_ylabel("IQM discounted return")
    ax.legend(fontsize="small")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


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
    task = _task(config)
    if task is None:
        raise TypeError(
            f"the comparison scores policies against an oracle, and {config.env_id} has none: "
            "use vistask/VisualMaze-v0 or vistask/VisualMountainCar-v0"
        )
    oracle_return = task.oracle_return
    units = load_finished(out, config)
    finished = {(r.method, r.seed, tuple(r.budgets)) for r in units}
    failed: list[dict] = []

    def record(outcome: Outcome) -> None:
        spec = outcome.item[1]
        if not outcome.ok:
            failed.append({**asdict(spec), "error": outcome.error})
            if progress:
                print(
                    f"{spec.method} seed {spec.seed} {list(spec.budgets)} FAILED: "
                    f"{outcome.error.strip().splitlines()[-1]}",
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
        raise RuntimeError("every run failed:\n" + "\n".join(f["error"] for f in failed))
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
        "tabular_grid": grid,
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
                k: _fmt(v) if not isinstance(v, list) else str([_fmt(x) for x in v])
                for k, v in summary["ratios"].items()
            }
        )
    if failed:
        print(
            f"{len(failed)} runs failed (errors in summary.json, 'failed'); the same command "
            "runs them again and keeps the finished ones"
        )
    return summary
