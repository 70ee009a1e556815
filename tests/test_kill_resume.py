"""Runs killed with SIGKILL (nothing to catch, files cut wherever they were) at several moments,
then resumed as the README says, end with the summary of a run straight through."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MOMENTS = (0.15, 0.45, 0.75, 0.95)  # shares of the straight run's seconds
SMALL_MAZE = '{"obstacles": [[0.45, 0.0, 0.55, 0.6]], "exits": [[0.8, 0.0, 1.0, 0.2]], "step": 0.2}'

RUNS = {
    "rlvc": (
        "train_rlvc.py",
        ["--interactions", "3000", "--env-kwargs", SMALL_MAZE, "--seed", "2", "--no-progress"],
        ["--no-progress"],
        ("rlvc_return", "stages", "classes", "selected_features", "interactions", "evaluations"),
    ),
    "rljc": (
        "train_rlvc.py",
        [
            "--env",
            "vistask/VisualMazeContinuous-v0",
            "--interactions",
            "4000",
            "--seed",
            "1",
            "--env-kwargs",
            SMALL_MAZE,
            "--no-progress",
        ],
        ["--no-progress"],
        ("rljc_return", "stages", "joint_classes", "interactions", "evaluations"),
    ),
    "grasps": (
        "learn_grasps.py",
        [
            "--objects",
            "cube",
            "--hypothesis",
            "demo",
            "--cycles",
            "2",
            "--trials-per-cycle",
            "2",
            "--eval-trials",
            "1",
            "--num-envs",
            "1",
            "--pose-source",
            "true",
            "--distractors",
            "0",
        ],
        [],
        ("objects",),
    ),
}


def _run(script: str, args: list[str], out: Path, kill_after: float | None = None) -> int:
    """Run ``script`` into ``out``; SIGKILL it after ``kill_after`` seconds. Returns its status."""
    env = {**os.environ, "MUJOCO_GL": "egl"}
    child = subprocess.Popen(
        [sys.executable, str(ROOT / "scripts" / script), *args, "--out", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    if kill_after is None:
        return child.wait(timeout=900)
    try:
        return child.wait(timeout=kill_after)
    except subprocess.TimeoutExpired:
        child.send_signal(signal.SIGKILL)
        return child.wait()


def _resume(script: str, args: list[str], resume: list[str], out: Path) -> None:
    """Go on as a user would: ``--resume`` when the run left its settings, else start again."""
    if (out / "summary.json").exists():
        return
    started = (out / "settings.json").exists() or (out / "config.json").exists()
    if started:
        command = [sys.executable, str(ROOT / "scripts" / script), "--resume", str(out), *resume]
        subprocess.run(
            command,
            check=True,
            capture_output=True,
            timeout=900,
            env={**os.environ, "MUJOCO_GL": "egl"},
        )
    else:
        assert _run(script, args, out) == 0


@pytest.mark.slow
@pytest.mark.parametrize("name", list(RUNS))
def test_a_run_killed_at_any_moment_resumes_to_the_summary_of_a_straight_run(name, tmp_path):
    if name == "grasps":
        pytest.importorskip("robosuite")
    script, args, resume, keys = RUNS[name]
    start = time.perf_counter()
    assert _run(script, args, tmp_path / "straight") == 0
    seconds = time.perf_counter() - start
    straight = json.loads((tmp_path / "straight" / "summary.json").read_text())
    for moment in MOMENTS:
        out = tmp_path / f"killed-{moment}"
        _run(script, args, out, kill_after=moment * seconds)
        _resume(script, args, resume, out)
        resumed = json.loads((out / "summary.json").read_text())
        for key in keys:
            if name == "grasps":
                a, b = straight[key]["cube"], resumed[key]["cube"]
                for k in ("hypothesis_success", "empirical_success", "trials", "cycles"):
                    sa = [c["successes"] for c in a[k]] if k == "cycles" else a[k]
                    sb = [c["successes"] for c in b[k]] if k == "cycles" else b[k]
                    assert sa == sb, (moment, k)
            else:
                assert resumed[key] == straight[key], (moment, key)
