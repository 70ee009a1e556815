"""One run of a comparison: a (method, seed) learned and scored at every budget, in this
process or a worker's."""

from __future__ import annotations

import functools
import json
import shutil
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

from vistask.agents import RLJCAgent, RLVCAgent, TabularQAgent
from vistask.envs.maze_oracle import Policy
from vistask.experiments.comparison import Comparison
from vistask.experiments.tasks import EpisodeTask, GridCells, Task, task_for
from vistask.rlvc import random_policy
from vistask.runs import (
    tensorboard,
)


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


# evaluate(policy) -> mean return from the task's fixed starts or episodes;
# log(budget, value, training seconds behind the policy evaluated).
Evaluate = Callable[[Policy], float]
Log = Callable[[int, float, float], None]


def _random_policy(seed: int, space: gym.spaces.Space) -> Policy:
    rng, policy = np.random.default_rng(seed), random_policy(space)
    return lambda percepts, positions: policy(percepts, rng)


def _model_policy(model, pixels: Callable[[np.ndarray], np.ndarray] | None = None) -> Policy:
    """An SB3 model (or anything with ``predict``) on percepts, batched, each made into the
    model's input by ``pixels`` (``sb3_pixels``) first."""
    convert = pixels or (lambda percepts: percepts)
    return lambda percepts, positions: model.predict(convert(percepts), deterministic=True)[0]


SB3_MIN_SIDE = 36  # the smallest image side SB3's CnnPolicy (NatureCNN) takes


def sb3_pixels(space: gym.spaces.Box) -> Callable[[np.ndarray], np.ndarray] | None:
    """How percepts of the image ``space`` become images SB3's ``CnnPolicy`` takes, or None
    where they already are: a grey (H, W) image gets a channel axis, and an image with a
    side below 36 pixels each pixel repeated by the smallest whole factor that reaches it
    (the same pixels, larger). The function takes one image or a batch (N, ...)."""
    grey = len(space.shape) == 2
    factor = -(-SB3_MIN_SIDE // min(space.shape[:2]))
    if not grey and factor <= 1:
        return None

    def pixels(images: np.ndarray) -> np.ndarray:
        images = images[..., None] if grey else images
        if factor > 1:
            images = images.repeat(factor, axis=-3).repeat(factor, axis=-2)
        return images

    return pixels


def sb3_env(env: gym.Env, pixels: Callable[[np.ndarray], np.ndarray]) -> gym.Env:
    """``env`` with its percepts made into SB3 images by ``pixels``."""
    sample = pixels(env.observation_space.sample())
    space = gym.spaces.Box(0, 255, sample.shape, np.uint8)
    return gym.wrappers.TransformObservation(env, pixels, space)


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
    seed: int, budgets: Sequence[int], evaluate: Evaluate, log: Log, task: Task | EpisodeTask
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
                returns.append(evaluate(_model_policy(self.model, pixels)))
                clock["evaluating"] += time.perf_counter() - t0
                log(budgets[len(returns) - 1], returns[-1], seconds[-1])
            return len(returns) < len(budgets)

    cls = {"dqn": DQN, "ppo": PPO, "sac": SAC}[method]
    env = gym.make(config.env_id, **config.env_kwargs)
    pixels = sb3_pixels(env.observation_space)
    wrap = None if pixels is None else functools.partial(sb3_env, pixels=pixels)
    if method == "ppo":
        env.close()
        # A function, not the id: make_vec_env gives an id render_mode="rgb_array", which
        # envs without it warn of.
        env = make_vec_env(
            functools.partial(gym.make, config.env_id, **config.env_kwargs),
            n_envs=config.ppo_envs,
            seed=seed,
            wrapper_class=wrap,
        )
    elif wrap is not None:
        env = wrap(env)
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
        """The (method, seed, budgets) that identify the run."""
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


def run_method(
    config: Comparison, spec: RunSpec, task: Task | EpisodeTask, tb_root: Path
) -> RunResult:
    """Train and evaluate one ``spec``; logs ``eval/return`` against interactions to
    ``tb_root/<method>-seed<seed>``."""
    method, seed, budgets = spec.method, spec.seed, spec.budgets

    def evaluate(policy: Policy) -> float:
        return task.evaluate(policy).mean

    # A visual learner's budgets are runs of their own, which may end in any order:
    # ``write_eval_log`` writes their points once they are all in.
    writer = None if method in VISUAL_METHODS else tensorboard(tb_root / f"{method}-seed{seed}")

    def log(budget: int, value: float, seconds: float) -> None:
        if writer is not None:
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
    if writer is not None:
        writer.close()
    if len(returns) != len(budgets):
        raise RuntimeError(f"{method} produced {len(returns)} of {len(budgets)} returns")
    # A visual learner's budgets are separate agents; the others train one agent on.
    train = sum(at) if method in VISUAL_METHODS else at[-1]
    seconds = time.perf_counter() - t0
    return RunResult(method, seed, list(budgets), returns, train, seconds, classes, at)


def write_eval_log(tb_root: Path, result: RunResult) -> None:
    """``eval/return`` and ``eval/train_seconds`` of a visual learner's merged run against
    interactions, in their order, to ``tb_root/<method>-seed<seed>`` (replacing it)."""
    path = tb_root / f"{result.method}-seed{result.seed}"
    shutil.rmtree(path, ignore_errors=True)
    writer = tensorboard(path)
    for budget, value, seconds in zip(
        result.budgets, result.returns, result.seconds_at, strict=True
    ):
        writer.add_scalar("eval/return", value, budget)
        writer.add_scalar("eval/train_seconds", seconds, budget)
    writer.close()


def comparison_task(config: Comparison) -> Task | EpisodeTask:
    """The comparison's task, built once per process (the oracle's solution takes a while):
    the env's oracle task, else seeded episodes."""
    return _cached_task(
        config.env_id, json.dumps(config.env_kwargs, sort_keys=True), config.eval_starts
    )


@functools.lru_cache(maxsize=4)
def _cached_task(env_id: str, env_kwargs: str, eval_starts: int) -> Task | EpisodeTask:
    kwargs = json.loads(env_kwargs)
    return task_for(env_id, kwargs, eval_starts) or EpisodeTask(env_id, kwargs, eval_starts)


def execute(job: tuple[Comparison, RunSpec]) -> tuple[RunResult, dict[str, bytes]]:
    """One run wherever it executes (this process, a worker process, a Ray cluster's node):
    its result and its TensorBoard files (path under ``tensorboard/`` -> bytes), which the
    caller writes into the comparison's folder."""
    config, spec = job
    task = comparison_task(config)
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
