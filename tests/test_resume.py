"""Stopped runs resume with the results of a run straight through."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch

os.environ.setdefault("MUJOCO_GL", "egl")


def _frozen_lake():
    import gymnasium as gym

    return gym.make("FrozenLake-v1")  # slippery: the env's own generator matters


def test_tabular_q_interrupted_and_resumed_ends_as_a_straight_run(tmp_path):
    import numpy as np
    from stable_baselines3.common.callbacks import BaseCallback

    from vistask.agents import TabularQAgent

    straight = TabularQAgent(_frozen_lake(), seed=3).learn(20_000)

    class Interrupt(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps == 12_345:
                raise KeyboardInterrupt
            return True

    path = tmp_path / "q.pt"
    stopped = TabularQAgent(_frozen_lake(), seed=3)
    with pytest.raises(KeyboardInterrupt):
        stopped.learn(20_000, callback=Interrupt(), checkpoint=path, checkpoint_every=5_000)
    resumed = TabularQAgent.load(path, _frozen_lake())  # a fresh env, as after a crash
    assert 0 < resumed.num_timesteps <= 12_345
    resumed.learn(20_000 - resumed.num_timesteps, reset_num_timesteps=False)
    assert np.array_equal(resumed.q, straight.q) and resumed.num_timesteps == 20_000
    (tmp_path / "cut.pt").write_bytes(path.read_bytes()[:300])
    with pytest.raises(ValueError, match="truncated"):
        TabularQAgent.load(tmp_path / "cut.pt")


@pytest.mark.slow
def test_tabular_q_stopped_by_sigterm_resumes_as_a_straight_run(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    import numpy as np

    from vistask.agents import TabularQAgent

    path, total = tmp_path / "q.pt", 100_000
    child = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import gymnasium as gym, sys\n"
            "from vistask.agents import TabularQAgent\n"
            "from vistask.cli import interrupt_on_sigterm\n"
            "interrupt_on_sigterm()\n"
            "TabularQAgent(gym.make('FrozenLake-v1'), seed=3).learn("
            f"{total}, checkpoint=sys.argv[1], checkpoint_every=5_000)\n",
            str(path),
        ],
        stderr=subprocess.PIPE,
        text=True,
    )
    while not path.exists() and child.poll() is None:
        time.sleep(0.05)
    child.send_signal(signal.SIGTERM)
    _, err = child.communicate(timeout=120)
    assert child.returncode != 0 and "KeyboardInterrupt" in err  # stopped, not finished
    resumed = TabularQAgent.load(path, _frozen_lake())
    assert resumed.num_timesteps < total
    resumed.learn(total - resumed.num_timesteps, reset_num_timesteps=False)
    straight = TabularQAgent(_frozen_lake(), seed=3).learn(total)
    assert np.array_equal(resumed.q, straight.q)


@pytest.mark.parametrize("agent_name", ["RLVCAgent", "RLJCAgent"])
def test_a_visual_agent_resumes_from_its_checkpoint_as_a_straight_run(agent_name, tmp_path):
    import gymnasium as gym
    import numpy as np
    from stable_baselines3.common.callbacks import BaseCallback

    import vistask.agents as agents
    import vistask.envs  # noqa: F401

    cls = getattr(agents, agent_name)
    env_id = (
        "vistask/VisualMaze-v0" if agent_name == "RLVCAgent" else "vistask/VisualMazeContinuous-v0"
    )
    small = {"obstacles": ((0.45, 0.0, 0.55, 0.6),), "exits": ((0.8, 0.0, 1.0, 0.2),), "step": 0.2}

    def make():
        return cls(gym.make(env_id, **small), n_words=256, databases=3, n_envs=16, seed=4)

    total = 1500  # three databases of 500
    straight = make().learn(total)

    class StopInTheLastDatabase(BaseCallback):
        def _on_step(self) -> bool:
            if self.model.num_timesteps == total:
                raise KeyboardInterrupt
            return True

    path = tmp_path / "agent.pt"
    with pytest.raises(KeyboardInterrupt):
        make().learn(total, callback=StopInTheLastDatabase(), checkpoint=path)
    resumed = cls.load(path, gym.make(env_id, **small))
    assert resumed.num_timesteps == 1000 and len(resumed.database) == 1000
    resumed.learn(total - resumed.num_timesteps, reset_num_timesteps=False)
    assert resumed.num_timesteps == total
    a, b = straight.learner.state_dict(), resumed.learner.state_dict()
    assert len(a["history"]) == len(b["history"])
    images = np.stack(
        [straight.env.unwrapped.percept_at(p) for p in np.random.default_rng(0).random((64, 2))]
    )
    assert np.array_equal(straight.predict(images)[0], resumed.predict(images)[0])
    assert torch.equal(straight.database.presence.dense(), resumed.database.presence.dense())


@pytest.mark.slow
def test_train_rlvc_stopped_by_sigterm_resumes_with_the_results_of_a_straight_run(tmp_path):
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    from vistask.experiments.train_rlvc import train_rlvc

    small = '{"obstacles": [[0.45, 0.0, 0.55, 0.6]], "exits": [[0.8, 0.0, 1.0, 0.2]], "step": 0.2}'
    straight = tmp_path / "straight"
    train_rlvc(
        env_kwargs=json.loads(small), interactions=3000, seed=2, out=straight, progress=False
    )

    # The same settings through the script, stopped by SIGTERM after its first database.
    script = str(Path(__file__).resolve().parents[1] / "scripts" / "train_rlvc.py")
    args = ["--interactions", "3000", "--env-kwargs", small, "--no-progress", "--seed", "2"]
    stopped = tmp_path / "stopped"
    child = subprocess.Popen(
        [sys.executable, script, *args, "--out", str(stopped)],
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
    )
    while not (stopped / "checkpoint.pt").exists() and child.poll() is None:
        time.sleep(0.05)
    child.send_signal(signal.SIGTERM)
    _, err = child.communicate(timeout=300)
    # One line says where the run is and how to go on, not a traceback.
    go_on = f"train_rlvc.py: stopped by SIGTERM; {stopped} keeps what it finished: go on with "
    assert child.returncode == 130 and err.strip().splitlines() == [
        go_on + f"python scripts/train_rlvc.py --resume {stopped}"
    ]
    assert not (stopped / "summary.json").exists()
    subprocess.run(
        [sys.executable, script, "--resume", str(stopped), "--no-progress"],
        check=True,
        capture_output=True,
    )
    a = json.loads((straight / "summary.json").read_text())
    b = json.loads((stopped / "summary.json").read_text())
    for key in (
        "rlvc_return",
        "stages",
        "classes",
        "selected_features",
        "interactions",
        "evaluations",
    ):
        assert a[key] == b[key], key
    assert not (stopped / "checkpoint.pt").exists()


class _StandInTrials:
    """A ``TrialRunner`` without a simulator: the cube 4 cm wide at a seeded place on the
    table; a grasp lifts it when it closes within 1.5 cm of the cube's centre. It raises
    ``KeyboardInterrupt`` at its ``stop_at``-th trial, as Ctrl-C would."""

    num_envs, workspace = 1, None
    object_bounds = np.array([[-0.021] * 3, [0.021] * 3])

    def __init__(self, stop_at: int | None = None) -> None:
        self.stop_at, self.executed = stop_at, 0

    def reset(self, seeds) -> torch.Tensor:
        from vistask.se3 import identity_poses, make_poses

        g = torch.Generator().manual_seed(int(seeds[0]))
        t = torch.cat([0.1 * torch.rand(1, 2, generator=g), torch.full((1, 1), 0.82)], 1)
        self.poses = make_poses(t, identity_poses(1)[:, 3:])
        return self.poses

    def execute(self, grasps: torch.Tensor):
        from vistask.se3 import relative

        self.executed += 1
        if self.executed == self.stop_at:
            raise KeyboardInterrupt
        local = relative(self.poses, grasps)
        return local[:, :3].norm(dim=1) < 0.015, {}

    def close(self) -> None:
        pass


def test_grasp_learning_stopped_inside_a_cycle_resumes_bit_for_bit(tmp_path, monkeypatch):
    pytest.importorskip("robosuite")
    from vistask.envs.tabletop import object_patches
    from vistask.experiments.grasps import GraspExperiment
    from vistask.grasp import GraspLearner
    from vistask.objects import ObjectModel

    model = ObjectModel.learn(object_patches("cube", 2, ("front", "top"), 96), name="cube")
    # 5 held-out placements, sampled and best of 10, before and after 3 cycles of 10 trials;
    # the second run is stopped at the 5th trial of the second cycle.
    runners = [_StandInTrials(), _StandInTrials(stop_at=10 + 10 + 5), _StandInTrials()]
    made = iter(runners)
    monkeypatch.setattr(GraspExperiment, "_runner", lambda self, kind, model: next(made))
    experiment = GraspExperiment(
        objects=("cube",), hypothesis="demo", cycles=3, trials_per_cycle=10, eval_trials=5
    )
    straight = experiment.learn_object("cube", model, tmp_path / "straight")
    stopped = tmp_path / "stopped"
    with pytest.raises(KeyboardInterrupt):
        experiment.learn_object("cube", model, stopped)
    assert (stopped / "checkpoint.pt").exists() and not (stopped / "learner.pt").exists()
    resumed = experiment.learn_object("cube", model, stopped)

    assert straight["empirical_success"] > 0 and straight["trials"] == 30
    for key in ("hypothesis_success", "empirical_success", "best_of_10_success", "trials"):
        assert resumed[key] == straight[key], key
    # Only the last two cycles and the learned density's evaluation ran again.
    assert runners[0].executed == 50 and runners[2].executed == 20 + 10
    # With no ranking validated, the best of 10 executes the plain draws, placement by placement.
    records = [json.loads(line) for line in (tmp_path / "straight" / "trials.jsonl").open()]
    grasps = lambda phase: [r["grasp"] for r in records if r["phase"] == phase]  # noqa: E731
    assert straight["ranking_width"] is None
    assert grasps("empirical_best_of_10") == grasps("empirical") != []
    assert (stopped / "trials.jsonl").read_text() == (
        tmp_path / "straight" / "trials.jsonl"
    ).read_text()
    a = GraspLearner.load(tmp_path / "straight" / "learner.pt")
    b = GraspLearner.load(stopped / "learner.pt")
    assert torch.equal(a.trials.grasps, b.trials.grasps)
    assert torch.equal(a.empirical.weights, b.empirical.weights)


@pytest.mark.slow
def test_learn_grasps_stopped_by_sigterm_resumes_bit_for_bit(tmp_path):
    pytest.importorskip("robosuite")
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    from vistask.experiments.grasps import GraspExperiment
    from vistask.grasp import GraspLearner

    tiny = {"objects": ("cube",), "hypothesis": "demo", "cycles": 2, "trials_per_cycle": 2}
    tiny |= {"eval_trials": 1, "num_envs": 1, "pose_source": "true", "n_distractors": 0}
    straight = GraspExperiment(**tiny).run(tmp_path / "straight", pictures=0)

    # The same settings through the script, stopped by SIGTERM after its first cycle.
    script = str(Path(__file__).resolve().parents[1] / "scripts" / "learn_grasps.py")
    args = ["--objects", "cube", "--hypothesis", "demo", "--cycles", "2", "--trials-per-cycle", "2"]
    args += ["--eval-trials", "1", "--num-envs", "1", "--pose-source", "true", "--distractors", "0"]
    stopped = tmp_path / "stopped"
    child = subprocess.Popen(
        [sys.executable, script, *args, "--out", str(stopped)],
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
    )
    while not (stopped / "cube" / "checkpoint.pt").exists() and child.poll() is None:
        time.sleep(0.05)
    child.send_signal(signal.SIGTERM)
    _, err = child.communicate(timeout=300)
    assert child.returncode == 130 and f"--resume {stopped}" in err, err  # stopped, not finished
    assert not (stopped / "summary.json").exists()
    written = (stopped / "cube" / "hypothesis.pt").stat().st_mtime_ns
    resumed = GraspExperiment(**tiny).run(stopped, pictures=0)["objects"]["cube"]
    # Resumed from the checkpoint: a start from scratch would have drawn the hypothesis again.
    assert (stopped / "cube" / "hypothesis.pt").stat().st_mtime_ns == written

    for key in ("hypothesis_success", "empirical_success", "best_of_10_success", "trials"):
        assert resumed[key] == straight["objects"]["cube"][key], key
    cycles = [c["successes"] for c in straight["objects"]["cube"]["cycles"]]
    assert [c["successes"] for c in resumed["cycles"]] == cycles
    a = GraspLearner.load(tmp_path / "straight" / "cube" / "learner.pt")
    b = GraspLearner.load(stopped / "cube" / "learner.pt")
    assert torch.equal(a.trials.grasps, b.trials.grasps)
    assert torch.equal(a.trials.success, b.trials.success)
    assert torch.equal(a.empirical.weights, b.empirical.weights)
    # Other settings in the same folder are refused rather than mixed in.
    with pytest.raises(ValueError, match=r"other settings \(cycles 2 there, 3 now\)"):
        GraspExperiment(**{**tiny, "cycles": 3}).run(stopped)
    assert json.loads((stopped / "config.json").read_text())["cycles"] == 2


def test_a_resumed_train_rlvc_keeps_the_evaluations_and_seconds_of_its_stopped_part(
    tmp_path, monkeypatch
):
    import functools

    from vistask.experiments import train_rlvc as module

    monkeypatch.setattr(module, "EvaluateEvery", functools.partial(module.EvaluateEvery, every=3))
    run = dict(
        env_kwargs={"obstacles": [[0.45, 0.0, 0.55, 0.6]], "step": 0.2},
        interactions=3000,
        seed=2,
        progress=False,
        pictures=False,
    )
    straight = module.train_rlvc(**run, out=tmp_path / "straight")

    # Stopped as the second database starts: after the first database's checkpoint.
    starts = []

    def stop_at_the_second_database(self):
        starts.append(1)
        if len(starts) == 2:
            raise KeyboardInterrupt
        original(self)

    original = module.RunClock._on_rollout_start
    with monkeypatch.context() as patch:
        patch.setattr(module.RunClock, "_on_rollout_start", stop_at_the_second_database)
        with pytest.raises(KeyboardInterrupt):
            module.train_rlvc(**run, out=tmp_path / "stopped")
    assert (tmp_path / "stopped" / "checkpoint.pt").exists()
    before = json.loads((tmp_path / "stopped" / "elapsed.json").read_text())["seconds"]
    resumed = module.train_rlvc(**run, out=tmp_path / "stopped")

    assert straight["evaluations"] and resumed["evaluations"] == straight["evaluations"]
    assert resumed["evaluations"][0][0] == 3  # stages counted over the whole run
    assert resumed["rlvc_return"] == straight["rlvc_return"]
    assert resumed["learn_seconds"] > before > 0
    assert not (tmp_path / "stopped" / "elapsed.json").exists()

    # Stopped after learning, while the learned agent is saved: it goes on from the last
    # database's checkpoint, not from the start, and ends as the run straight through.
    def stop_while_saving(self, path):
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(module.RLVCAgent, "save", stop_while_saving)
        with pytest.raises(KeyboardInterrupt):
            module.train_rlvc(**run, out=tmp_path / "late")
    assert (tmp_path / "late" / "checkpoint.pt").exists()
    late = module.train_rlvc(**run, out=tmp_path / "late")
    assert late["evaluations"] == straight["evaluations"]
    assert late["rlvc_return"] == straight["rlvc_return"] and late["stages"] == straight["stages"]
    assert not (tmp_path / "late" / "checkpoint.pt").exists()


def test_a_run_folder_in_use_is_refused_and_a_stop_says_how_to_go_on(tmp_path):
    import signal
    import subprocess
    import sys

    script = tmp_path / "hold.py"
    # A shell that starts the suite in the background leaves SIGINT ignored in its children.
    script.write_text(
        "import signal, sys, time\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "from vistask.cli import run_main\n"
        "from vistask.runs import run_dir\n"
        "def main():\n"
        "    run_dir('hold', sys.argv[1])\n"
        "    print('started', flush=True)\n"
        "    time.sleep(120)\n"
        "run_main(main, go_on='the same command with --out {out}')\n"
    )
    out = tmp_path / "run"

    def start() -> subprocess.Popen:
        run = subprocess.Popen(
            [sys.executable, str(script), str(out)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert run.stdout.readline() == "started\n"
        return run

    first = start()
    second = subprocess.run(
        [sys.executable, str(script), str(out)], capture_output=True, text=True, timeout=120
    )
    assert second.returncode == 2
    assert f"{out} is in use by another run (process {first.pid})" in second.stderr
    first.send_signal(signal.SIGINT)
    _, err = first.communicate(timeout=60)
    assert first.returncode == 130 and err.strip() == (
        f"hold.py: stopped by Ctrl-C; {out} keeps what it finished: go on with the same "
        f"command with --out {out}"
    )
    # A run killed with nothing to catch frees its folder too.
    third = start()
    third.kill()
    third.wait()
    fourth = start()
    fourth.kill()
    fourth.wait()
