"""Bad inputs at the public entry points: each is refused with an error that names what is
wrong, before any work starts."""

from __future__ import annotations

import json
import runpy
import sys
from pathlib import Path

import gymnasium as gym
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from vistask.agents import TabularQAgent
from vistask.grasp import GraspLearner, demonstration_density
from vistask.objects import ObjectModel
from vistask.rlvc import RLVC
from vistask.runs import check_same_settings, read_records, run_dir
from vistask.se3 import SE3KDE, identity_poses, random_poses
from vistask.vision import Patches

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def density_file(tmp_path) -> Path:
    path = tmp_path / "density.pt"
    SE3KDE(random_poses(5), sigma_t=0.01, sigma_r=0.3).save(path)
    return path


@pytest.mark.parametrize("cls", [SE3KDE, RLVC, ObjectModel, Patches, GraspLearner])
def test_every_library_file_is_checked_on_load(cls, density_file, tmp_path):
    loader = cls.load
    truncated, garbage = tmp_path / "truncated.pt", tmp_path / "garbage.pt"
    truncated.write_bytes(density_file.read_bytes()[:200])
    garbage.write_bytes(b"\x00not a model at all")
    for bad in (truncated, garbage):
        with pytest.raises(ValueError, match=f"{bad}.*(truncated|not a vistask)"):
            loader(bad)
    if cls is not SE3KDE:  # another class's file
        with pytest.raises(ValueError, match=f"holds a SE3KDE, not a {cls.__name__}"):
            loader(density_file)
    with pytest.raises(FileNotFoundError, match="no saved"):
        loader(tmp_path / "missing.pt")


def test_a_grasp_learner_round_trips(tmp_path):
    learner = GraspLearner(demonstration_density(identity_poses(1)))
    learner.save(tmp_path / "learner.pt")
    assert GraspLearner.load(tmp_path / "learner.pt").hypothesis.points.shape[1] == 7


@settings(max_examples=25, deadline=None)
@given(st.one_of(st.floats(allow_nan=True), st.integers(-5, -1), st.integers(16, 100)))
def test_tabular_predict_refuses_anything_but_a_known_state_id(state):
    agent = TabularQAgent(gym.make("FrozenLake-v1"), seed=0)
    with pytest.raises((TypeError, ValueError), match="state ids"):
        agent.predict(state)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"epsilon": 2.0}, "epsilon"),
        ({"epsilon": -0.1}, "epsilon"),
        ({"learning_rate": 0}, "learning_rate"),
    ],
)
def test_tabular_hyperparameters_out_of_range_are_refused(kwargs, name):
    with pytest.raises(ValueError, match=name):
        TabularQAgent(gym.make("FrozenLake-v1"), **kwargs)


@pytest.mark.parametrize(
    ("script", "args", "name"),
    [
        ("learn_grasps.py", ["--cycles", "-1"], "--cycles"),
        ("learn_grasps.py", ["--c-rel", "nan"], "--c-rel"),
        ("learn_grasps.py", ["--reliability", "-1"], "--reliability"),
        ("bench_features.py", ["--words", "0"], "--words"),
        ("compare_baselines.py", ["--seeds", "0"], "--seeds"),
        ("compare_baselines.py", ["--workers", "0"], "--workers"),
        ("bench_pose.py", ["--pictures", "-2"], "--pictures"),
        ("train_rlvc.py", ["--seed", "-1"], "--seed"),
        ("train_rlvc.py", ["--env-kwargs", "[1,2]"], "--env-kwargs"),
        ("compare_baselines.py", ["--env-kwargs", "{bad"], "--env-kwargs"),
        ("compare_compaction.py", ["--seeds", "-3"], "--seeds"),
    ],
)
def test_scripts_refuse_bad_values_before_any_work(script, args, name, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", [script, *args])
    with pytest.raises(SystemExit) as stopped:
        runpy.run_path(str(ROOT / "scripts" / script), run_name="__main__")
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {name}" in err and args[1] in err


def test_a_float32_density_is_exact_at_its_kernel_centre_for_narrow_kernels():
    # The example of the issue: 1e-4 rad made this 8e-29 instead of the kernel's peak.
    points = random_poses(2, generator=torch.Generator().manual_seed(1))
    density = SE3KDE(points, sigma_t=0.01, sigma_r=1e-4)
    torch.testing.assert_close(density.evaluate(points), torch.full((2,), 0.5), rtol=1e-5, atol=0)


def test_a_run_folder_records_its_script_and_refuses_another(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["train_rlvc.py", "--seed", "3"])
    run_dir("train_rlvc", tmp_path)
    run_dir("train_rlvc", tmp_path)  # a resumed run: the same script
    run = json.loads((tmp_path / "run.json").read_text())
    assert run == {"script": "train_rlvc", "commands": [["train_rlvc.py", "--seed", "3"]] * 2}
    with pytest.raises(ValueError, match="holds a run of 'train_rlvc', not of 'compare'"):
        run_dir("compare", tmp_path)


def test_garbage_in_a_run_folder_is_named(tmp_path, monkeypatch, capsys):
    (tmp_path / "settings.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"settings.json is not valid JSON"):
        check_same_settings(tmp_path / "settings.json", {"seed": 0})
    (tmp_path / "runs.jsonl").write_text('{"a": 1}\n{"b": \n')
    with pytest.raises(ValueError, match=r"runs.jsonl, line 2, is not valid JSON"):
        read_records(tmp_path / "runs.jsonl")
    monkeypatch.setattr(sys, "argv", ["train_rlvc.py", "--resume", str(tmp_path)])
    with pytest.raises(SystemExit):
        runpy.run_path(str(ROOT / "scripts" / "train_rlvc.py"), run_name="__main__")
    assert "settings.json is not valid JSON" in capsys.readouterr().err


def test_resuming_a_finished_run_is_refused(tmp_path, monkeypatch, capsys):
    (tmp_path / "settings.json").write_text('{"env_id": "vistask/VisualMaze-v0"}')
    (tmp_path / "summary.json").write_text("{}")
    monkeypatch.setattr(sys, "argv", ["train_rlvc.py", "--resume", str(tmp_path)])
    with pytest.raises(SystemExit):
        runpy.run_path(str(ROOT / "scripts" / "train_rlvc.py"), run_name="__main__")
    assert "holds a finished run" in capsys.readouterr().err
