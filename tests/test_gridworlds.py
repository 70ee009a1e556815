"""The MiniGrid benchmark: frames, scoring, runs, resuming and the summary's layout."""

import json

import numpy as np
import pytest

pytest.importorskip("minigrid")

from vistask.experiments import gridworlds
from vistask.experiments.gridworlds import (
    EPISODES,
    bench_gridworlds,
    grid_runs,
    make_gridworld,
    percept_table_policy,
    success_rate,
    summarise,
)
from vistask.parallel import RunsFailed

ENV = "MiniGrid-Empty-5x5-v0"


def test_gridworld_frames_are_64_pixel_rgb_images_of_the_whole_grid():
    env = make_gridworld(ENV)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (64, 64, 3) and obs.dtype == np.uint8
    assert env.action_space.n == 7


def test_success_counts_the_episodes_that_reach_the_goal():
    def never(observations):
        return np.zeros(len(observations), dtype=np.int64)  # turn left forever

    assert success_rate(never, ENV, episodes=5) == 0.0
    rng = np.random.default_rng(0)
    assert 0 < success_rate(lambda x: rng.integers(3, size=len(x)), ENV, episodes=20) <= 1


def test_rlvc_learns_one_agent_per_budget_and_the_others_train_once():
    runs = grid_runs([ENV], ["rlvc", "ppo", "random"], [0, 1], [1000, 2000])
    assert sum(r.method == "rlvc" for r in runs) == 4
    assert {r.budgets for r in runs if r.method != "rlvc"} == {(1000, 2000)}
    assert runs[-1].method == "random"  # the short runs last


def test_the_benchmark_writes_its_summary_and_resumes_what_is_missing(tmp_path, capsys):
    out = tmp_path / "bench"
    summary = bench_gridworlds([ENV], ["random", "ppo"], [0], [1024], out, workers=1)
    entry = summary[ENV]["random"]
    assert set(entry) == {"success", "interval", "to_reach", "per_seed"}
    assert 0 <= entry["success"]["1024"] <= 1 and "1024" in summary[ENV]["ppo"]["success"]
    assert summary["episodes"] == EPISODES and summary["failed"] == []
    assert (out / "success.png").stat().st_size > 0
    assert json.loads((out / "summary.json").read_text())[ENV]["random"] == entry
    capsys.readouterr()
    again = bench_gridworlds([ENV], ["random", "ppo"], [0], [1024], out, workers=1)
    assert again[ENV] == summary[ENV]
    assert "seed 0" not in capsys.readouterr().out  # nothing ran again
    with pytest.raises(ValueError, match="unknown methods"):
        bench_gridworlds([ENV], ["dqn"], [0], [1024], out, workers=1)


def test_a_task_that_is_not_minigrid_is_refused_and_failed_runs_end_the_benchmark(
    tmp_path, monkeypatch
):
    for env_id, error in (
        ("CartPole-v1", "not a MiniGrid task"),
        ("MiniGrid-Emty-5x5-v0", "Did you mean"),
    ):
        with pytest.raises(Exception, match=error):
            bench_gridworlds([env_id], ["random"], [0], [100], tmp_path / "refused", workers=1)
    assert not (tmp_path / "refused").exists()  # refused before any work
    run_grid = gridworlds.run_grid

    def fails_on_seed_1(run):
        if run.seed == 1:
            raise RuntimeError("a run that fails")
        return run_grid(run)

    monkeypatch.setattr(gridworlds, "run_grid", fails_on_seed_1)
    out = tmp_path / "bench"
    with pytest.raises(RunsFailed, match=r"1 of the runs failed: .* random: RuntimeError"):
        bench_gridworlds([ENV], ["random"], [0, 1], [100], out, workers=1)
    summary = json.loads((out / "summary.json").read_text())  # what finished is written
    assert list(summary[ENV]["random"]["per_seed"]) and len(summary["failed"]) == 1


def test_the_first_database_extracts_each_frame_it_meets_once(monkeypatch):
    from vistask.agents import RLVCAgent
    from vistask.features import SiftExtractor

    extracted = []
    detect = SiftExtractor._detect

    def counted(self, image):
        extracted.append(image.tobytes())
        return detect(self, image)

    monkeypatch.setattr(SiftExtractor, "_detect", counted)
    # 3,000 random steps in a 3 x 3 room meet at most its 36 frames (cell and heading).
    RLVCAgent(make_gridworld(ENV), databases=1, max_stages=1, seed=0).learn(3000)
    assert 1 < len(extracted) == len(set(extracted)) <= 36


def test_the_percept_table_acts_on_what_the_database_holds_where_the_classes_cannot():
    from vistask.agents import RLVCAgent

    # One stage on one database leaves one class: its greedy action never reaches the goal.
    agent = RLVCAgent(make_gridworld(ENV), databases=1, max_stages=1, n_envs=8, seed=0)
    agent.learn(3000)
    assert agent.rlvc.n_classes == 1 and agent.rewards_seen > 0
    assert success_rate(lambda x: agent.predict(x)[0], ENV, episodes=10) == 0.0
    assert success_rate(percept_table_policy(agent), ENV, episodes=10) == 1.0


def test_the_summary_gives_the_percept_table_where_the_records_hold_it():
    run = {"env_id": ENV, "method": "rlvc", "budgets": [1000]}
    records = [
        {**run, "seed": 0, "success": [0.0], "percept_table": [1.0]},
        {**run, "seed": 1, "success": [0.5]},  # a record from before the field
    ]
    entry = summarise(records, [ENV], ["rlvc"], [0, 1], [1000])[ENV]["rlvc"]
    assert entry["per_seed"]["1000"] == {"0": 0.0, "1": 0.5}
    assert entry["percept_table"] == {"1000": 1.0}
