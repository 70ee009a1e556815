"""The bench of grasps on every robosuite object that fits the hand
(``scripts/bench_grasp_objects.py``), with the learning runs stood in for."""

from __future__ import annotations

import json
import warnings

import pytest

pytest.importorskip("robosuite")

from vistask.envs import hand_fit
from vistask.envs.hand_fit import pose_misfits, warn_misfits
from vistask.envs.objects import lying_rotations, object_name, object_spec, rest_rotation
from vistask.experiments.grasp_objects import bench_grasp_objects, robosuite_objects
from vistask.experiments.grasps import GraspExperiment
from vistask.runs import check_same_settings


def test_robosuite_objects_keep_what_builds_and_say_why_others_do_not() -> None:
    kept, left_out = robosuite_objects()
    assert {"LemonObject", "CanObject", "BallObject", "PotWithHandlesObject"} <= set(kept)
    assert "only visual geoms" in left_out["CanVisualObject"]
    assert "no free joint" in left_out["DoorObject"]
    assert not set(kept) & set(left_out)


def test_a_bench_given_more_objects_keeps_the_settings_it_checks(tmp_path) -> None:
    path, free = tmp_path / "config.json", ("objects",)
    check_same_settings(path, {"objects": ["lemon"], "cycles": 5}, free)
    check_same_settings(path, {"objects": ["lemon", "can"], "cycles": 5}, free)
    assert json.loads(path.read_text())["objects"] == ["lemon", "can"]
    with pytest.raises(ValueError, match=r"other settings \(cycles 5 there, 3 now\)"):
        check_same_settings(path, {"objects": ["lemon"], "cycles": 3}, free)


def test_a_pose_fits_the_hand_where_some_part_is_narrower_than_the_opening() -> None:
    box = object_spec("BoxObject")  # 111 x 82 x 63 mm, resting on its largest face
    assert "82 mm across" in hand_fit.pose_misfit(box.make("probe"), rest_rotation(box))
    assert all(hand_fit.pose_misfit(box.make("probe"), r) is None for r in lying_rotations(box))
    # Lying on its side, the 100 x 150 mm cereal box is 30 mm high: nothing to close across.
    cereal = pose_misfits(object_spec("cereal"))
    assert set(cereal) == {"lying"} and "turned -90 degrees about x" in cereal["lying"]
    assert "100 mm across" in cereal["lying"]
    assert pose_misfits(object_spec("can")) == {
        "lying": "round about its upright axis, it would roll away on a side"
    }
    # A pot 140 mm across at its narrowest fits the hand by a handle, standing upright.
    assert set(pose_misfits(object_spec("PotWithHandlesObject"))) == {"lying"}


def test_fingers_from_above_hold_no_ball_by_its_rounded_top_or_underside(monkeypatch) -> None:
    ball = object_spec("BallObject")  # 111 mm across
    resting = ball.make("probe"), rest_rotation(ball)
    assert "rounded top or underside" in hand_fit.pose_misfit(*resting)
    # Its cap leans 45 degrees where it is 80 mm across: let sides lean that far and it fits.
    monkeypatch.setattr(hand_fit, "SLOPE", 1.5)
    assert hand_fit.pose_misfit(*resting) is None


def test_trials_in_a_pose_no_grasp_closes_across_are_warned_of(tmp_path) -> None:
    with pytest.warns(UserWarning, match="box_object: .*standing as built.*lay it on a side"):
        warn_misfits(object_spec("BoxObject"), 0.0)
    with pytest.warns(UserWarning, match="cereal: .*on some sides.*stand it upright"):
        warn_misfits(object_spec("cereal"), 0.3)
    big = tmp_path / "big.xml"  # a 30 cm cube: no side fits the hand
    big.write_text(
        '<mujoco model="big"><worldbody><body><body name="object">'
        '<geom type="box" size="0.15 0.15 0.15" group="0"/></body></body></worldbody></mujoco>'
    )
    with pytest.warns(UserWarning, match="no resting pose fits: make it smaller") as found:
        warn_misfits(object_spec(big), 0.3)
    assert len(found) == 1  # one warning, not advice for each pose that contradicts the other
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_misfits(object_spec("BoxObject"), 1.0)  # lying, it fits
        warn_misfits(object_spec("can"), 0.3)  # it never lies


def test_a_ring_fits_by_its_wall_with_a_finger_in_its_hole(monkeypatch) -> None:
    nut = object_spec("RoundNutObject")  # 108 mm across its ring
    assert hand_fit.pose_misfit(nut.make("probe"), rest_rotation(nut)) is None
    monkeypatch.setattr(hand_fit, "FINGER", 0.2)  # no hole takes so wide a finger
    assert "108 mm across" in hand_fit.pose_misfit(nut.make("probe"), rest_rotation(nut))


def test_bench_runs_each_object_upright_and_lying_and_checks_the_targets(tmp_path, monkeypatch):
    runs = []

    def run(self, out, pictures=3):
        runs.append((out.name, tuple(self.objects), self.tip_probability, self.trials_per_cycle))
        lying = self.tip_probability > 0
        return {
            "objects": {
                object_name(k): {
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
    summary = bench_grasp_objects(tmp_path, ["lemon", "can", "BoxObject"], trials=100)
    # The can stands round about a vertical axis: it cannot lie on a side. The box is wider
    # than the hand standing on its largest face.
    assert runs == [
        ("upright", ("lemon", "can"), 0.0, 20),
        ("lying", ("lemon", "BoxObject"), 1.0, 20),
    ]
    # The class at robosuite's sizes is not the "box" preset, nor named as it is.
    assert (object_name("BoxObject"), object_name("box")) == ("box_object", "box")
    box = summary["objects"]["box_object"]
    assert (box["sampled"], box["best_of_10"], box["lying_sampled"]) == (None, None, 0.8)
    assert set(summary["poses_left_out"]) == {"can", "box_object"}
    assert "82 mm" in summary["poses_left_out"]["box_object"]["upright"]
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
