"""Train RLJC on an image env with continuous actions, score it, log it, draw it
(``scripts/train_rlvc.py`` picks it for a ``Box`` action space).

On the continuous-direction maze the greedy policy is scored against the oracle that moves in
32 directions, beside four-action RLVC trained with the same seed and interactions on the
discrete maze (same starts, same noise: one scale); on any other env by mean episode reward.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import vistask.envs  # noqa: F401  (registers the environments)
from vistask.agents import RLJCAgent, RLVCAgent
from vistask.envs.maze_plots import percept_grid, plot_directions
from vistask.experiments.hyperparams import hyperparams_for
from vistask.experiments.tasks import MazeTask
from vistask.experiments.train_rlvc import (
    EvaluateEvery,
    Scorer,
    agent_policy,
    check_unfinished,
    end_resumable,
    evaluations_of,
    learn_resumable,
)
from vistask.runs import check_same_settings, print_table, run_dir

DISCRETE_MAZE = "vistask/VisualMaze-v0"  # the four-action twin of the continuous maze


def direction_pictures(agent: RLJCAgent, task: MazeTask, out: Path, grid: int = 25) -> dict:
    """Fig. 3 right with arrows at any angle: RLJC's greedy directions over the true positions
    beside the oracle's; and Fig. 10 right: the joint classes over a slice of percepts."""
    maze, oracle = task.env, task.oracle
    angles = percept_grid(maze, lambda images: agent.predict(np.stack(images))[0][:, 0], grid)
    plot_directions(maze, angles, out / "rljc_policy.png", title="RLJC greedy directions")
    step = max(1, oracle.grid // grid)
    plot_directions(
        maze, oracle.policy_angles[::step, ::step], out / "oracle_policy.png", "Oracle policy"
    )
    joint_space_slice(agent, task, out / "joint_space.png")
    # How far the greedy direction is from the oracle's, over the free cells of the grid.
    free = np.isfinite(angles)
    best = oracle.policy_angles[::step, ::step][free]
    gap = np.abs(np.angle(np.exp(1j * (angles[free] - best))))
    return {"median_angle_error_degrees": float(np.degrees(np.median(gap)))}


def joint_space_slice(agent: RLJCAgent, task: MazeTask, path: Path, y: float = 0.5) -> None:
    """Q of the joint class of every (percept, angle) along the horizontal line ``y`` of the
    maze (x across, the angle up), with RLJC's greedy angle and the oracle's (Fig. 10 right)."""
    maze, rljc = task.env, agent.rljc
    size = maze.geometry.size
    xs = (np.arange(100) + 0.5) / 100 * size
    points = np.stack([xs, np.full_like(xs, y * size)], 1)
    free = maze.geometry.is_free(points)
    angles = np.linspace(-np.pi, np.pi, 129)[:-1] + np.pi / 128
    presence = agent.extractor.presence([maze.percept_at(p) for p in points[free]])
    percepts = np.repeat(np.arange(int(free.sum())), len(angles))
    joint = rljc.structure.classify(presence, np.tile(angles, free.sum())[:, None], percepts)
    q = np.full((len(angles), len(xs)), np.nan)
    values = rljc.q.numpy()[joint.numpy()].reshape(-1, len(angles)).T
    q[:, free] = np.where(np.isfinite(values), values, np.nan)
    fig, ax = plt.subplots(figsize=(7, 4))
    shown = ax.imshow(
        q,
        origin="lower",
        aspect="auto",
        extent=(0, size, -np.pi, np.pi),
        interpolation="nearest",
        cmap="viridis",
    )
    fig.colorbar(shown, ax=ax, label="Q of the joint class")
    ax.plot(xs[free], rljc.greedy(presence)[:, 0], "w.", ms=4, label="RLJC greedy angle")
    ax.plot(xs[free], task.oracle.angle(points[free]), "rx", ms=3, label="oracle's angle")
    ax.set_xlabel(f"x of the percept (y = {y * size:.2f})")
    ax.set_ylabel("move angle (rad): -π/2 up, 0 right, π/2 down")
    ax.set_title(f"Joint classes over a slice of percepts ({rljc.n_classes} joint classes)")
    ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def train_rljc(
    env_id: str = "vistask/VisualMazeContinuous-v0",
    env_kwargs: dict | None = None,
    interactions: int = 60_000,
    seed: int = 0,
    out: str | Path | None = None,
    progress: bool = True,
    pictures: bool = True,
    hyperparams: dict | None = None,
) -> dict:
    """Learn joint classes with ``RLJCAgent``'s defaults, score the greedy policy, save the
    agent, its TensorBoard run, pictures and ``summary.json`` in ``out``. On the continuous
    maze, four-action RLVC learns with the same seed and interactions for comparison.

    Args:
        env_id, env_kwargs: the env (``gym.make`` arguments): image observations, a bounded
            ``Box`` action space.
        interactions: interactions in all (the agent's ``databases`` share them).
        seed: seeds the agents.
        out: run directory (default ``runs/train_rljc-<time>``); one that a stopped run
            left goes on from its checkpoint, with the same settings.
        progress: show progress bars.
        pictures: draw the directions and the joint classes (the maze).
        hyperparams: ``RLJCAgent`` arguments, e.g. ``{"n_words": 4096}`` (``hyperparams_for``).

    Returns:
        The summary written to ``summary.json``.
    """
    hyperparams = hyperparams_for(env_id, hyperparams, RLJCAgent)
    start = time.perf_counter()
    out = run_dir("train_rljc", out)
    settings = {
        "env_id": env_id,
        "env_kwargs": env_kwargs or {},
        "interactions": interactions,
        "seed": seed,
    }
    if hyperparams:  # absent, not empty, in runs of the defaults: those resume as before
        settings["hyperparams"] = hyperparams
    check_same_settings(out / "settings.json", settings)
    check_unfinished(out)
    env = gym.make(env_id, **(env_kwargs or {}))
    scorer = Scorer(env_id, env_kwargs)
    agent = RLJCAgent(env, **hyperparams, seed=seed, tensorboard_log=out / "tensorboard")
    evaluations = EvaluateEvery(scorer)
    agent, before = learn_resumable(agent, interactions, out, evaluations, progress)
    learned = time.perf_counter()
    final_return = evaluations.final
    agent.save(out / "rljc_agent.pt")

    rljc, tree = agent.rljc, agent.rljc.structure
    cells = tree.cells(agent.database.presence)[0]
    summary = {
        "env_id": env_id,
        "env_kwargs": env_kwargs or {},
        "rljc_return": final_return,
        "stages": len(rljc.history),
        "joint_classes": rljc.n_classes,
        "perceptual_cells": int(cells.max()) + 1,
        "action_tests": tree.action_tests,
        "selected_features": len(tree.selected_features),
        "vocabulary_size": agent.extractor.n_features,
        "interactions": agent.num_timesteps,
        "rewards_seen": agent.rewards_seen,
        "evaluations": evaluations_of(evaluations),
    }
    task = scorer.task
    if task.oracle_return is not None:
        summary |= {
            "return_ratio": final_return / task.oracle_return,
            "oracle_return": task.oracle_return,
        }
    if isinstance(task, MazeTask):
        summary |= {"starts_never_exiting": int((scorer.last_returns == 0).sum())}
        if pictures:
            summary |= direction_pictures(agent, task, out)
    rljc_done = time.perf_counter()
    if isinstance(task, MazeTask):
        summary |= discrete_comparison(env_kwargs, interactions, seed, progress)
    summary |= {
        "seconds": before + time.perf_counter() - start,
        "rljc_seconds": before + rljc_done - start,
        "learn_seconds": before + learned - start,
        "seconds_split": {
            "collect": agent.timing["collect"],
            "feature_extraction": agent.timing["extract"],
            "vocabulary": agent.timing["vocabulary"],
            "q_solving": rljc.timing.solve,
            "split_search": rljc.timing.split,
            "evaluation": evaluations.seconds,
        },
        "history": [asdict(r) for r in rljc.history],
        "seed": seed,
    }
    end_resumable(out, summary)
    print_summary(summary, out)
    return summary


def discrete_comparison(
    env_kwargs: dict | None, interactions: int, seed: int, progress: bool
) -> dict:
    """Four-action RLVC on the discrete twin of the maze, same seed and interactions, scored
    from the same starts with the same noise (the continuous maze's scale)."""
    start = time.perf_counter()
    env = gym.make(DISCRETE_MAZE, **(env_kwargs or {}))
    agent = RLVCAgent(env, seed=seed).learn(interactions, progress_bar=progress)
    task = MazeTask(env.unwrapped)
    return {
        "rlvc_discrete_return": task.evaluate(agent_policy(agent)).mean,
        "rlvc_classes": agent.rlvc.n_classes,
        "rlvc_classes_x4": 4 * agent.rlvc.n_classes,
        "rlvc_discrete_oracle_return": task.oracle_return,
        "rlvc_seconds": time.perf_counter() - start,
    }


def print_summary(summary: dict, out: Path) -> None:
    """Print the summary as a table, with the folder it was written to."""
    rows = {"RLJC mean return": summary["rljc_return"]}
    for key, name in (
        ("return_ratio", "return ratio (RLJC / oracle)"),
        ("oracle_return", "oracle mean return (32 directions)"),
        ("rlvc_discrete_return", "four-action RLVC mean return, same starts"),
        ("rlvc_discrete_oracle_return", "four-action oracle mean return"),
        ("starts_never_exiting", "starts never reaching an exit"),
        ("median_angle_error_degrees", "median angle from the oracle's (degrees)"),
    ):
        if key in summary:
            rows[name] = summary[key]
    rows |= {
        "stages": summary["stages"],
        "joint classes": summary["joint_classes"],
    }
    if "rlvc_classes_x4" in summary:
        rows["RLVC classes x 4"] = summary["rlvc_classes_x4"]
    rows |= {
        "perceptual cells (database percepts)": summary["perceptual_cells"],
        "action tests": summary["action_tests"],
        "selected features": summary["selected_features"],
        "interactions": summary["interactions"],
        **{f"seconds: {k}": v for k, v in summary["seconds_split"].items()},
        "seconds: RLJC run": summary["rljc_seconds"],
        "seconds: whole run": summary["seconds"],
    }
    print_table(rows, title=f"RLJC on {summary['env_id']} -> {out}")
