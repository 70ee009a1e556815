"""Every example under examples/ runs to its end (on a small budget), so that none rots."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
# Each example with a small budget as its argument, and a line its output must show.
RUNS = {
    "rlvc_own_env.py": (["4000"], "reached the right end: True"),
    "compare_sb3.py": (["1500"], "PPO: mean return"),
    "se3_densities.py": ([], "product: 500 particles"),
    "grasp_own_object.py": (["4"], "learned density:"),
}


def test_every_example_is_run_here() -> None:
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == sorted(RUNS)


@pytest.mark.parametrize("name", sorted(RUNS))
def test_example_runs(name: str, tmp_path: Path) -> None:
    args, expected = RUNS[name]
    env = {**os.environ, "MUJOCO_GL": "egl", "PYTHONWARNINGS": "ignore"}
    result = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *args],
        cwd=tmp_path,  # examples write their files where they run
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert expected in result.stdout, result.stdout[-3000:]
