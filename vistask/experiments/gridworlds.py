"""RLVC against SB3 PPO and random actions on public MiniGrid tasks seen as full RGB frames:
greedy success at equal interactions, over seeds (``scripts/bench_gridworlds.py``)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from vistask.checks import check_at_least
from vistask.experiments.statistics import iqm_curves
from vistask.parallel import Outcome, RunsFailed, last_line, map_runs
from vistask.rlvc.presence import PackedPresence
from vistask.rlvc.solver import estimate_mdp, value_iteration
from vistask.runs import (
    append_record,
    check_same_settings,
    print_table,
    read_records,
    run_dir,
    write_summary,
)

GRIDWORLDS = (
    "MiniGrid-Empty-8x8-v0",
    "MiniGrid-DoorKey-5x5-v0",
    "MiniGrid-Unlock-v0",
    "MiniGrid-LavaGapS5-v0",
    "MiniGrid-SimpleCrossingS9N1-v0",
    "MiniGrid-MultiRoom-N2-S4-v0",
    "MiniGrid-KeyCorridorS3R1-v0",
)
METHODS = ("rlvc", "ppo", "random")
BUDGETS = (10_000, 25_000, 50_000, 100_000)
FRAME = 64  # pixels of a side of the frames every method sees
EPISODES = 100  # greedy episodes a policy is scored on
EVAL_SEED = 1_000_000  # their reset seeds start here, apart from any training episode's
SUCCESS = 0.9  # the success that "interactions to reach" counts to
# rl-zoo3's ppo.yml entry for MiniGrid (MiniGrid-Empty-Random-5x5-v0 and the tasks that share
# it), here with CnnPolicy on the frames: its VecNormalize is left out, since CnnPolicy
# scales the pixels itself and MiniGrid's rewards lie in [0, 1].
PPO_MINIGRID = {
    "n_steps": 128,
    "batch_size": 64,
    "gae_lambda": 0.95,
    "gamma": 0.99,
    "n_epochs": 10,
    "ent_coef": 0.0,
    "learning_rate": 2.5e-4,
    "clip_range": 0.2,
}
PPO_ENVS = 8

Policy = Callable[[np.ndarray], np.ndarray]  # (B, H, W, 3) frames -> (B,) actions


def make_gridworld(env_id: str, frame: int = FRAME) -> gym.Env:
    """MiniGrid ``env_id`` whose observations are its full RGB frame resized to ``frame`` x
    ``frame`` pixels (``RGBImgObsWrapper``, ``ImgObsWrapper``, ``ResizeObservation``), with
    the env's own episode length.

    Example:
        >>> agent = RLVCAgent(make_gridworld("MiniGrid-DoorKey-5x5-v0")).learn(50_000)
    """
    from minigrid.wrappers import ImgObsWrapper, RGBImgObsWrapper

    check_minigrid(env_id)
    env = ImgObsWrapper(RGBImgObsWrapper(gym.make(env_id)))
    return gym.wrappers.ResizeObservation(env, (frame, frame))


def check_minigrid(env_id: str) -> None:
    """Raise a clear error unless ``env_id`` names a MiniGrid task (gymnasium's own error,
    with its "Did you mean", for an id that is not registered)."""
    import minigrid  # noqa: F401  (registers the MiniGrid ids)

    entry_point = gym.spec(env_id).entry_point
    if not str(getattr(entry_point, "__module__", entry_point)).startswith("minigrid"):
        raise ValueError(
            f"{env_id} is not a MiniGrid task: the gridworld benchmark sees MiniGrid's RGB "
            "frames; compare_baselines.py takes any image env"
        )


def success_rate(
    policy: Policy, env_id: str, episodes: int = EPISODES, seed: int = EVAL_SEED
) -> float:
    """Share of ``episodes`` episodes (reset seeds ``seed + i``) that ``policy`` ends with a
    reward: every MiniGrid task rewards reaching its goal only."""
    envs = [make_gridworld(env_id) for _ in range(episodes)]
    observations = np.stack([e.reset(seed=seed + i)[0] for i, e in enumerate(envs)])
    running = np.ones(episodes, dtype=bool)
    rewarded = np.zeros(episodes, dtype=bool)
    while running.any():
        live = np.flatnonzero(running)
        for i, action in zip(live, policy(observations[live]), strict=True):
            observations[i], reward, terminated, truncated, _ = envs[i].step(action)
            rewarded[i] |= reward > 0
            running[i] = not (terminated or truncated)
    return float(rewarded.mean())


@dataclass(frozen=True)
class GridRun:
    """One run: ``method`` with ``seed`` on ``env_id``, scored at ``budgets`` (RLVC learns
    afresh for each budget, one budget a run; PPO trains once past all of them)."""

    env_id: str
    method: str
    seed: int
    budgets: tuple[int, ...]


def grid_runs(
    envs: Sequence[str], methods: Sequence[str], seeds: Sequence[int], budgets: Sequence[int]
) -> list[GridRun]:
    """Every run of the benchmark, the longest first."""
    runs = []
    for env_id in envs:
        for method in methods:
            for seed in seeds:
                if method == "rlvc":
                    runs += [GridRun(env_id, method, seed, (b,)) for b in budgets]
                else:
                    runs.append(GridRun(env_id, method, seed, tuple(budgets)))
    return sorted(runs, key=lambda r: (r.method == "random", -max(r.budgets) * len(r.budgets)))


def percept_table_policy(agent) -> Policy:
    """Greedy policy of Q solved on the distinct feature sets of a learned ``RLVCAgent``'s own
    database, each a state of its own (no visual classes); a percept whose feature set is not in
    the database gets the agent's action. Where the percepts of a task repeat exactly, its
    success says what the interactions allow: above the agent's, the classes lose it."""
    db = agent.database
    packed = db.presence.numpy().packed
    sets, state_of = np.unique(packed, axis=0, return_inverse=True)
    state_of = torch.from_numpy(state_of.reshape(-1))
    mdp = estimate_mdp(
        state_of[db.obs],
        db.actions,
        db.rewards,
        state_of[db.next_obs],
        db.terminal,
        len(sets),
        agent.action_space.n,
    )
    greedy = value_iteration(mdp, agent.gamma).argmax(dim=1).numpy()
    acted = (mdp.counts > 0).any(dim=1).numpy()  # sets only ever met as successors: no action
    index = {row.tobytes(): i for i, row in enumerate(sets) if acted[i]}

    def policy(frames: np.ndarray) -> np.ndarray:
        presence = agent._presence(frames)
        actions = agent._greedy(presence)
        rows = PackedPresence.from_dense(presence).numpy().packed
        known = [index.get(row.tobytes()) for row in rows]
        return np.array(
            [a if i is None else greedy[i] for a, i in zip(actions, known, strict=True)]
        )

    return policy


def run_grid(run: GridRun) -> dict:
    """Train and score one run; returns its record: success, seconds and (RLVC) classes,
    rewards seen and the success of ``percept_table_policy``, one entry per budget."""
    start = time.perf_counter()
    record = {**asdict(run), "success": [], "seconds": []}
    if run.method == "rlvc":
        from vistask.agents import RLVCAgent

        (budget,) = run.budgets
        agent = RLVCAgent(make_gridworld(run.env_id), seed=run.seed)
        agent.learn(budget)
        seconds = time.perf_counter() - start
        record["success"].append(success_rate(lambda x: agent.predict(x)[0], run.env_id))
        record |= {"seconds": [seconds], "classes": [agent.rlvc.n_classes]}
        record["rewards_seen"] = [agent.rewards_seen]
        record["percept_table"] = [success_rate(percept_table_policy(agent), run.env_id)]
    elif run.method == "ppo":
        record |= _run_ppo(run, start)
    else:
        rng = np.random.default_rng(run.seed)
        n = int(make_gridworld(run.env_id).action_space.n)
        score = success_rate(lambda x: rng.integers(n, size=len(x)), run.env_id)
        record |= {"success": [score] * len(run.budgets), "seconds": [0.0] * len(run.budgets)}
    return record


def _run_ppo(run: GridRun, start: float) -> dict:
    """SB3 PPO (CnnPolicy, ``PPO_MINIGRID``) trained once, scored when it passes each budget."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env

    success, seconds, scoring = [], [], [0.0]

    class ScoreAtBudgets(BaseCallback):
        def _on_step(self) -> bool:
            while (
                len(success) < len(run.budgets) and self.num_timesteps >= run.budgets[len(success)]
            ):
                t0 = time.perf_counter()
                seconds.append(t0 - start - scoring[0])
                policy = lambda x: self.model.predict(x, deterministic=True)[0]  # noqa: E731
                success.append(success_rate(policy, run.env_id))
                scoring[0] += time.perf_counter() - t0
            return len(success) < len(run.budgets)

    envs = make_vec_env(lambda: make_gridworld(run.env_id), n_envs=PPO_ENVS, seed=run.seed)
    model = PPO("CnnPolicy", envs, seed=run.seed, verbose=0, **PPO_MINIGRID)
    model.learn(max(run.budgets), callback=ScoreAtBudgets())
    return {"success": success, "seconds": seconds}


def bench_gridworlds(
    envs: Sequence[str] = GRIDWORLDS,
    methods: Sequence[str] = METHODS,
    seeds: Sequence[int] = range(5),
    budgets: Sequence[int] = BUDGETS,
    out: str | Path | None = None,
    workers: int | None = None,
    address: str | None = None,
    progress: bool = True,
) -> dict:
    """Run every (env, method, seed) and write ``runs.jsonl``, ``summary.json``, the table and
    ``success.png`` to ``out``; the same ``out`` again runs only what is missing.

    Args:
        envs: MiniGrid env ids (``make_gridworld``).
        methods: of ``METHODS``.
        seeds: seeds of every method.
        budgets: increasing interaction budgets.
        out: run folder (default ``runs/bench_gridworlds-<time>``).
        workers, address: where the runs go (``vistask.parallel.map_runs``).
        progress: print a line per finished run.

    Returns:
        The summary: ``summary[env][method]["success"][str(budget)]`` the IQM success over
        seeds, ``["to_reach"]`` the smallest budget whose IQM reaches ``SUCCESS`` (None:
        none), ``summary[env]["rlvc"]["percept_table"][str(budget)]`` the IQM success of
        ``percept_table_policy``, ``summary["failed"]`` the runs that raised.

    Raises:
        ValueError: an env id that is not a MiniGrid task, before any work.
        RunsFailed: runs failed; raised after the summary of the others is written (the
            same call again runs only the failed ones).
    """
    unknown = sorted(set(methods) - set(METHODS))
    if unknown:
        raise ValueError(f"unknown methods {unknown}: choose from {list(METHODS)}")
    budgets, seeds = sorted(set(budgets)), sorted(set(seeds))
    check_at_least(1, budgets=min(budgets))
    for env_id in envs:
        check_minigrid(env_id)
    out = run_dir("bench_gridworlds", out)
    check_same_settings(out / "settings.json", {"frame": FRAME, "episodes": EPISODES})
    done = {_key(r) for r in read_records(out / "runs.jsonl")}
    todo = [r for r in grid_runs(envs, methods, seeds, budgets) if _key(asdict(r)) not in done]
    if done and progress:
        print(f"{len(done)} runs that an earlier call finished in {out} are kept", flush=True)
    failed = []

    def finished(outcome: Outcome) -> None:
        run = outcome.item
        if not outcome.ok:
            failed.append({**asdict(run), "error": outcome.error})
            line = f"FAILED: {last_line(outcome.error)}"
        else:
            append_record(out / "runs.jsonl", outcome.result)
            scores = " ".join(f"{s:.2f}" for s in outcome.result["success"])
            line = f"{scores} ({outcome.result['seconds'][-1]:.0f} s)"
        if progress:
            print(
                f"{run.env_id} {run.method} seed {run.seed} {list(run.budgets)}: {line}", flush=True
            )

    map_runs(run_grid, todo, workers, address, finished)
    lines = [f"{f['env_id']} {f['method']}: {last_line(f['error'])}" for f in failed]
    if failed and not read_records(out / "runs.jsonl"):
        raise RunsFailed.of(lines, every=True)
    summary = summarise(read_records(out / "runs.jsonl"), envs, methods, seeds, budgets)
    summary["failed"] = failed
    write_summary(out, summary)
    plot_success(out / "success.png", summary, envs, methods, budgets)
    print(f"IQM greedy success over {len(seeds)} seeds, at {budgets} interactions")
    print_table(
        {
            f"{env_id} {method}": " ".join(f"{s:.2f}" for s in entry["success"].values())
            for env_id in envs
            for method, entry in summary[env_id].items()
        }
        | {
            f"{env_id} rlvc percept table": " ".join(f"{s:.2f}" for s in table.values())
            for env_id in envs
            if (table := summary[env_id].get("rlvc", {}).get("percept_table"))
        }
    )
    if failed:  # after what finished is written: the same command runs the rest again
        raise RunsFailed.of(lines)
    return summary


def _key(record: dict) -> tuple:
    return (record["env_id"], record["method"], record["seed"], tuple(record["budgets"]))


def summarise(
    records: list[dict],
    envs: Sequence[str],
    methods: Sequence[str],
    seeds: Sequence[int],
    budgets: Sequence[int],
) -> dict:
    """Per env and method: IQM success over the seeds at each budget with its 95% interval,
    the budget that reaches ``SUCCESS`` and each seed's success (only the seeds that ran, if
    the benchmark stopped); for RLVC also ``percept_table``, the IQM success of
    ``percept_table_policy`` where the records hold it."""
    summary: dict = {"budgets": list(budgets), "seeds": list(seeds), "episodes": EPISODES}
    for env_id in envs:
        summary[env_id] = {}
        for method in methods:
            mine = [r for r in records if r["env_id"] == env_id and r["method"] == method]
            entry = _iqm_entry(mine, "success", method, seeds, budgets)
            if not entry["success"]:
                continue
            table = _iqm_entry(mine, "percept_table", method, seeds, budgets)["success"]
            if table:
                entry["percept_table"] = table
            summary[env_id][method] = entry
    return summary


def _iqm_entry(
    records: list[dict], field: str, method: str, seeds: Sequence[int], budgets: Sequence[int]
) -> dict:
    """IQM over seeds of the records' ``field`` at each budget (see ``summarise``)."""
    table = np.full((len(seeds), len(budgets)), np.nan)
    for r in records:
        if r["seed"] in seeds and field in r:
            for budget, score in zip(r["budgets"], r[field], strict=True):
                if budget in budgets:
                    table[seeds.index(r["seed"]), budgets.index(budget)] = score
    entry = {"success": {}, "interval": {}, "to_reach": None, "per_seed": {}}
    for column, budget in zip(table.T, budgets, strict=True):
        done = column[~np.isnan(column)]  # a stopped benchmark: the seeds that ran
        if not len(done):
            continue
        iqm, low, high = (float(v[0]) for v in iqm_curves({method: done[:, None]})[method])
        entry["success"][str(budget)] = iqm
        entry["interval"][str(budget)] = [low, high]
        entry["per_seed"][str(budget)] = {
            str(seed): float(v) for seed, v in zip(seeds, column, strict=True) if v == v
        }
        if entry["to_reach"] is None and iqm >= SUCCESS:
            entry["to_reach"] = budget
    return entry


def plot_success(
    path: Path, summary: dict, envs: Sequence[str], methods: Sequence[str], budgets: Sequence[int]
) -> None:
    """IQM success against interactions, one panel per env, with the seeds' 95% interval."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = min(4, len(envs))
    rows = -(-len(envs) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(3.6 * columns, 2.9 * rows), squeeze=False)
    for ax, env_id in zip(axes.flat, envs, strict=False):
        for method in methods:
            entry = summary[env_id].get(method)
            if entry is None:
                continue
            x = [int(b) for b in entry["success"]]
            ax.plot(x, list(entry["success"].values()), marker="o", label=method, zorder=3)
            low, high = zip(*entry["interval"].values(), strict=True)
            ax.fill_between(x, low, high, alpha=0.2)
            if "percept_table" in entry:
                table = entry["percept_table"]
                x = [int(b) for b in table]
                # Behind the methods' lines, which it often equals.
                ax.plot(
                    x,
                    list(table.values()),
                    "k--",
                    marker=".",
                    alpha=0.5,
                    zorder=2,
                    label=f"{method} percept table",
                )
        ax.axhline(SUCCESS, color="k", linestyle=":", linewidth=0.8)
        ax.set(title=env_id.removeprefix("MiniGrid-"), xscale="log", ylim=(-0.03, 1.03))
        ax.set_xticks(budgets, [f"{b / 1000:g}k" if b >= 1000 else str(b) for b in budgets])
        ax.minorticks_off()
        ax.set_xlabel("interactions")
        ax.set_ylabel("greedy success")
    for ax in list(axes.flat)[len(envs) :]:
        ax.axis("off")
    axes.flat[0].legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
