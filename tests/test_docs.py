"""The documentation site builds from the sources with warnings as errors (`make docs`)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"


def test_the_site_builds_without_warnings(tmp_path: Path) -> None:
    command = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html"]
    result = subprocess.run(
        [*command, str(DOCS), str(tmp_path / "html")],
        env={**os.environ, "MUJOCO_GL": "egl"},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-5000:]
    html = tmp_path / "html"
    # autodoc found the public classes and their methods, inherited ones included
    for page, name in [
        ("agents", "vistask.agents.RLVCAgent.learn"),
        ("agents", "vistask.agents.RLVCAgent.predict"),
        ("rlvc", "vistask.rlvc.RLVC.learn"),
        ("se3", "vistask.se3.SE3KDE.sample"),
        ("grasp", "vistask.grasp.GraspLearner.run_cycle"),
        ("objects", "vistask.objects.NBP.infer"),
    ]:
        assert f'id="{name}"' in (html / "api" / f"{page}.html").read_text(), name
    for guide in ("own_env", "own_object", "ray_cluster", "tensorboard"):
        assert (html / "guides" / f"{guide}.html").exists()
