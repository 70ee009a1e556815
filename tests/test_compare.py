"""The quick comparison: every method yields curves, the table, CSV, plot, TensorBoard logs."""

from __future__ import annotations

import csv
import json

import gymnasium as gym
import numpy as np
import pytest
import torch

from vistask.experiments.compare import compare
from vistask.experiments.compare_results import aggregate, interactions_to, speedups
from vistask.experiments.compare_runs import RunResult, sb3_env, sb3_pixels
from vistask.experiments.comparison import DISCRETE_METHODS, Comparison
from vistask.experiments.tasks import GridCells, task_for


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("compare")
    # Two worker processes, one thread each: the path a user's default run takes.
    return out, compare(Comparison.quick(budgets=(300, 600)), out, progress=False, workers=2)


def test_quick_comparison_writes_every_output(quick_run):
    out, summary = quick_run
    budgets = summary["budgets"]
    assert set(summary["methods"]) == set(DISCRETE_METHODS)
    on_disk = json.loads((out / "summary.json").read_text())
    for name in DISCRETE_METHODS:
        m = on_disk["methods"][name]
        for key in ("interactions_to_90pct", "final_return", "oracle_return", "seconds"):
            assert key in m
        assert m["oracle_return"] == pytest.approx(summary["oracle_return"])
        assert m["interactions_to_90pct"] is None or m["interactions_to_90pct"] in budgets
        curve = np.array(m["curve"]["per_seed"])
        assert curve.shape == (2, len(budgets))
        assert np.all(curve >= 0) and np.all(curve <= m["oracle_return"] * 1.5)
        assert np.all(np.array(m["curve"]["ci_low"]) <= np.array(m["curve"]["iqm"]) + 1e-9)
        assert (out / "tensorboard" / f"{name}-seed0").is_dir()
    # SB3 wrote its own training logs next to the evaluation scalars.
    assert list((out / "tensorboard" / "seed0").glob("dqn-sb3_*/events.*"))
    assert list((out / "tensorboard" / "seed1").glob("ppo-sb3_*/events.*"))
    # The privileged tabular agent is scored from true positions and learns something.
    assert summary["oracle_return"] > on_disk["methods"]["random"]["final_return"]

    rows = list(csv.DictReader((out / "curves.csv").open()))
    assert len(rows) == len(DISCRETE_METHODS) * len(budgets)
    assert {r["method"] for r in rows} == set(DISCRETE_METHODS)
    table = (out / "table.md").read_text()
    assert all(f"| {name} |" in table for name in DISCRETE_METHODS)
    for picture in ("curves", "aggregates", "profiles", "improvement", "wallclock"):
        assert (out / f"{picture}.png").read_bytes()[:4] == b"\x89PNG"
    # One line per independent run: RLVC learns afresh at each budget, the others once.
    runs = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    per_budget = {("rlvc", s, b) for s in (0, 1) for b in budgets}
    assert {(r["method"], r["seed"], r["budgets"][0]) for r in runs if r["method"] == "rlvc"} == (
        per_budget
    )
    assert len(runs) == 2 * 2 * len(budgets) + 4 * 2  # rlvc, rlvc_compounds; 4 others
    assert summary["failed"] == []
    dqn = on_disk["methods"]["dqn"]["curve"]["train_seconds"]
    assert 0 < dqn[0] < dqn[1]  # one DQN trained on: more time behind the larger budget
    stats = summary["statistics"]
    assert set(stats["aggregates"]) == set(DISCRETE_METHODS)
    assert set(stats["improvement"]) == {f"rlvc,{m}" for m in DISCRETE_METHODS if m != "rlvc"}


def test_tensorboard_holds_eval_return_against_interactions(quick_run):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out, summary = quick_run
    acc = EventAccumulator(str(out / "tensorboard" / "rlvc-seed1")).Reload()
    # The budgets are runs of their own, ending in any order; the log holds them in order.
    events = acc.Scalars("eval/return")
    assert [e.step for e in events] == summary["budgets"]
    run = next(r for r in summary["runs"] if r["method"] == "rlvc" and r["seed"] == 1)
    assert [e.value for e in events] == pytest.approx(run["returns"], rel=1e-5)


@pytest.mark.parametrize("env_id", ["vistask/VisualMaze-v0", "vistask/VisualMountainCar-v0"])
def test_grid_cells_wrapper_follows_the_true_state(env_id):
    task = task_for(env_id, eval_starts=1)
    env = GridCells(gym.make(env_id), task, grid=10)
    obs, info = env.reset(seed=3)
    for _ in range(20):
        assert obs == task.cells(info["position"][None], 10)[0]
        assert env.observation_space.contains(obs)
        obs, _, terminated, truncated, info = env.step(env.action_space.sample())
        if terminated or truncated:
            obs, info = env.reset()


def test_true_state_cells_cover_the_grid_row_by_row():
    maze = task_for("vistask/VisualMaze-v0", eval_starts=1)
    corners = np.array([[0.0, 0.0], [0.99, 0.0], [0.0, 0.99], [1.0, 1.0]])
    assert maze.cells(corners, 10).tolist() == [0, 9, 90, 99]
    car = task_for("vistask/VisualMountainCar-v0", eval_starts=1)
    corners = np.array([[-1.0, -3.0], [0.99, -3.0], [-1.0, 2.99], [1.0, 3.0], [0.05, 0.1]])
    assert car.cells(corners, 10).tolist() == [0, 9, 90, 99, 55]


def test_aggregation_thresholds():
    values = np.array([[0.0, 10.0], [1.0, 50.0], [2.0, 60.0], [3.0, 70.0], [100.0, 80.0]])
    assert interactions_to([1, 2, 3], np.array([0.0, 5.0, 9.0]), 5.0) == 2
    assert interactions_to([1, 2, 3], np.array([0.0, 5.0, 9.0]), 10.0) is None
    runs = [RunResult("a", s, [10, 20], list(v), 1.0, 2.0) for s, v in enumerate(values)]
    entry = aggregate(runs, [10, 20], oracle_return=60.0)["a"]
    assert entry["curve"]["iqm"] == pytest.approx([2.0, 60.0])  # the outlier 100 is trimmed
    assert entry["interactions_to_90pct"] == 20 and entry["seconds"] == pytest.approx(10.0)


def _quick_rlvc_and_random(**overrides) -> Comparison:
    small = {"methods": ("rlvc", "random"), "budgets": (200, 400), "seeds": 2, "eval_starts": 5}
    return Comparison.quick(**{**small, **overrides})


def test_a_comparison_resumes_where_it_stopped(tmp_path):
    config = _quick_rlvc_and_random(seeds=1)
    first = compare(config, tmp_path, progress=False, workers=1)
    lines = (tmp_path / "runs.jsonl").read_text().splitlines()
    assert len(lines) == 2 + 1  # rlvc: one run a budget; random: one run
    # Interrupted after all but two runs: resuming runs exactly those two, with the results
    # of a run straight through.
    (tmp_path / "runs.jsonl").write_text("\n".join(lines[:-2]) + "\n")
    again = compare(config, tmp_path, progress=False, workers=1)
    assert len((tmp_path / "runs.jsonl").read_text().splitlines()) == len(lines)
    returns = lambda s: [(r["method"], r["seed"], r["returns"]) for r in s["runs"]]  # noqa: E731
    assert returns(again) == returns(first)
    with pytest.raises(ValueError, match=r"other settings \(seeds 1 there, 2 now\)"):
        compare(_quick_rlvc_and_random(seeds=2), tmp_path, progress=False, workers=1)


@pytest.mark.slow
def test_worker_processes_and_a_local_ray_give_the_returns_of_one_process(tmp_path):
    config = _quick_rlvc_and_random(budgets=(200,))
    returns = lambda s: sorted((r["method"], r["seed"], r["returns"]) for r in s["runs"])  # noqa: E731
    alone = compare(config, tmp_path / "alone", progress=False, workers=1)
    processes = compare(config, tmp_path / "processes", progress=False, workers=2)
    ray = compare(config, tmp_path / "ray", progress=False, workers=2, address="local")
    assert returns(processes) == returns(alone) == returns(ray)
    assert len(alone["runs"]) == 4


def test_a_failed_run_is_reported_and_the_others_finish(tmp_path, monkeypatch):
    import vistask.experiments.compare_runs as runs

    def broken(seed, *args):
        raise FloatingPointError(f"seed {seed} diverged")

    monkeypatch.setattr(runs, "run_random", broken)
    config = _quick_rlvc_and_random(budgets=(200,))
    summary = compare(config, tmp_path, progress=False, workers=1)
    assert [f["method"] for f in summary["failed"]] == ["random", "random"]
    assert "FloatingPointError: seed 0 diverged" in summary["failed"][0]["error"]
    assert set(summary["methods"]) == {"rlvc"}
    # Fixed, the same command runs only the failed runs.
    monkeypatch.undo()
    summary = compare(config, tmp_path, progress=False, workers=1)
    assert summary["failed"] == [] and set(summary["methods"]) == {"rlvc", "random"}


def test_config_rejects_bad_input():
    with pytest.raises(ValueError, match="methods"):
        Comparison(methods=("a3c",))
    with pytest.raises(ValueError, match="budgets"):
        Comparison(budgets=(2000, 1000))


def test_speedup_ratio_and_its_interval():
    def method(to90, ci):
        return {
            "interactions_to_90pct": to90,
            "interactions_to_90pct_ci": ci,
            "interactions_to_75pct": None,
            "interactions_to_75pct_ci": [None, None],
        }

    methods = {
        "rlvc": method(1000, [500, 2000]),
        "dqn": method(None, [50_000, None]),
        "ppo": method(20_000, [10_000, 50_000]),
    }
    ratios = speedups(methods, [500, 1000, 2000, 10_000, 20_000, 50_000])
    assert ratios["sb3_over_rlvc_90pct"] == 20.0
    assert ratios["sb3_over_rlvc_90pct_ci"] == [5.0, 100.0]
    assert ratios["sb3_over_rlvc_75pct"] is None
    methods["ppo"] = method(None, [None, None])
    ratios = speedups(methods, [500, 1000, 2000, 10_000, 20_000, 50_000])
    assert ratios["sb3_over_rlvc_90pct"] is None
    assert ratios["sb3_over_rlvc_90pct_lower_bound"] == 50.0


def test_a_continuous_maze_compares_rljc_with_sac_and_ppo(tmp_path):
    small = dict(
        obstacles=((0.45, 0.0, 0.55, 0.6),),
        exits=((0.0, 0.0, 0.2, 0.2), (0.8, 0.0, 1.0, 0.2)),
        step=0.2,
        pixels_per_unit=240.0,
    )
    config = Comparison.quick(
        env_id="vistask/VisualMazeContinuous-v0",
        env_kwargs=small,
        budgets=(300, 600),
        seeds=1,
        eval_starts=10,
    )
    assert config.methods == ("rljc", "sac", "ppo", "random")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        summary = compare(config, tmp_path, progress=False)
    finally:
        torch.set_num_threads(threads)
    assert set(summary["methods"]) == set(config.methods)
    assert summary["runs"][0]["classes"][-1] > 1  # RLJC's joint classes
    assert "sb3_over_rljc_90pct" in summary["ratios"]
    assert list((tmp_path / "tensorboard" / "seed0").glob("sac-sb3_*/events.*"))
    with pytest.raises(ValueError, match="continuous actions: methods must"):
        Comparison(env_id="vistask/VisualMazeContinuous-v0", methods=("rlvc",))
    with pytest.raises(ValueError, match="discrete actions: methods must"):
        Comparison(methods=("sac",))


def test_sb3_baselines_take_grey_images_and_images_below_their_cnns_size():
    from stable_baselines3 import DQN

    from vistask.envs import VisualMazeEnv

    grey = gym.spaces.Box(0, 255, (20, 24), np.uint8)
    pixels = sb3_pixels(grey)
    image = grey.sample()
    big = pixels(image)
    assert big.shape == (40, 48, 1) and (big[::2, ::2, 0] == image).all()  # the same pixels
    assert pixels(np.stack([image] * 3)).shape == (3, 40, 48, 1)  # a batch
    assert sb3_pixels(gym.spaces.Box(0, 255, (64, 64, 3), np.uint8)) is None
    maze = gym.wrappers.TransformObservation(  # a grey 20-pixel view: NatureCNN needs 36
        VisualMazeEnv(window=20),
        lambda o: o.mean(axis=2).astype(np.uint8),
        gym.spaces.Box(0, 255, (20, 20), np.uint8),
    )
    env = sb3_env(maze, sb3_pixels(maze.observation_space))
    assert env.observation_space.shape == (40, 40, 1)
    DQN("CnnPolicy", env, learning_starts=20, buffer_size=200, seed=0).learn(60)
