"""Train RLVC on the visual maze and score it against the oracle (``scripts/train_rlvc.py``)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from vistask.agents import RLVCAgent
from vistask.envs import (
    ACTION_NAMES,
    MazeGeometry,
    MazeOracle,
    VisualMazeEnv,
    evaluate_policy,
    start_positions,
)
from vistask.envs.maze_oracle import Policy, grid_cells
from vistask.envs.maze_plots import percept_grid, plot_policy, plot_values
from vistask.features import SiftExtractor
from vistask.runs import print_table, run_dir, tensorboard, write_summary
from vistask.rlvc import InteractionDatabase, Transitions
from vistask.rlvc.solver import estimate_mdp, value_iteration

PAPER = {"stages": 84, "classes": 205, "selected_features": 200, "vocabulary_size": 2298}


def agent_policy(agent: RLVCAgent):
    """The agent as a batched maze ``Policy`` (it sees percepts only, never positions)."""
    return lambda percepts, positions: agent.predict(percepts)[0]


def true_grid_policy(
    geometry: MazeGeometry, transitions: Transitions | InteractionDatabase, grid: int = 20
) -> Policy:
    """Greedy policy of value iteration on ``transitions`` with the true position cut into
    ``grid`` x ``grid`` cells: what a perfect state aggregation of the same interactions scores,
    a ceiling for the learned visual classes. It reads the privileged positions."""
    if transitions.positions is None:
        raise ValueError("the transitions hold no true positions (info['position'])")
    cells = torch.as_tensor(grid_cells(transitions.positions, geometry.size, grid))
    mdp = estimate_mdp(
        cells[torch.as_tensor(transitions.obs)],
        torch.as_tensor(transitions.actions),
        torch.as_tensor(transitions.rewards),
        cells[torch.as_tensor(transitions.next_obs)],
        torch.as_tensor(transitions.terminal),
        grid * grid,
        len(ACTION_NAMES),
    )
    greedy = value_iteration(mdp, geometry.gamma).argmax(1).numpy()
    return lambda percepts, positions: greedy[grid_cells(positions, geometry.size, grid)]


def train_rlvc(
    env_id: str = "vistask/VisualMaze-v0",
    env_kwargs: dict | None = None,
    interactions: int = 30_000,
    n_words: int = 8192,
    vocabulary_groups: int = 64,
    alpha: float = 0.05,
    min_count: int = 10,
    max_stages: int = 300,
    databases: int | Sequence[float] = 3,
    blocked_is_stuck: bool = False,
    max_keypoints: int = 24,
    n_envs: int = 128,
    eval_starts: int = 100,
    eval_every: int = 50,
    seed: int = 0,
    out: str | Path | None = None,
    progress: bool = True,
) -> dict:
    """Learn visual classes on a maze, log every stage, write pictures and ``summary.json``.

    Args:
        env_id, env_kwargs: the maze (``gym.make`` arguments).
        interactions: interactions in all (the budget); the default is the paper's protocol,
            three databases of 10,000.
        n_words, vocabulary_groups, alpha, min_count, max_stages, databases,
            blocked_is_stuck: RLVC settings (see ``RLVCAgent``).
        max_keypoints: SIFT keypoints kept per percept, strongest first (0: all); fewer
            make extraction faster.
        n_envs: episodes collected side by side on the classes (see ``RLVCAgent``).
        eval_starts: number of fixed start positions of the evaluation.
        eval_every: evaluate the greedy policy every this many stages (and at the end).
        seed: seeds collection and the vocabulary.
        out: run directory (default ``runs/train_rlvc-<time>``).
        progress: show progress bars.

    Returns:
        The summary written to ``summary.json``.
    """
    start = time.perf_counter()
    out = run_dir("train_rlvc", out)
    env = gym.make(env_id, **(env_kwargs or {}))
    maze = env.unwrapped
    if not isinstance(maze, VisualMazeEnv):
        raise TypeError(f"train_rlvc scores policies with the maze oracle; {env_id} is no maze")
    starts = start_positions(maze.geometry, eval_starts)
    oracle = MazeOracle.solve(maze.geometry)
    oracle_return = evaluate_policy(maze, oracle.as_policy(), starts).mean

    agent = RLVCAgent(
        env,
        n_words=n_words,
        vocabulary_groups=vocabulary_groups,
        alpha=alpha,
        min_count=min_count,
        max_stages=max_stages,
        databases=databases,
        blocked_is_stuck=blocked_is_stuck,
        keypoints=SiftExtractor(max_keypoints=max_keypoints),
        n_envs=n_envs,
        seed=seed,
    )
    writer = tensorboard(out / "tensorboard")

    def log_stage(record) -> None:
        for key in ("classes", "selected_features", "mean_abs_td", "splits"):
            writer.add_scalar(f"rlvc/{key}", getattr(record, key), record.stage)
        if record.greedy_return is not None:
            writer.add_scalar("rlvc/greedy_return", record.greedy_return, record.stage)
            writer.add_scalar(
                "rlvc/return_ratio", record.greedy_return / oracle_return, record.stage
            )

    evaluations = []

    def evaluate(a: RLVCAgent) -> float:
        evaluations.append(evaluate_policy(maze, agent_policy(a), starts))
        return evaluations[-1].mean

    agent.learn(
        interactions,
        evaluate=evaluate,
        eval_every=eval_every,
        progress_bar=progress,
        on_stage=log_stage,
    )
    learned = time.perf_counter()
    rlvc_return = evaluations[-1].mean
    # The agent's own interactions, aggregated on true positions instead of visual classes.
    ceiling = true_grid_policy(maze.geometry, agent.database)
    grid_return = evaluate_policy(maze, ceiling, starts).mean
    writer.close()

    agent.save(out / "rlvc_agent.pt")
    classes = percept_grid(maze, lambda images: agent.classifier.classify(images).numpy(), 50)
    free = ~np.isnan(classes)
    index = np.nan_to_num(classes).astype(int)
    values = np.where(free, agent.rlvc.values().numpy()[index], np.nan)
    plot_values(
        maze,
        {"oracle (true position)": oracle.values, "RLVC (percepts)": values},
        out / "value_functions.png",
        title="Fig. 4: optimal vs RLVC value function",
    )
    actions = np.where(free, agent.rlvc.q.argmax(1).numpy()[index], 0)
    plot_policy(maze, actions[::2, ::2], out / "rlvc_policy.png", title="RLVC greedy policy")
    plot_policy(maze, oracle.policy[::2, ::2], out / "oracle_policy.png", title="Oracle policy")

    rlvc = agent.rlvc
    summary = {
        "env_id": env_id,
        "env_kwargs": env_kwargs or {},
        "return_ratio": rlvc_return / oracle_return,
        "rlvc_return": rlvc_return,
        "oracle_return": oracle_return,
        "true_grid_return_ratio": grid_return / oracle_return,
        "starts_never_exiting": int((evaluations[-1].returns == 0).sum()),
        "stages": len(rlvc.history),
        "classes": rlvc.n_classes,
        "selected_features": len(rlvc.tree.selected_features),
        "vocabulary_size": agent.extractor.n_features,
        "vocabulary_groups": vocabulary_groups,
        "interactions": agent.num_timesteps,
        "databases": list(agent.databases),
        "blocked_is_stuck": blocked_is_stuck,
        "max_keypoints": max_keypoints,
        "n_envs": n_envs,
        "seconds": time.perf_counter() - start,
        "learn_seconds": learned - start,
        "seconds_split": {
            "collect": agent.timing["collect"],
            "feature_extraction": agent.timing["extract"],
            "vocabulary": agent.timing["vocabulary"],
            "q_solving": rlvc.timing.solve,
            "split_search": rlvc.timing.split,
            "evaluation": rlvc.timing.evaluate,
        },
        "policy_agreement_with_oracle": float((actions == oracle.policy)[free].mean()),
        "paper": PAPER,
        "history": [asdict(r) for r in rlvc.history],
        "seed": seed,
    }
    write_summary(out, summary)
    print_table(
        {
            "return ratio (RLVC / oracle)": summary["return_ratio"],
            "RLVC mean discounted return": rlvc_return,
            "oracle mean discounted return": oracle_return,
            "same interactions on a true 20x20 grid / oracle": summary["true_grid_return_ratio"],
            f"starts never reaching an exit (of {len(starts)})": summary["starts_never_exiting"],
            "stages (paper 84)": summary["stages"],
            "visual classes (paper 205)": summary["classes"],
            "selected features (paper 200)": summary["selected_features"],
            "vocabulary size (paper 2298)": summary["vocabulary_size"],
            "interactions": summary["interactions"],
            **{f"seconds: {k}": v for k, v in summary["seconds_split"].items()},
            "seconds: whole run": summary["seconds"],
        },
        title=f"RLVC on {env_id} -> {out}",
    )
    return summary
