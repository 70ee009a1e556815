"""Stopped runs resume with the results of a run straight through."""

from __future__ import annotations

import json
import os

import pytest
import torch

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.mark.slow
def test_grasp_learning_stopped_after_a_cycle_resumes_bit_for_bit(tmp_path, monkeypatch):
    pytest.importorskip("robosuite")
    from vistask.experiments.grasps import GraspExperiment
    from vistask.grasp import GraspLearner

    experiment = GraspExperiment(
        objects=("cube",),
        hypothesis="demo",
        cycles=3,
        trials_per_cycle=3,
        eval_trials=2,
        num_envs=1,
        candidates=2,
    )
    straight = experiment.run(tmp_path / "straight")

    run_cycle, calls = GraspLearner.run_cycle, []

    def stop_in_the_second_cycle(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return run_cycle(self, *args, **kwargs)

    monkeypatch.setattr(GraspLearner, "run_cycle", stop_in_the_second_cycle)
    with pytest.raises(KeyboardInterrupt):
        experiment.run(tmp_path / "stopped")
    assert (tmp_path / "stopped" / "cube" / "checkpoint.pt").exists()
    calls.clear()

    def count(self, *args, **kwargs):
        calls.append(1)
        return run_cycle(self, *args, **kwargs)

    monkeypatch.setattr(GraspLearner, "run_cycle", count)
    resumed = experiment.run(tmp_path / "stopped")
    assert len(calls) == 2  # the first cycle came from the checkpoint
    monkeypatch.undo()

    a = GraspLearner.load(tmp_path / "straight" / "cube" / "learner.pt")
    b = GraspLearner.load(tmp_path / "stopped" / "cube" / "learner.pt")
    assert torch.equal(a.trials.grasps, b.trials.grasps) and torch.equal(
        a.trials.success, b.trials.success
    )
    assert torch.equal(a.empirical.weights, b.empirical.weights)
    for key in ("hypothesis_success", "empirical_success", "empirical_best_of_k_success", "trials"):
        assert resumed["objects"]["cube"][key] == straight["objects"]["cube"][key]
    # Other settings in the same folder are refused rather than mixed in.
    with pytest.raises(ValueError, match=r"other settings \(cycles\)"):
        GraspExperiment(
            objects=("cube",),
            hypothesis="demo",
            cycles=2,
            trials_per_cycle=3,
            eval_trials=2,
            num_envs=1,
            candidates=2,
        ).run(tmp_path / "stopped")
    assert json.loads((tmp_path / "stopped" / "config.json").read_text())["cycles"] == 3
