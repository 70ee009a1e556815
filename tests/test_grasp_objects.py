"""The bench of grasps on every robosuite object that fits the hand
(``scripts/bench_grasp_objects.py``), with the learning runs stood in for."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("robosuite")

from vistask.experiments.grasp_objects import bench_grasp_objects, graspable_objects
from vistask.experiments.grasps import GraspExperiment


def test_graspable_objects_keep_what_fits_the_hand_and_say_why_others_do_not() -> None:
    kept, left_out = graspable_objects()
    assert {"LemonObject", "CanObject", "MilkObject", "RoundNutObject"} <= set(kept)
    assert "does not fit between the open fingers (80 mm)" in left_out["BallObject"]
    assert "only visual geoms" in left_out["CanVisualObject"]
    assert "no free joint" in left_out["DoorObject"]
    assert not set(kept) & set(left_out)


def test_bench_runs_each_object_upright_and_lying_and_checks_the_targets(tmp_path, monkeypatch):
    runs = []

    def run(self, out, pictures=3):
        runs.append((out.name, tuple(self.objects), self.tip_probability, self.trials_per_cycle))
        lying = self.tip_probability > 0
        return {
            "objects": {
                k: {
                    "empirical_success": 0.8 if lying else 0.9,
                    "best_of_10_success": 0.95 if k == "lemon" else 0.85,
                    "failure_reasons": {"dropped": 4, "missed": 1},
                    "eval_trials_per_measure": 100,
                    "mean_pose_error_deg": 3.0,
                    "mean_pose_error_cm": 0.2,
                    "ranking_width": 6.0,
                }
                for k in self.objects
            }
        }

    monkeypatch.setattr(GraspExperiment, "run", run)
    summary = bench_grasp_objects(tmp_path, ["lemon", "can"], trials=100)
    # The can stands round about a vertical axis: it cannot lie on a side.
    assert runs == [("upright", ("lemon", "can"), 0.0, 20), ("lying", ("lemon",), 1.0, 20)]
    lemon, can = summary["objects"]["lemon"], summary["objects"]["can"]
    assert (lemon["sampled"], lemon["lying_sampled"], can["lying_sampled"]) == (0.9, 0.8, None)
    assert lemon["drop_rate"] == 0.04 and lemon["position_error_mm"] == 2.0
    assert lemon["symmetry"]["axis"] is not None  # about its long axis
    assert summary["mean_best_of_10"] == pytest.approx(0.9)
    assert summary["met"] == {
        "mean_sampled": True,
        "mean_best_of_10": False,
        "lowest_sampled": True,
        "lying": True,
        "best_of_10_at_least_sampled": False,  # the can's 0.85 against 0.9
    }
    assert json.loads((tmp_path / "summary.json").read_text())["objects"]["can"]["sampled"] == 0.9
    assert (tmp_path / "success.png").stat().st_size > 0
    with pytest.raises(ValueError, match="trials"):
        bench_grasp_objects(tmp_path, ["lemon"], trials=3)
