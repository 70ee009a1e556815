"""Bad inputs at the public entry points: each is refused with an error that names what is
wrong, before any work starts."""

from __future__ import annotations

import json
import math
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
from vistask.runs import check_same_settings, read_json, read_records, run_dir, write_json
from vistask.saving import load_state, save_state
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
        ("bench_grasp_objects.py", ["--trials", "0"], "--trials"),
        ("bench_features.py", ["--words", "0"], "--words"),
        ("bench_keypoints.py", ["--views", "0"], "--views"),
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


def test_a_write_that_fails_keeps_the_file_before_and_leaves_no_part(tmp_path, monkeypatch):
    model, summary = tmp_path / "model.pt", tmp_path / "summary.json"
    save_state(model, "Model", {"a": 1})
    write_json(summary, {"a": 1})

    def full_disk(value, file):  # as torch.save on a full disk: a part written, then an error
        Path(file).write_bytes(b"part")
        raise RuntimeError("[enforce fail at inline_container.cc:664] . unexpected pos 64 vs 0")

    def no_space(self, text):
        self.write_bytes(b"part")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(torch, "save", full_disk)
    monkeypatch.setattr(Path, "write_text", no_space)
    for write, path in (
        (lambda: save_state(model, "Model", {"a": 2}), model),
        (lambda: write_json(summary, {"a": 2}), summary),
    ):
        with pytest.raises(
            OSError,
            match=rf"cannot write {path} .* MB free on its disk\): the file there before is kept",
        ):
            write()
    monkeypatch.undo()
    assert load_state(model, "Model") == {"a": 1} and read_json(summary) == {"a": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.pt", "summary.json"]


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
    # The same command again, as a fresh run into the folder, would learn over it
    (tmp_path / "run.json").write_text('{"script": "train_rlvc", "commands": []}')
    (tmp_path / "settings.json").unlink()  # the defaults' settings, written by this command
    monkeypatch.setattr(sys, "argv", ["train_rlvc.py", "--out", str(tmp_path)])
    with pytest.raises(SystemExit):
        runpy.run_path(str(ROOT / "scripts" / "train_rlvc.py"), run_name="__main__")
    assert f"{tmp_path} holds a finished run" in capsys.readouterr().err


# -- every public entry point checks the types its annotations name ---------------------------
PACKAGES = ("agents", "rlvc", "se3", "objects", "grasp", "vision", "features", "envs")


def test_every_public_class_and_function_checks_its_argument_types():
    import importlib
    import inspect

    unchecked = []
    for package in PACKAGES:
        module = importlib.import_module(f"vistask.{package}")
        for name in module.__all__:
            member = getattr(module, name)
            ours = getattr(member, "__module__", "").startswith("vistask")  # not roma's
            if (
                (inspect.isclass(member) or inspect.isfunction(member))
                and ours
                and not getattr(member, "__checked__", False)
            ):
                unchecked.append(f"vistask.{package}.{name}")
    assert not unchecked, f"without @checked: {unchecked}"


@settings(max_examples=60, deadline=None)
@given(
    st.sampled_from(["n_words", "databases", "min_count", "max_stages", "n_envs", "seed"]),
    st.one_of(st.floats(allow_nan=True), st.text(max_size=3), st.booleans(), st.complex_numbers()),
)
def test_an_integer_setting_of_another_type_is_refused_naming_it(name, value):
    from vistask.agents import RLVCAgent

    with pytest.raises((TypeError, ValueError), match=name):
        RLVCAgent(None, **{name: value})


@settings(max_examples=80, deadline=None)
@given(
    st.sampled_from(["alpha", "epsilon", "gamma", "contrast_threshold", "min_effect"]),
    st.floats(allow_nan=True, allow_infinity=True),
)
def test_a_float_setting_is_kept_in_its_range_or_refused_naming_it(name, value):
    from vistask.agents import RLVCAgent

    try:
        agent = RLVCAgent(None, **{name: value})
    except ValueError as error:
        assert name in str(error)
        return
    kept = getattr(agent, name)
    assert (
        math.isfinite(kept)
        and {
            "alpha": 0 < kept < 1,
            "epsilon": 0 <= kept <= 1,
            "gamma": 0 <= kept < 1,
            "contrast_threshold": kept > 0,
            "min_effect": 0 <= kept < 1,
        }[name]
    )


@settings(max_examples=60, deadline=None)
@given(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(allow_nan=True, allow_infinity=True),
    st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=5, max_size=5),
)
def test_a_density_is_finite_and_positive_at_its_particles_or_refused_naming_why(
    sigma_t, sigma_r, weights
):
    points = random_poses(5, generator=torch.Generator().manual_seed(0)).double()
    try:
        density = SE3KDE(points, torch.tensor(weights), sigma_t=sigma_t, sigma_r=sigma_r)
    except ValueError as error:
        assert any(name in str(error) for name in ("sigma_t", "sigma_r", "weights"))
        return
    values = density.evaluate(points)
    assert torch.isfinite(values).all() and (values > 0).all()


@settings(max_examples=40, deadline=None)
@given(st.floats(min_value=-1e300, max_value=1e300), st.integers(0, 4))
def test_a_far_particle_is_refused_or_leaves_the_others_intact(offset, column):
    points = random_poses(4, generator=torch.Generator().manual_seed(1)).double()
    moved = points.clone()
    moved[0, column % 3] += offset
    try:
        density = SE3KDE(moved, sigma_t=0.1)
    except ValueError as error:
        assert "points" in str(error) and ("overflow" in str(error) or "precision" in str(error))
        return
    assert torch.isfinite(density.evaluate(points)).all()


# -- one test per kind of mistake ---------------------------------------------------------------
def test_options_that_act_only_with_another_are_refused_without_it():
    with pytest.raises(ValueError, match="compact_every acts only with compaction"):
        RLVC(40, 4, 0.9, compact_every=5)
    with pytest.raises(ValueError, match="compound_tolerances acts only with use_compounds"):
        RLVC(40, 4, 0.9, compound_tolerances=(0.5,))
    with pytest.raises(ValueError, match="checkpoint_every needs checkpoint"):
        TabularQAgent(gym.make("FrozenLake-v1")).learn(10, checkpoint_every=5)
    assert RLVC(40, 4, 0.9, compaction=True, compact_every=5).compact_every == 5


def test_densities_that_do_not_overlap_have_no_product():
    from vistask.se3 import product

    near = SE3KDE(random_poses(5), sigma_t=0.05)
    far = SE3KDE(random_poses(5) + torch.tensor([100.0, 0, 0, 0, 0, 0, 0]), sigma_t=0.01)
    with pytest.raises(ValueError, match=r"do not overlap: densities\[1\]"):
        product([near, far], 50)
    assert len(product([near, near], 50)) == 50


def test_weights_near_the_largest_float_still_give_a_density():
    points = random_poses(5).double()
    density = SE3KDE(points, torch.full((5,), 1e308, dtype=torch.float64))
    torch.testing.assert_close(density.weights, torch.full((5,), 0.2, dtype=torch.float64))


def test_an_agent_refuses_to_learn_on_another_env_than_it_learned_on(tmp_path):
    lake = TabularQAgent(gym.make("FrozenLake-v1"), seed=0).learn(50)
    lake.save(tmp_path / "lake.pt")
    other = gym.make("FrozenLake-v1", is_slippery=False)
    with pytest.warns(UserWarning, match="acting on another env") as warned:
        loaded = TabularQAgent.load(tmp_path / "lake.pt", env=other)
    assert warned[0].filename == __file__  # the warning points at the user's line
    with pytest.raises(ValueError, match=r"is_slippery.*start a new agent"):
        loaded.learn(10)
    TabularQAgent.load(tmp_path / "lake.pt", env=gym.make("FrozenLake-v1")).learn(10)


def test_a_script_refuses_a_resume_with_other_settings_in_one_line(tmp_path, monkeypatch, capsys):
    (tmp_path / "settings.json").write_text('{"env_id": "vistask/VisualMaze-v0"}')
    monkeypatch.setattr(sys, "argv", ["train_rlvc.py", "--resume", str(tmp_path), "--seed", "4"])
    with pytest.raises(SystemExit):
        runpy.run_path(str(ROOT / "scripts" / "train_rlvc.py"), run_name="__main__")
    assert "drop --seed" in capsys.readouterr().err


def test_a_refusal_inside_a_script_is_one_line_naming_it(tmp_path, monkeypatch, capsys):
    env_kwargs = '{"layout_seed": -1}'
    monkeypatch.setattr(sys, "argv", ["train_rlvc.py", "--env-kwargs", env_kwargs])
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stopped:
        runpy.run_path(str(ROOT / "scripts" / "train_rlvc.py"), run_name="__main__")
    err = capsys.readouterr().err
    assert stopped.value.code == 2 and "Traceback" not in err
    assert "train_rlvc.py: error: layout_seed must be >= 0, got -1" in err


def test_the_sweep_of_wrong_inputs_over_the_api_finds_every_answer_clear(tmp_path):
    from vistask.experiments.wrong_input_cases import api_cases
    from vistask.experiments.wrong_inputs import answer_call, summary

    result = summary([answer_call(case) for case in api_cases(tmp_path)])
    assert result["cases"] >= 300
    assert result["outcomes"]["clear"] == result["cases"], result["not_clear"]
