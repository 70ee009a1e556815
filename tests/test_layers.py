"""Layers: the numeric cores import without Gymnasium or OpenCV; import-linter's contracts."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest


def test_importing_se3_loads_neither_gymnasium_nor_opencv():
    code = "import sys, vistask.se3; print('gymnasium' in sys.modules, 'cv2' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["False", "False"]


def test_import_linter_contracts_hold():
    lint_imports = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    if lint_imports is None:
        pytest.skip("import-linter is not installed")
    root = Path(__file__).resolve().parents[1]
    result = subprocess.run([lint_imports], cwd=root, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
