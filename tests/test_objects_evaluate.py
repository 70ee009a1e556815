"""Benchmark bookkeeping: summaries, the Markdown table and summary.json (no rendering)."""

import json
import math

import pytest

from vistask.experiments.pose import PoseBenchmark
from vistask.experiments.pose_summary import markdown_table, summarize, write_results


def _record(method: str, cond: str, kind: str, t: float, r: float, s: float) -> dict:
    record = {
        "method": method,
        "condition": cond,
        "object": kind,
        "translation_error_m": t,
        "rotation_error_deg": r,
        "success": t < 0.02 and r < 15.0,
        "seconds": s,
        "visible_fraction": [0.4, 0.5] if cond == "clutter" else [1.0],
    }
    if kind == "bread":  # scored again up to its shape's half turn
        record["success_up_to_shape"] = t < 0.02
    return record


@pytest.fixture
def records() -> list[dict]:
    return [
        _record("nbp", "clutter", "milk", 0.001, 1.0, 0.2),
        _record("nbp", "clutter", "milk", 0.05, 3.0, 0.4),
        _record("nbp", "clutter", "box", 0.002, 2.0, 0.3),
        _record("nbp", "clutter", "bread", 0.003, 178.0, 0.3),
        _record("open3d", "one_camera", "box", math.inf, 180.0, 0.1),
    ]


def test_summary_figures_per_method_condition_and_object(records: list[dict]) -> None:
    summary = summarize(records)
    clutter = summary["nbp"]["clutter"]
    assert clutter["success"] == pytest.approx(2 / 4)
    # The 95% Wilson interval of 2 successes in 4, checked against its formula.
    n, p, z = 4, 0.5, 1.959963984540054
    half = z * math.sqrt(p * (1 - p) / n + z**2 / (4 * n**2)) / (1 + z**2 / n)
    centre = (p + z**2 / (2 * n)) / (1 + z**2 / n)
    assert clutter["ci_low"] == pytest.approx(centre - half)
    assert clutter["ci_high"] == pytest.approx(centre + half)
    assert clutter["median_translation_error_m"] == pytest.approx(0.0025)
    assert clutter["seconds_per_scene"] == pytest.approx(0.3)
    assert clutter["mean_visible_fraction"] == pytest.approx(0.5)
    assert clutter["per_object"]["milk"]["success"] == 0.5
    assert clutter["per_object"]["bread"]["success"] == 0.0
    assert clutter["up_to_shape"]["bread"]["success"] == 1.0
    assert set(clutter["up_to_shape"]) == {"bread"}
    assert summary["open3d"]["one_camera"]["success"] == 0.0
    assert "clutter" not in summary["open3d"]


def test_results_files_are_valid_json_and_markdown(records: list[dict], tmp_path) -> None:
    summary = summarize(records)
    table = write_results(summary, tmp_path)
    loaded = json.loads((tmp_path / "summary.json").read_text())
    assert loaded["open3d"]["one_camera"]["median_translation_error_m"] is None  # inf -> null
    text = (tmp_path / "results.md").read_text()
    assert text.count("| nbp | clutter |") == 5  # milk, box, bread, bread up to shape, all
    assert "| nbp | clutter | bread (shape only) | 1 | 100% (" in text
    assert "| open3d | one_camera | box | 1 | 0% (0-79) | none found | 180.0 |" in text
    assert table == markdown_table(summary)


def test_bad_bench_configs_are_clear_errors() -> None:
    with pytest.raises(ValueError, match="unknown conditions"):
        PoseBenchmark(conditions=("foggy",))
    with pytest.raises(ValueError, match="methods"):
        PoseBenchmark(methods=("icp",))
    with pytest.raises(ValueError, match="n_scenes must be >= 1, got 0"):
        PoseBenchmark(n_scenes=0)


@pytest.mark.slow
def test_scenes_spread_over_two_workers_give_the_records_of_one_process(tmp_path) -> None:
    import os

    import torch

    os.environ.setdefault("MUJOCO_GL", "egl")
    bench = PoseBenchmark(
        objects=("box",), n_scenes=2, conditions=("one_camera",), image_size=96, n_rotations=2
    )
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as each worker runs
    try:
        alone = bench.run(tmp_path / "alone", log=None, workers=1, pictures=1)
    finally:
        torch.set_num_threads(threads)
    spread = bench.run(tmp_path / "spread", log=None, workers=2, pictures=1)

    def key(summary):
        return [(r["method"], r["seed"], r["pose"]) for r in summary["records"]]

    assert key(spread) == key(alone) and len(alone["records"]) == 2 * 3
    assert spread["failed"] == []
    pictures = sorted(p.name for p in (tmp_path / "spread" / "pictures").glob("*.png"))
    seed = bench.scene_seed("box", "one_camera", 0)
    assert pictures == [f"box_one_camera_{seed}_{m}.png" for m in sorted(bench.methods)]
