"""compare_compaction end to end on a small maze run; the test sets of the oracle tasks."""

import json

import numpy as np
import pytest

from vistask.agents import RLVCAgent
from vistask.experiments.compare_compaction import compare_compaction
from vistask.experiments.tasks import task_for


def test_small_comparison_writes_both_methods_and_the_sawtooth(tmp_path):
    summary = compare_compaction(
        interactions=1500, seeds=[0], contrast_threshold=0.01, out=tmp_path, progress=False
    )
    saved = json.loads((tmp_path / "summary.json").read_text())
    for method in ("tree", "bdd"):
        for key in (
            "classes",
            "selected_features",
            "return_ratio",
            "test_error",
            "seconds",
            "return_ratio_nearest_seen",
            "test_error_nearest_seen",
        ):
            assert saved[method][key] == pytest.approx(summary[method][key])
        assert 0 <= saved[method]["test_error"] <= 1
    assert saved["bdd"]["classes"] < saved["tree"]["classes"]
    assert (tmp_path / "sawtooth.png").stat().st_size > 0
    assert saved["hyperparams"] == {"contrast_threshold": 0.01}  # the maze has no entry
    for method in ("tree", "bdd"):
        assert RLVCAgent.load(tmp_path / f"{method}-seed0.pt").contrast_threshold == 0.01

    # Run again on the same folder: every run is finished, so nothing learns again.
    (tmp_path / "tree-seed0.pt").unlink()
    again = compare_compaction(
        interactions=1500, seeds=[0], contrast_threshold=0.01, out=tmp_path, progress=False
    )
    assert not (tmp_path / "tree-seed0.pt").exists()
    assert len((tmp_path / "runs.jsonl").read_text().splitlines()) == 2
    for method in ("tree", "bdd"):
        assert again[method]["runs"] == summary[method]["runs"]
    with pytest.raises(ValueError, match="other settings"):
        compare_compaction(interactions=1000, seeds=[0], out=tmp_path, progress=False)


def test_maze_test_set_marks_the_oracles_action_optimal():
    task = task_for("vistask/VisualMaze-v0")
    percepts, optimal = task.test_set(grid=10)
    assert percepts.shape[1:] == (64, 64, 3) and optimal.shape == (len(percepts), 4)
    assert optimal.any(axis=1).all()
    with pytest.raises(ValueError, match="oracle test set"):
        compare_compaction("vistask/VisualMountainCar-v0", interactions=100)
    with pytest.raises(ValueError, match="methods must be among"):
        compare_compaction(methods=["forest"], interactions=100)
    assert np.isin(optimal.sum(axis=1), [1, 2, 3, 4]).all()
