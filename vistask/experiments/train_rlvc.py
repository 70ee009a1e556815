"""Train RLVC on an image env, score it, log it, draw it (``scripts/train_rlvc.py``).

On the visual maze and the visual mountain car the greedy policy is scored against the env's
oracle from fixed starts, with pictures; on any other image env it is scored by its mean
episode reward over seeded episodes.
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
import torch
from scipy.spatial import cKDTree
from stable_baselines3.common.callbacks import BaseCallback

import vistask.envs  # noqa: F401  (registers the environments)
from vistask.agents import RLVCAgent
from vistask.agents.visual_agent import VisualAgent
from vistask.checks import check_at_least
from vistask.envs.car_plots import percepts_at, plot_car_policy, plot_road, state_grid
from vistask.envs.maze_oracle import Policy
from vistask.envs.maze_plots import percept_grid, plot_policy, plot_values
from vistask.experiments.hyperparams import agent_kwargs, hyperparams_for
from vistask.experiments.tasks import CarTask, EpisodeTask, MazeTask, Task, task_for
from vistask.features import draw_compound
from vistask.rlvc import InteractionDatabase, Transitions
from vistask.rlvc.solver import estimate_mdp, value_iteration
from vistask.runs import (
    append_record,
    check_same_settings,
    print_table,
    read_json,
    read_records,
    run_dir,
    write_json,
    write_summary,
)

PAPER = {"stages": 84, "classes": 205, "selected_features": 200, "vocabulary_size": 2298}
EVAL_EVERY = 50  # stages between evaluations logged while learning
EVAL_STARTS = 100  # fixed maze starts (or seeded episodes on other envs) of an evaluation


def agent_policy(agent: VisualAgent) -> Policy:
    """The agent as a batched ``Policy`` (it sees percepts only, never the true state)."""
    return lambda percepts, states: agent.predict(percepts)[0]


def true_grid_policy(
    task: Task, transitions: Transitions | InteractionDatabase, grid: int = 20
) -> Policy:
    """Greedy policy of value iteration on ``transitions`` with the true state cut into
    ``grid`` cells per dimension: what a perfect state aggregation of the same interactions
    scores, a ceiling for the learned visual classes. It reads the privileged true states."""
    if transitions.positions is None:
        raise ValueError("the transitions hold no true states (info['position'])")
    cells = torch.as_tensor(task.cells(transitions.positions, grid))
    mdp = estimate_mdp(
        cells[torch.as_tensor(transitions.obs)],
        torch.as_tensor(transitions.actions),
        torch.as_tensor(transitions.rewards),
        cells[torch.as_tensor(transitions.next_obs)],
        torch.as_tensor(transitions.terminal),
        grid * grid,
        int(task.env.action_space.n),
    )
    greedy = value_iteration(mdp, task.env.gamma).argmax(1).numpy()
    return lambda percepts, states: greedy[task.cells(states, grid)]


def seen_percepts_policy(
    task: MazeTask | CarTask, database: InteractionDatabase, greedy: np.ndarray
) -> Policy:
    """At each state, the action that the agent takes on the database's percept nearest to it
    in true state (``greedy`` (M,): the agent's action on each of the database's percepts).

    This is how the learned classes score on the very percepts they were learned from; the
    agent itself meets new percepts. Below ``true_grid_policy``'s figure, the classes are
    short of the state's resolution; below this one, the agent classifies new percepts worse
    than seen ones. It reads the privileged true states.
    """
    if database.positions is None:
        raise ValueError("the database holds no true states (info['position'])")
    if len(greedy) != len(database.positions):
        raise ValueError(
            f"need one action per percept of the database ({len(database.positions)}), "
            f"got {len(greedy)}"
        )
    tree = cKDTree(task.unit(database.positions))
    return lambda percepts, states: greedy[tree.query(task.unit(states))[1]]


class Scorer:
    """Mean return of an agent's greedy policy: from an oracle task's fixed starts (the maze,
    the car; ``oracle_return`` is then the oracle's), or on any other env, mean episode reward
    over seeded episodes."""

    def __init__(self, env_id: str, env_kwargs: dict | None = None, episodes: int = EVAL_STARTS):
        self.task = task_for(env_id, env_kwargs, episodes) or EpisodeTask(
            env_id, env_kwargs, episodes
        )
        self.oracle_return = self.task.oracle_return
        self.last_returns: np.ndarray | None = None

    def __call__(self, agent: VisualAgent) -> float:
        """Mean return of ``agent``'s greedy policy (see the class)."""
        self.last_returns = self.task.evaluate(agent_policy(agent)).returns
        return float(self.last_returns.mean())


class EvaluateEvery(BaseCallback):
    """Scores the greedy policy every ``every`` stages (counted over the whole run, a resumed
    one included) and once more when learning ends (``final``), and logs ``eval/return`` (and
    ``eval/return_ratio`` against the oracle) to the agent's TensorBoard run.

    Args:
        scorer: scores an agent's greedy policy.
        every: stages between two evaluations.
        record: a JSON-lines file that every evaluation is appended to, so that a run resumed
            after a stop keeps the evaluations made before it (``evaluations_of``).
    """

    def __init__(self, scorer: Scorer, every: int = EVAL_EVERY, record: Path | None = None) -> None:
        super().__init__()
        self.scorer, self.every, self.record, self.seconds = scorer, every, record, 0.0
        self.evaluations: list[tuple[int, float]] = []  # (stage, return)

    def _on_step(self) -> bool:
        stage = len(self.model.learner.history)
        if stage % self.every == 0:
            self._evaluate(stage)
        return True

    def _on_training_end(self) -> None:
        # The learned agent, after the classes' last change (compaction's regrowing, the
        # structures' committee): a run of fewer stages than ``every`` is scored too.
        self._evaluate(len(self.model.learner.history))
        self.logger.dump()  # at the last stage, as every point of the agent's run

    @property
    def final(self) -> float:
        """The score of the agent as learning left it."""
        return self.evaluations[-1][1]

    def _evaluate(self, stage: int) -> None:
        start = time.perf_counter()
        value = self.scorer(self.model)
        self.seconds += time.perf_counter() - start
        self.evaluations.append((stage, value))
        if self.record is not None:
            append_record(self.record, {"stage": stage, "return": value})
        self.logger.record("eval/return", value)
        if self.scorer.oracle_return:
            self.logger.record("eval/return_ratio", value / self.scorer.oracle_return)


def classes_and_actions(agent: RLVCAgent, images: list[np.ndarray]) -> np.ndarray:
    """(N, 2) the visual class and the greedy action of each image (after ``RLVC.fuse`` the
    action is the structures', not the class's)."""
    rlvc = agent.rlvc
    presence = agent.extractor.presence(images, rlvc.compounds)
    return np.stack([rlvc.classify(presence).numpy(), rlvc.greedy(presence).numpy()], 1)


def maze_pictures(agent: RLVCAgent, task: MazeTask, out: Path) -> dict:
    """Fig. 4 (values) and Fig. 3 right (policies) over the true positions, and how often the
    greedy action is the oracle's on a 50 x 50 grid."""
    maze, oracle = task.env, task.oracle
    found = percept_grid(maze, lambda images: classes_and_actions(agent, images), 50)
    free = ~np.isnan(found[..., 0])
    index = np.nan_to_num(found[..., 0]).astype(int)
    values = np.where(free, agent.rlvc.values().numpy()[index], np.nan)
    plot_values(
        maze,
        {"oracle (true position)": oracle.values, "RLVC (percepts)": values},
        out / "value_functions.png",
        title="Fig. 4: optimal vs RLVC value function",
    )
    actions = np.nan_to_num(found[..., 1]).astype(int)  # 0 where not free
    plot_policy(maze, actions[::2, ::2], out / "rlvc_policy.png", title="RLVC greedy policy")
    plot_policy(maze, oracle.policy[::2, ::2], out / "oracle_policy.png", title="Oracle policy")
    return {"policy_agreement_with_oracle": float((actions == oracle.policy)[free].mean())}


def car_pictures(agent: RLVCAgent, task: CarTask, out: Path, grid: int = 50) -> dict:
    """Fig. 6 top (the road, the percept's window and gauge), Fig. 6 bottom (a compound the
    classes test, drawn on a percept that shows it), Fig. 7 (RLVC's classes and greedy actions
    over the true (p, s) plane beside the oracle's policy), and how often the greedy action is
    the oracle's on a ``grid`` x ``grid`` plane."""
    car, rlvc = task.env, agent.rlvc
    plot_road(car, np.array([-0.5, 1.0]), out / "road_and_gauge.png")
    states = state_grid(grid)
    percepts = list(percepts_at(car, states))
    classes, actions = classes_and_actions(agent, percepts).T
    oracle = task.oracle.act(states)
    plot_car_policy(
        {
            "RLVC (percepts)": actions.reshape(grid, grid),
            "oracle (true state)": oracle.reshape(grid, grid),
        },
        out / "car_policy.png",
        title="Fig. 7: greedy actions over (position, speed)",
    )
    plot_classes(classes.reshape(grid, grid), out / "car_classes.png")
    summary = {"policy_agreement_with_oracle": float((actions == oracle).mean())}
    tested = rlvc.compound_features
    if tested:
        compound = rlvc.compounds[tested[0] - rlvc.n_words]
        occurrences = agent.extractor.occurrences(percepts, rlvc.compounds)
        shown = np.flatnonzero(occurrences.presence(rlvc.n_features)[:, tested[0]].numpy())
        if len(shown):
            k = int(shown[len(shown) // 2])
            one = occurrences.select(np.array([k]))
            picture = draw_compound(percepts[k], one, compound)
            plt.imsave(out / "compound.png", picture)
            summary["drawn_compound"] = {"feature": tested[0], "state": states[k].tolist()}
    return summary


def plot_classes(classes: np.ndarray, path: Path) -> None:
    """Visual classes over the (p, s) plane, one colour per class (Fig. 7)."""
    fig, ax = plt.subplots(figsize=(4.5, 3.6))
    colours = np.random.default_rng(0).permutation(int(classes.max()) + 1)
    ax.imshow(
        colours[classes],
        cmap="tab20",
        origin="lower",
        extent=(-1, 1, -3, 3),
        aspect="auto",
        interpolation="nearest",
    )
    ax.set_title(f"RLVC's visual classes ({len(np.unique(classes))} on this plane)")
    ax.set_xlabel("position p")
    ax.set_ylabel("speed s")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def feature_r2(presence: torch.Tensor, values: np.ndarray) -> torch.Tensor:
    """(F,) share of the variance of ``values`` (M,) that each feature's presence explains
    (presence (M, F) bool): between-group over total sum of squares, 0 to 1."""
    v = torch.as_tensor(values, dtype=torch.float64)
    percept, feature = presence.nonzero(as_tuple=True)
    n_features, total = presence.shape[1], float(((v - v.mean()) ** 2).sum())
    n_f = torch.bincount(feature, minlength=n_features).double()
    s_f = torch.zeros(n_features, dtype=torch.float64).index_add_(0, feature, v[percept])
    n_nf, s_nf = len(v) - n_f, float(v.sum()) - s_f
    mean = float(v.mean())
    between = s_f**2 / n_f.clamp_min(1) + s_nf**2 / n_nf.clamp_min(1) - len(v) * mean**2
    return (between / total).clamp(0, 1)


def velocity_readability(agent: RLVCAgent) -> dict:
    """How well one feature reads the car's velocity over the agent's percepts: the largest
    share of the velocity's variance explained by the presence of a single word, and of a
    single learned compound (a word alone should read it poorly: the gauge shows velocity
    in the relation between the needle's tip and the numerals)."""
    db = agent.database
    r2 = feature_r2(db.presence, db.positions[:, 1])
    words = agent.extractor.n_features
    best_compound = float(r2[words:].max()) if len(r2) > words else None
    return {
        "velocity_r2_best_word": float(r2[:words].max()),
        "velocity_r2_best_compound": best_compound,
    }


class RunClock(BaseCallback):
    """Writes the seconds a run has taken so far, its stopped parts included, to ``path``
    (JSON) as each database starts: when a checkpoint was written just before."""

    def __init__(self, path: Path, before: float) -> None:
        super().__init__()
        self.path, self.before, self.start = path, before, time.perf_counter()

    @property
    def seconds(self) -> float:
        """Seconds of the whole run so far."""
        return self.before + time.perf_counter() - self.start

    def _on_rollout_start(self) -> None:
        write_json(self.path, {"seconds": self.seconds})

    def _on_step(self) -> bool:
        return True


def check_unfinished(out: Path) -> None:
    """Refuse a run folder that holds a finished run: learning again would overwrite it."""
    if (out / "summary.json").exists():
        raise ValueError(
            f"out: {out} holds a finished run (summary.json and its agent): pick another "
            "output folder"
        )


def learn_resumable(
    agent: VisualAgent, interactions: int, out: Path, evaluations: EvaluateEvery, progress: bool
) -> tuple[VisualAgent, float]:
    """``agent.learn(interactions)`` with a checkpoint in ``out/checkpoint.pt`` after each
    database; when a stopped run left one there, go on from it instead (the same result as a
    run straight through, ``evaluations`` of the stopped part included). The checkpoint stays
    until the run's summary is written (``end_resumable``): a stop while the learned agent is
    scored goes on from the last database, not from the start.

    Returns:
        The agent, and the seconds that the run's stopped parts took before this call.
    """
    checkpoint, clock_file = out / "checkpoint.pt", out / "elapsed.json"
    evaluations.record = out / "evaluations.jsonl"
    if checkpoint.exists():
        agent = type(agent).load(checkpoint, agent.env, tensorboard_log=agent.tensorboard_log)
        interactions, reset = interactions - agent.num_timesteps, False
        before = read_json(clock_file)["seconds"] if clock_file.exists() else 0.0
    else:
        reset, before = True, 0.0
        evaluations.record.unlink(missing_ok=True)  # a run stopped before its first checkpoint
    clock = RunClock(clock_file, before)
    callbacks = [evaluations, clock]
    agent.learn(interactions, callbacks, None, reset, progress, checkpoint=checkpoint)
    return agent, before


def end_resumable(out: Path, summary: dict) -> None:
    """Write the run's ``summary`` to ``out``, then remove what a stop would have resumed
    from (``learn_resumable``'s checkpoint and clock)."""
    write_summary(out, summary)
    (out / "checkpoint.pt").unlink(missing_ok=True)
    (out / "elapsed.json").unlink(missing_ok=True)


def evaluations_of(evaluations: EvaluateEvery) -> list[tuple[int, float]]:
    """(stage, return) of every evaluation of the run, a stopped part's included, by stage
    (a stage evaluated again after a stop counts once)."""
    if evaluations.record is None:
        return evaluations.evaluations
    return sorted({r["stage"]: r["return"] for r in read_records(evaluations.record)}.items())


def train_rlvc(
    env_id: str = "vistask/VisualMaze-v0",
    env_kwargs: dict | None = None,
    interactions: int = 40_000,
    seed: int = 0,
    out: str | Path | None = None,
    progress: bool = True,
    pictures: bool = True,
    hyperparams: dict | None = None,
    eval_starts: int = EVAL_STARTS,
) -> dict:
    """Learn visual classes with ``RLVCAgent``'s settings for ``env_id`` (its entry in
    ``hyperparams/rlvc.yml``, else the defaults), score the greedy policy, save the agent, its
    TensorBoard run, pictures and ``summary.json`` in ``out``.

    Args:
        env_id, env_kwargs: the env (``gym.make`` arguments): image observations, Discrete
            actions.
        interactions: interactions in all (the agent's ``databases`` share them).
        seed: seeds the agent.
        out: run directory (default ``runs/train_rlvc-<time>``); one that a stopped run
            left goes on from its checkpoint (``learn_resumable``), with the same settings.
        progress: show progress bars.
        pictures: draw values and policies (the maze, the car).
        hyperparams: ``RLVCAgent`` arguments over the table's entry for ``env_id``
            (``hyperparams_for``), e.g. ``{"compaction": False}``.
        eval_starts: starts the greedy policy is scored from on the maze and the car (seeded
            episodes on an env without an oracle); fewer score faster and noisier.

    Returns:
        The summary written to ``summary.json``.
    """
    check_at_least(1, eval_starts=eval_starts)
    hyperparams = hyperparams_for(env_id, hyperparams)
    start = time.perf_counter()
    out = run_dir("train_rlvc", out)
    settings = {"env_id": env_id, "env_kwargs": env_kwargs or {}, "interactions": interactions}
    if eval_starts != EVAL_STARTS:
        settings["eval_starts"] = eval_starts
    settings |= {"seed": seed, "hyperparams": hyperparams}
    check_same_settings(out / "settings.json", settings)
    check_unfinished(out)
    env = gym.make(env_id, **(env_kwargs or {}))
    scorer = Scorer(env_id, env_kwargs, eval_starts)
    agent = RLVCAgent(
        env, **agent_kwargs(hyperparams), seed=seed, tensorboard_log=out / "tensorboard"
    )
    evaluations = EvaluateEvery(scorer)
    agent, before = learn_resumable(agent, interactions, out, evaluations, progress)
    learned = time.perf_counter()
    final_return = evaluations.final
    agent.save(out / "rlvc_agent.pt")

    rlvc = agent.rlvc
    summary = {
        "env_id": env_id,
        "env_kwargs": env_kwargs or {},
        "hyperparams": hyperparams,
        "rlvc_return": final_return,
        "stages": len(rlvc.history),
        "classes": rlvc.n_classes,
        "selected_features": len(rlvc.structure.selected_features),
        "compound_features": len(rlvc.compound_features),
        "compounds_made": len(rlvc.compounds),
        "compaction_tolerance": agent.compaction.tolerance if agent.compaction else None,
        "structures": agent.structures,
        "vocabulary_size": agent.extractor.n_features,
        "vocabulary_groups": agent.vocabulary_groups,
        "enlarge": agent.extractor.keypoints.enlarge,  # what "auto" chose
        "min_count": agent.split_count,
        "min_effect": agent.split_margin,
        "interactions": agent.num_timesteps,
        "rewards_seen": agent.rewards_seen,
        "eval_starts": eval_starts,
        "evaluations": evaluations_of(evaluations),
    }
    task = scorer.task
    if task.oracle_return is not None:
        ceiling = true_grid_policy(task, agent.database)  # the agent's own interactions
        summary |= {
            "return_ratio": final_return / task.oracle_return,
            "oracle_return": task.oracle_return,
            "true_grid_return_ratio": task.evaluate(ceiling).mean / task.oracle_return,
        }
    if isinstance(task, MazeTask | CarTask):
        seen = seen_percepts_policy(
            task, agent.database, agent.rlvc.greedy(agent.database.presence).numpy()
        )
        summary["seen_percepts_return_ratio"] = task.evaluate(seen).mean / task.oracle_return
    if isinstance(task, MazeTask):
        summary |= {"starts_never_exiting": int((scorer.last_returns == 0).sum()), "paper": PAPER}
        if pictures:
            summary |= maze_pictures(agent, task, out)
    if isinstance(task, CarTask):
        failing = scorer.last_returns <= 0
        lost = task.oracle_returns[failing] - scorer.last_returns[failing]
        summary |= {
            "starts_failing": int(failing.sum()),
            # The share of the oracle's return lost on the failing starts; the rest of
            # 1 - return_ratio is lost on the starts that reach the top, later than the oracle.
            "return_gap_failing_starts": float(lost.sum() / task.oracle_returns.sum()),
        }
        summary |= velocity_readability(agent)
        if pictures:
            summary |= car_pictures(agent, task, out)
    summary |= {
        "seconds": before + time.perf_counter() - start,
        "learn_seconds": before + learned - start,
        "seconds_split": {
            "collect": agent.timing["collect"],
            "feature_extraction": agent.timing["extract"],
            "vocabulary": agent.timing["vocabulary"],
            "q_solving": rlvc.timing.solve,
            "split_search": rlvc.timing.split - rlvc.timing.compounds,
            "compound_search": rlvc.timing.compounds,
            "compaction": rlvc.timing.compaction,
            "evaluation": evaluations.seconds,
        },
        "history": [asdict(r) for r in rlvc.history],
        "seed": seed,
    }
    end_resumable(out, summary)
    print_summary(summary, out)
    return summary


def print_summary(summary: dict, out: Path) -> None:
    """Print the summary as a table, with the folder it was written to."""
    rows = {"RLVC mean return": summary["rlvc_return"]}
    if "return_ratio" in summary:
        rows |= {
            "return ratio (RLVC / oracle)": summary["return_ratio"],
            "oracle mean discounted return": summary["oracle_return"],
            "same interactions on a true 20x20 grid / oracle": summary["true_grid_return_ratio"],
        }
    for key, name in (
        ("seen_percepts_return_ratio", "acting as on the seen percept nearest in state / oracle"),
        ("starts_never_exiting", "starts never reaching an exit"),
        ("starts_failing", "starts not reaching the goal"),
        ("return_gap_failing_starts", "share of the oracle's return lost on them"),
        ("velocity_r2_best_word", "velocity R^2 of the best single word"),
        ("velocity_r2_best_compound", "velocity R^2 of the best compound"),
    ):
        if key in summary:
            rows[name] = summary[key]
    paper = summary.get("paper", {})  # the paper's maze figures, beside the maze's

    def label(name: str, key: str) -> str:
        return f"{name} (paper {paper[key]})" if key in paper else name

    rows |= {
        label("stages", "stages"): summary["stages"],
        label("visual classes", "classes"): summary["classes"],
        label("selected features", "selected_features"): summary["selected_features"],
        "compound features (tested / made)": (
            f"{summary['compound_features']} / {summary['compounds_made']}"
        ),
        label("vocabulary size", "vocabulary_size"): summary["vocabulary_size"],
        "interactions": summary["interactions"],
        **{f"seconds: {k}": v for k, v in summary["seconds_split"].items()},
        "seconds: whole run": summary["seconds"],
    }
    print_table(rows, title=f"RLVC on {summary['env_id']} -> {out}")
