"""A run's memory: its peak measured, its need estimated and refused when it would not fit,
and the scaling benchmark's summary."""

import json
import time
from collections import namedtuple

import gymnasium as gym
import numpy as np
import pytest

import vistask.envs  # noqa: F401  (registers the maze)
from vistask.agents import RLVCAgent, visual_agent
from vistask.experiments.bench_scale import bench_scale, growth_exponent
from vistask.memory import PeakMemory


def test_peak_memory_sees_an_array_freed_inside_the_block():
    with PeakMemory(every=0.01) as memory:
        start = memory.peak_mb
        block = np.ones(300 * 2**20 // 8)  # 300 MB, touched
        # Held for many sampling periods: on a loaded machine the sampling thread may not run
        # within one, and the process's own peak bounds only spikes above its lifetime peak.
        time.sleep(0.5)
        del block
    assert memory.peak_mb >= start + 250


def test_the_estimate_grows_with_the_run_and_a_run_that_would_not_fit_is_refused(monkeypatch):
    agent = RLVCAgent(gym.make("vistask/VisualMaze-v0"))
    small, large = agent.memory_needed_mb(40_000), agent.memory_needed_mb(400_000)
    assert 0 < small < large
    fewer_words = RLVCAgent(gym.make("vistask/VisualMaze-v0"), n_words=1024)
    assert fewer_words.memory_needed_mb(400_000) < large
    free = namedtuple("Memory", "available")
    monkeypatch.setattr(visual_agent.psutil, "virtual_memory", lambda: free(int(small * 2**20)))
    with pytest.raises(MemoryError, match=r"learn\(400000\) would need about \d+ MB"):
        agent.learn(400_000)
    assert agent.num_timesteps == 0  # refused before collecting
    with pytest.raises(ValueError, match="total_timesteps must be >= 1"):
        agent.memory_needed_mb(-5)


def test_a_run_folder_that_cannot_be_made_is_refused_naming_it(tmp_path):
    from vistask.runs import run_dir

    (tmp_path / "file").write_text("")
    for out in (tmp_path / "file" / "run", "/proc/no-run-here"):
        with pytest.raises(ValueError, match=r"out: cannot make the run folder .*run"):
            run_dir("bench_scale", out)


def test_bench_scale_ends_with_the_error_of_a_run_that_would_not_fit(tmp_path):
    from vistask.parallel import RunsFailed

    budgets = {"vistask/VisualMaze-v0": [10**9]}
    with pytest.raises(RunsFailed, match=r"every run failed: .* at 1000000000: MemoryError: "):
        bench_scale(["vistask/VisualMaze-v0"], budgets, out=tmp_path)
    assert not (tmp_path / "summary.json").exists()


def test_growth_exponent_of_a_power_law():
    budgets = [1000, 2000, 4000]
    assert growth_exponent(budgets, [3 * b**1.5 for b in budgets]) == pytest.approx(1.5)


def test_bench_scale_measures_each_budget_once_and_resumes(tmp_path, capsys):
    budgets = {"vistask/VisualMaze-v0": [1200, 2400]}
    summary = bench_scale(["vistask/VisualMaze-v0"], budgets, out=tmp_path)
    maze = summary["vistask/VisualMaze-v0"]
    for budget in ("1200", "2400"):
        run = maze[budget]
        assert run["peak_rss_mb"] > 100 and run["classes"] >= 1 and run["seconds"] > 0
        assert sum(run["seconds_by_phase"].values()) == pytest.approx(run["seconds"])
    assert {"time_exponent", "memory_exponent", "predict_ms_per_percept"} <= set(maze)
    assert (tmp_path / "scale.png").stat().st_size > 0
    assert json.loads((tmp_path / "summary.json").read_text()) == summary
    assert "VisualMaze-v0 | 2400" in capsys.readouterr().out
    again = bench_scale(["vistask/VisualMaze-v0"], budgets, out=tmp_path)  # nothing to run
    assert again == summary
    assert len((tmp_path / "runs.jsonl").read_text().splitlines()) == 2


def test_one_run_learns_the_same_classes_on_one_and_on_two_threads():
    from vistask.experiments.bench_parallel import bench_one_run

    rows = bench_one_run((1, 2), interactions=3_000, views=64)
    assert [(r["work"], r["workers"]) for r in rows] == [
        ("one RLVC run", 1),
        ("one RLVC run", 2),
        ("SIFT of 64 views", 1),
        ("SIFT of 64 views", 2),
    ]
    assert rows[0]["classes"] > 1
    assert all(r["same_results"] for r in rows)
