"""The robosuite grasp-trial environment (one env built per module: about 5 s)."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest
import torch

pytest.importorskip("robosuite")

from vistask.envs.grasp_runners import VectorGraspTrials
from vistask.envs.grasp_trial import GraspTrialEnv, check_grasp, top_down_grasp

EASY = {"n_distractors": 0, "placement_range": 0.06, "tip_probability": 0.0}


@pytest.fixture(scope="module")
def env():
    # The easy placement the scripted grasps assume: upright, near the centre, alone.
    env = GraspTrialEnv("cube", cameras=("front",), image_size=96, **EASY)
    yield env
    env.close()


def test_reset_observation_matches_its_space(env) -> None:
    obs, info = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    assert info["object_pose"].shape == (7,)
    assert abs(np.linalg.norm(info["object_pose"][3:]) - 1) < 1e-6
    # The cube rests on the table (z of its centre = half its side above the top).
    assert abs(info["object_pose"][2] - (0.8 + 0.021)) < 0.005
    seg = obs["front_segmentation"]
    assert (seg == 0).sum() > 20  # the target is visible
    depth = obs["front_depth"][seg == 0]
    assert 0.3 < depth.mean() < 1.2
    patches = env.patches(obs, label=0)
    assert len(patches) > 0
    assert np.linalg.norm(patches.positions.mean(0).numpy() - info["object_pose"][:3]) < 0.05


def test_scripted_top_down_grasp_succeeds_and_far_grasp_fails(env) -> None:
    _, info = env.reset(seed=11)
    grasp = top_down_grasp(info["object_pose"], info["object_bounds"])
    _, reward, terminated, truncated, step_info = env.step(grasp)
    assert (reward, terminated, truncated) == (1.0, True, False)
    assert step_info["lift_height"] >= 0.05 and step_info["grasped"]
    assert step_info["grasp_error_t"] < 0.01
    with pytest.raises(RuntimeError, match="reset"):
        env.step(grasp)

    _, info = env.reset(seed=12)
    far = top_down_grasp(info["object_pose"], info["object_bounds"])
    far[1] += 0.2
    _, reward, _, _, step_info = env.step(far)
    assert reward == 0.0 and step_info["reason"] == "missed"
    assert abs(step_info["lift_height"]) < 0.01


def test_unreachable_grasp_fails_cleanly_and_next_reset_is_unaffected(env) -> None:
    _, info = env.reset(seed=13)
    below = top_down_grasp(info["object_pose"], info["object_bounds"])
    below[2] -= 0.3  # inside the table
    _, reward, _, _, step_info = env.step(below)
    assert reward == 0.0 and step_info["reason"] == "unreachable"
    _, info = env.reset(seed=14)
    assert abs(info["object_pose"][2] - (0.8 + 0.021)) < 0.005
    _, reward, _, _, _ = env.step(top_down_grasp(info["object_pose"], info["object_bounds"]))
    assert reward == 1.0


@pytest.mark.parametrize(
    ("grasp", "message"),
    [
        (np.zeros(6), "shape"),
        (np.zeros((1, 7)), "shape"),
        (np.r_[0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 2.0], "unit norm"),
        (np.r_[np.nan, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "finite"),
        (np.array(["a"] * 7), "numeric"),
    ],
)
def test_malformed_grasps_are_rejected(env, grasp, message) -> None:
    with pytest.raises(ValueError, match=message):
        check_grasp(grasp)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=message):
        env.step(grasp)


@pytest.mark.slow
def test_parallel_trials_in_processes() -> None:
    runner = VectorGraspTrials("cube", num_envs=2, **EASY)
    try:
        poses = runner.reset([1, 2])
        assert poses.shape == (2, 7)
        bounds = runner.object_bounds
        grasps = np.stack([top_down_grasp(p.double().numpy(), bounds) for p in poses])
        grasps[1, 1] += 0.2  # one far miss
        success, info = runner.execute(grasps)
        assert success.tolist() == [True, False]
        assert list(info["reason"]) == ["success", "missed"]
    finally:
        runner.close()


@pytest.mark.slow
def test_ray_actors_run_the_trials_of_local_processes() -> None:
    from vistask.envs.grasp_runners import RayGraspTrials
    from vistask.grasp import demonstration_density, run_trials, scripted_teacher_grasps

    results = []
    for make in (
        lambda: RayGraspTrials("cube", num_envs=2, **EASY),
        lambda: VectorGraspTrials("cube", 1, asynchronous=True, **EASY),
    ):
        runner = make()
        try:
            bounds = torch.as_tensor(runner.object_bounds, dtype=torch.float32)
            generator = torch.Generator().manual_seed(0)
            density = demonstration_density(scripted_teacher_grasps(bounds), generator=generator)
            results.append(run_trials(density, runner, 5, range(5), runner.workspace, generator))
            assert len(runner.last_info["reason"]) == runner.num_envs
        finally:
            runner.close()
    (grasps_ray, success_ray, _, _), (grasps_proc, success_proc, _, _) = results
    torch.testing.assert_close(grasps_ray, grasps_proc)
    assert torch.equal(success_ray, success_proc) and len(success_ray) == 5


def test_a_simulation_gone_nan_fails_its_trial_and_the_next_one_runs(env, monkeypatch) -> None:
    _, info = env.reset(seed=3)
    grasp = top_down_grasp(info["object_pose"], info["object_bounds"])
    act = env._act

    def unstable(*args):
        env._sim.data.qvel[:] = np.nan  # what a diverging integration leaves behind
        act(*args)

    monkeypatch.setattr(env, "_act", unstable)
    _, reward, terminated, _, info = env.step(grasp)
    assert reward == 0.0 and terminated
    assert info["reason"] == "simulator" and "NaN or unbounded" in info["error"]
    monkeypatch.undo()
    _, info = env.reset(seed=3)
    _, reward, _, _, info = env.step(top_down_grasp(info["object_pose"], info["object_bounds"]))
    assert reward == 1.0 and info["reason"] == "success" and info["error"] == ""


def test_estimated_poses_drive_the_trials() -> None:
    """The trials act on the pose the robot estimated: with the estimate fixed, the grasp does
    not depend on where the object really is; shift the estimate and the grasp shifts."""
    from types import SimpleNamespace

    from vistask.envs.tabletop import object_patches
    from vistask.grasp import demonstration_density, run_trials, scripted_teacher_grasps
    from vistask.objects import ObjectModel

    patches = object_patches("cube", 2, ("front", "top"), 128, voxel=0.004)
    model = ObjectModel.learn(patches, name="cube")
    runner = VectorGraspTrials("cube", 1, model, cameras=("front",), image_size=96, **EASY)

    class Fixed:
        """An estimator that always sees the object at ``pose``."""

        def __init__(self, pose: torch.Tensor) -> None:
            self.pose = pose

        def infer(self, model, patches, device=None, seed=0, depth=None):
            return SimpleNamespace(pose=self.pose)

    try:
        bounds = torch.as_tensor(runner.object_bounds, dtype=torch.float32)
        teacher = scripted_teacher_grasps(bounds)
        density = demonstration_density(teacher, generator=torch.Generator().manual_seed(0))

        def trials(seeds, pose):
            runner.env.envs[0].nbp = Fixed(pose)
            records = []
            generator = torch.Generator().manual_seed(1)
            run_trials(density, runner, 2, seeds, None, generator, records=records)
            return records

        estimate = torch.tensor([0.0, 0.05, 0.83, 0.0, 0.0, 0.0, 1.0])
        here, there = trials([1, 2], estimate), trials([7, 8], estimate)
        truths = [np.array(r["object_pose"]) for r in here + there]
        assert np.abs(truths[0][:2] - truths[2][:2]).max() > 0.005  # the objects moved
        for a, b in zip(here, there, strict=True):
            np.testing.assert_allclose(a["world_grasp"], b["world_grasp"], atol=1e-6)
            np.testing.assert_allclose(a["estimated_pose"], estimate.numpy(), atol=1e-6)
            error = np.linalg.norm(np.array(a["object_pose"][:3]) - estimate[:3].numpy())
            assert abs(a["pose_error_m"] - error) < 1e-4
        shift = torch.tensor([0.04, -0.02, 0.0, 0.0, 0.0, 0.0, 0.0])
        moved = trials([1, 2], estimate + shift)
        for a, b in zip(here, moved, strict=True):
            np.testing.assert_allclose(
                np.array(b["world_grasp"]) - a["world_grasp"], shift.numpy(), atol=1e-5
            )
            np.testing.assert_allclose(a["grasp"], b["grasp"], atol=1e-6)  # object frame
    finally:
        runner.close()


@pytest.mark.parametrize("kind", ["tests/data/hinged_lid.xml", "hinged_box"])
def test_objects_of_several_bodies_and_joints_run_trials(kind) -> None:
    env = GraspTrialEnv(kind, cameras=("front",), image_size=64, **EASY)
    _, info = env.reset(seed=1)
    lo, hi = info["object_bounds"]
    assert hi[2] - lo[2] > 0.04  # the lid's geoms count in the object's box
    _, _, terminated, _, step_info = env.step(
        top_down_grasp(info["object_pose"], info["object_bounds"])
    )
    assert terminated and step_info["error"] == ""
    env.close()


def test_a_round_object_stays_where_it_was_seen() -> None:
    """The lemon, an ellipsoid of 3 g, rocked and rolled on the table for seconds after it
    was placed (26 of 40 placements moved more than 5 mm or 10 degrees in the 2 s the arm
    takes to its pre-grasp pose) until the table's rolling friction took effect."""
    from scipy.spatial.transform import Rotation

    env = GraspTrialEnv("lemon", cameras=(), n_distractors=0)
    try:
        for seed in range(8):
            _, info = env.reset(seed=seed)
            home = env.eef_pose()
            for _ in range(40):  # 2 s at 20 Hz, the arm holding still
                env._act(home[:3], Rotation.from_quat(home[3:]), -1.0)
            seen, now = info["object_pose"], env.object_pose()
            turned = Rotation.from_quat(now[3:]) * Rotation.from_quat(seen[3:]).inv()
            assert np.linalg.norm(now[:3] - seen[:3]) < 0.005
            assert np.degrees(turned.magnitude()) < 10
    finally:
        env.close()


def test_a_reset_draws_the_scene_again_where_it_finds_no_room(env, monkeypatch) -> None:
    import vistask.envs.grasp_trial as grasp_trial
    from vistask.envs.objects import NoRoomError

    place, calls = grasp_trial.place_apart, []

    def crowded(*args, **kwargs):  # no room at the first draw of a reset, room at the next
        calls.append(1)
        if len(calls) == 1:
            raise NoRoomError("no room")
        return place(*args, **kwargs)

    monkeypatch.setattr(grasp_trial, "place_apart", crowded)
    _, info = env.reset(seed=3)
    assert len(calls) == 2 and info["object_pose"][2] > 0

    def full(*args, **kwargs):
        raise NoRoomError("no room")

    monkeypatch.setattr(grasp_trial, "place_apart", full)
    with pytest.raises(NoRoomError, match=r"cube and 0 distractors .* \(--distractors\)"):
        env.reset(seed=4)
