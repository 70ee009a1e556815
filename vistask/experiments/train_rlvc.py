"""Train RLVC on an image env, score it, log it, draw it (``scripts/train_rlvc.py``).

On the visual maze the greedy policy is scored against the maze's oracle from fixed starts,
with pictures of values and policies; on any other image env it is scored by its mean
episode reward over seeded episodes.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.evaluation import evaluate_policy as sb3_evaluate_policy

import vistask.envs  # noqa: F401  (registers the environments)
from vistask.agents import RLVCAgent
from vistask.envs import ACTION_NAMES, MazeOracle, VisualMazeEnv, evaluate_policy, start_positions
from vistask.envs.maze_oracle import Policy, grid_cells
from vistask.envs.maze_plots import percept_grid, plot_policy, plot_values
from vistask.rlvc import InteractionDatabase, Transitions
from vistask.rlvc.solver import estimate_mdp, value_iteration
from vistask.runs import print_table, run_dir, write_summary

PAPER = {"stages": 84, "classes": 205, "selected_features": 200, "vocabulary_size": 2298}
EVAL_EVERY = 50  # stages between evaluations logged while learning
EVAL_STARTS = 100  # fixed maze starts (or seeded episodes on other envs) of an evaluation


def agent_policy(agent: RLVCAgent) -> Policy:
    """The agent as a batched maze ``Policy`` (it sees percepts only, never positions)."""
    return lambda percepts, positions: agent.predict(percepts)[0]


def true_grid_policy(
    maze: VisualMazeEnv, transitions: Transitions | InteractionDatabase, grid: int = 20
) -> Policy:
    """Greedy policy of value iteration on ``transitions`` with the true position cut into
    ``grid`` x ``grid`` cells: what a perfect state aggregation of the same interactions scores,
    a ceiling for the learned visual classes. It reads the privileged positions."""
    if transitions.positions is None:
        raise ValueError("the transitions hold no true positions (info['position'])")
    size = maze.geometry.size
    cells = torch.as_tensor(grid_cells(transitions.positions, size, grid))
    mdp = estimate_mdp(
        cells[torch.as_tensor(transitions.obs)],
        torch.as_tensor(transitions.actions),
        torch.as_tensor(transitions.rewards),
        cells[torch.as_tensor(transitions.next_obs)],
        torch.as_tensor(transitions.terminal),
        grid * grid,
        len(ACTION_NAMES),
    )
    greedy = value_iteration(mdp, maze.geometry.gamma).argmax(1).numpy()
    return lambda percepts, positions: greedy[grid_cells(positions, size, grid)]


class Scorer:
    """Mean return of an agent's greedy policy: from the maze's fixed starts, as a share of
    its oracle's, or (any other env) mean episode reward over seeded episodes."""

    def __init__(self, env: gym.Env, episodes: int = EVAL_STARTS) -> None:
        self.env, self.episodes = env, episodes
        self.maze = env.unwrapped if isinstance(env.unwrapped, VisualMazeEnv) else None
        self.oracle_return = None
        if self.maze is not None:
            self.starts = start_positions(self.maze.geometry, episodes)
            self.oracle = MazeOracle.solve(self.maze.geometry)
            self.oracle_return = evaluate_policy(
                self.maze, self.oracle.as_policy(), self.starts
            ).mean
        self.last_returns: np.ndarray | None = None

    def __call__(self, agent: RLVCAgent) -> float:
        if self.maze is not None:
            self.last_returns = evaluate_policy(self.maze, agent_policy(agent), self.starts).returns
        else:
            self.env.reset(seed=0)  # seeds the episodes that follow
            rewards, _ = sb3_evaluate_policy(
                agent, self.env, self.episodes, deterministic=True, return_episode_rewards=True
            )
            self.last_returns = np.asarray(rewards, dtype=float)
        return float(self.last_returns.mean())


class EvaluateEvery(BaseCallback):
    """Scores the greedy policy every ``every`` stages and logs ``eval/return`` (and
    ``eval/return_ratio`` against the oracle) to the agent's TensorBoard run."""

    def __init__(self, scorer: Scorer, every: int = EVAL_EVERY) -> None:
        super().__init__()
        self.scorer, self.every, self.seconds = scorer, every, 0.0
        self.evaluations: list[tuple[int, float]] = []  # (stage, return)

    def _on_step(self) -> bool:
        if self.n_calls % self.every == 0:
            start = time.perf_counter()
            value = self.scorer(self.model)
            self.seconds += time.perf_counter() - start
            self.evaluations.append((self.n_calls, value))
            self.logger.record("eval/return", value)
            if self.scorer.oracle_return:
                self.logger.record("eval/return_ratio", value / self.scorer.oracle_return)
        return True


def maze_pictures(agent: RLVCAgent, scorer: Scorer, out: Path) -> dict:
    """Fig. 4 (values) and Fig. 3 right (policies) over the true positions, and how often the
    greedy action is the oracle's on a 50 x 50 grid."""
    maze, oracle = scorer.maze, scorer.oracle
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
    return {"policy_agreement_with_oracle": float((actions == oracle.policy)[free].mean())}


def train_rlvc(
    env_id: str = "vistask/VisualMaze-v0",
    env_kwargs: dict | None = None,
    interactions: int = 30_000,
    seed: int = 0,
    out: str | Path | None = None,
    progress: bool = True,
    pictures: bool = True,
) -> dict:
    """Learn visual classes with ``RLVCAgent``'s defaults, score the greedy policy, save the
    agent, its TensorBoard run, pictures and ``summary.json`` in ``out``.

    Args:
        env_id, env_kwargs: the env (``gym.make`` arguments): image observations, Discrete
            actions.
        interactions: interactions in all (the agent's ``databases`` share them).
        seed: seeds the agent.
        out: run directory (default ``runs/train_rlvc-<time>``).
        progress: show progress bars.
        pictures: draw values and policies (maze only).

    Returns:
        The summary written to ``summary.json``.
    """
    start = time.perf_counter()
    out = run_dir("train_rlvc", out)
    env = gym.make(env_id, **(env_kwargs or {}))
    scorer = Scorer(gym.make(env_id, **(env_kwargs or {})))
    agent = RLVCAgent(env, seed=seed, tensorboard_log=out / "tensorboard")
    evaluations = EvaluateEvery(scorer)
    agent.learn(interactions, callback=evaluations, progress_bar=progress)
    learned = time.perf_counter()
    final_return = scorer(agent)
    agent.save(out / "rlvc_agent.pt")

    rlvc = agent.rlvc
    summary = {
        "env_id": env_id,
        "env_kwargs": env_kwargs or {},
        "rlvc_return": final_return,
        "stages": len(rlvc.history),
        "classes": rlvc.n_classes,
        "selected_features": len(rlvc.tree.selected_features),
        "vocabulary_size": agent.extractor.n_features,
        "interactions": agent.num_timesteps,
        "evaluations": evaluations.evaluations,
    }
    if scorer.maze is not None:
        ceiling = true_grid_policy(scorer.maze, agent.database)  # the agent's own interactions
        grid_return = evaluate_policy(scorer.maze, ceiling, scorer.starts).mean
        summary |= {
            "return_ratio": final_return / scorer.oracle_return,
            "oracle_return": scorer.oracle_return,
            "true_grid_return_ratio": grid_return / scorer.oracle_return,
            "starts_never_exiting": int((scorer.last_returns == 0).sum()),
            "paper": PAPER,
        }
        if pictures:
            summary |= maze_pictures(agent, scorer, out)
    summary |= {
        "seconds": time.perf_counter() - start,
        "learn_seconds": learned - start,
        "seconds_split": {
            "collect": agent.timing["collect"],
            "feature_extraction": agent.timing["extract"],
            "vocabulary": agent.timing["vocabulary"],
            "q_solving": rlvc.timing.solve,
            "split_search": rlvc.timing.split,
            "evaluation": evaluations.seconds,
        },
        "history": [asdict(r) for r in rlvc.history],
        "seed": seed,
    }
    write_summary(out, summary)
    print_summary(summary, out)
    return summary


def print_summary(summary: dict, out: Path) -> None:
    rows = {"RLVC mean return": summary["rlvc_return"]}
    if "return_ratio" in summary:
        rows |= {
            "return ratio (RLVC / oracle)": summary["return_ratio"],
            "oracle mean discounted return": summary["oracle_return"],
            "same interactions on a true 20x20 grid / oracle": summary["true_grid_return_ratio"],
            "starts never reaching an exit": summary["starts_never_exiting"],
        }
    rows |= {
        "stages (paper 84)": summary["stages"],
        "visual classes (paper 205)": summary["classes"],
        "selected features (paper 200)": summary["selected_features"],
        "vocabulary size (paper 2298)": summary["vocabulary_size"],
        "interactions": summary["interactions"],
        **{f"seconds: {k}": v for k, v in summary["seconds_split"].items()},
        "seconds: whole run": summary["seconds"],
    }
    print_table(rows, title=f"RLVC on {summary['env_id']} -> {out}")
