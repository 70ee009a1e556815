"""rliable's statistics as the comparisons use them, checked against direct computation."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import psutil
import pytest

from vistask.experiments import statistics
from vistask.parallel import map_runs


def _iqm(column: np.ndarray) -> float:
    """The mean of the middle half of sorted values (sizes divisible by 4)."""
    x = np.sort(column)
    n = len(x) // 4
    return float(x[n : len(x) - n].mean())


def test_iqm_curves_match_the_middle_half_and_cover_it():
    rng = np.random.default_rng(0)
    scores = {"a": rng.normal(size=(8, 3)), "b": rng.normal(5.0, 1.0, size=(8, 3))}
    curves = statistics.iqm_curves(scores, seed=1)
    for name, runs in scores.items():
        center, low, high = curves[name]
        assert center == pytest.approx([_iqm(runs[:, j]) for j in range(3)])
        assert np.all(low <= center) and np.all(center <= high) and np.all(low < high)
    again = statistics.iqm_curves(scores, seed=1)
    assert all(np.array_equal(again[k][1], curves[k][1]) for k in scores)
    state = np.random.get_state()[1].copy()
    statistics.iqm_curves(scores, seed=2)
    assert np.array_equal(np.random.get_state()[1], state)  # the global generator is restored


def test_one_seed_has_no_interval():
    center, low, high = statistics.iqm_curves({"a": np.array([[1.0, 2.0]])})["a"]
    assert np.array_equal(center, low) and np.array_equal(center, high)


def test_profiles_and_improvement_count_runs():
    scores = {"x": np.array([0.1, 0.5, 0.9, 1.0]), "y": np.array([0.0, 0.2, 0.3, 0.4])}
    profiles = statistics.performance_profiles(scores, [0.0, 0.45, 0.95])
    assert profiles["x"][0] == pytest.approx([1.0, 0.75, 0.25])
    assert profiles["y"][0] == pytest.approx([0.75, 0.0, 0.0])
    better = sum(a > b for a in scores["x"] for b in scores["y"]) / 16
    p, low, high = statistics.improvement_probabilities(scores, [("x", "y")])["x,y"]
    assert p == pytest.approx(better) and low <= p <= high
    metrics = statistics.aggregate_metrics(scores)["x"]
    assert metrics["Mean"][0] == pytest.approx(0.625)
    assert metrics["Optimality gap"][0] == pytest.approx(1 - 0.625)


def test_map_runs_reports_failures_and_finishes_the_rest_wherever_it_runs():
    for workers, address in ((1, None), (2, None), (2, "local")):  # process, processes, Ray
        outcomes = map_runs(json.loads, ["4", "[1,", "9"], workers, address)
        by_item = {o.item: o for o in outcomes}
        assert by_item["4"].result == 4 and by_item["9"].result == 9
        assert not by_item["[1,"].ok and "JSONDecodeError" in by_item["[1,"].error


def test_a_cluster_that_does_not_answer_is_refused_at_once(monkeypatch):
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:1")  # as a script's --address is checked
    with pytest.raises(ValueError, match=r"RAY_ADDRESS\): cannot reach 127\.0\.0\.1:1"):
        map_runs(json.loads, ["4"], 2)


@pytest.mark.parametrize("runs", [2, 3, 5, 8, 11])
def test_numpy_statistics_equal_rliables(runs):
    from rliable import metrics

    rng = np.random.default_rng(runs)
    x = rng.normal(size=(runs, 1)).round(1)  # rounded: ties between runs occur
    y = rng.normal(size=(runs + 1, 1)).round(1)
    assert statistics.trimmed_mean(x) == pytest.approx(metrics.aggregate_iqm(x))
    assert statistics.improvement_probability(x, y) == pytest.approx(
        metrics.probability_of_improvement(x, y)
    )
    columns = rng.normal(size=(runs, 4))
    assert statistics.trimmed_mean(columns, axis=0) == pytest.approx(
        [metrics.aggregate_iqm(columns[:, j]) for j in range(4)]
    )


def test_a_run_that_exits_or_kills_its_worker_process_fails_alone():
    # The worker process takes the first run of the list; exec runs each item's code.
    for first in ("import sys; sys.exit(3)", "import os; os._exit(3)"):
        outcomes = map_runs(exec, [first, "x = 1", "y = 2", "z = 3"], workers=2)
        by_item = {o.item: o for o in outcomes}
        assert len(outcomes) == 4 and not by_item[first].ok
        assert all(by_item[code].ok for code in ("x = 1", "y = 2", "z = 3"))


def test_an_interrupted_map_stops_the_runs_of_its_worker_processes():
    def interrupt(outcome):
        raise KeyboardInterrupt

    start = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        # The worker process has the first run, of two minutes; this process has the second
        # and is interrupted as it ends.
        map_runs(time.sleep, [120, 10], workers=2, on_outcome=interrupt)
    assert time.perf_counter() - start < 60


def test_a_script_without_a_main_guard_stops_in_its_worker_with_what_to_do(tmp_path):
    script = tmp_path / "unguarded.py"
    script.write_text(
        "from vistask.parallel import map_runs\n"
        "print(sorted(o.ok for o in map_runs(abs, [1, -2, 3], workers=2)))\n"
    )
    done = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=300
    )
    # The worker process stops as it imports the script again, instead of running it whole;
    # its run fails and this process runs the others.
    assert "imports the main script again" in done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[False, True, True]"


def test_worker_processes_end_when_the_process_that_started_them_is_killed(tmp_path):
    script = tmp_path / "killed.py"
    script.write_text(
        "import os, time\n"
        "from vistask.parallel import map_runs\n"
        "def run(seconds):\n"
        f"    open({str(tmp_path)!r} + f'/{{os.getpid()}}.pid', 'w').close()\n"
        "    time.sleep(seconds)\n"
        "if __name__ == '__main__':\n"
        "    map_runs(run, [300, 300, 300], workers=3)\n"
    )
    child = subprocess.Popen([sys.executable, str(script)])
    deadline = time.monotonic() + 120
    while len(list(tmp_path.glob("*.pid"))) < 3 and time.monotonic() < deadline:
        time.sleep(0.2)
    workers = [int(p.stem) for p in tmp_path.glob("*.pid") if int(p.stem) != child.pid]
    assert len(workers) == 2
    child.kill()  # SIGKILL: nothing in the process can catch it
    child.wait()
    deadline = time.monotonic() + 30
    while any(psutil.pid_exists(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(psutil.pid_exists(pid) for pid in workers)


def test_a_failed_runs_line_names_its_exception_even_when_its_message_has_several_lines():
    from vistask.parallel import last_line

    sb3 = (
        'Traceback (most recent call last):\n  File "run.py", line 3, in <module>\n'
        "AssertionError: You should use NatureCNN only with images not with Box(0, 255, (48,))\n"
        "If you are using a custom environment,\nplease check it using our env checker:\n"
        "https://stable-baselines3.readthedocs.io/en/master/guide/custom_env.html\n"
    )
    assert last_line(sb3).startswith("AssertionError: You should use NatureCNN")
    assert last_line("Traceback:\n  File x\nValueError: bad\nhint: do x") == "ValueError: bad"
    assert last_line("Traceback:\n  File x\nKeyboardInterrupt\n") == "KeyboardInterrupt"


def test_a_local_ray_keeps_the_scripts_sigterm_handler():
    import signal

    from vistask.parallel import ray_session

    def stop(signum, frame):  # as cli.run_main's: a stop that says how to go on
        raise KeyboardInterrupt

    before = signal.signal(signal.SIGTERM, stop)
    try:
        with ray_session(1, "local"):
            assert signal.getsignal(signal.SIGTERM) is stop  # not Ray's, which exits at once
    finally:
        signal.signal(signal.SIGTERM, before)
