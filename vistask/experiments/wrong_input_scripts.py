"""The wrong inputs over the scripts of ``scripts/sweep_wrong_inputs.py``: bad numbers and
choices, env ids and ``--env-kwargs``, devices and clusters, and run folders misused (resumed
with other flags, another script's, garbage settings), each run in a folder of its own.

Example:
    >>> cases = script_cases()
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from vistask.experiments.wrong_inputs import Case

MAZE = "vistask/VisualMaze-v0"


def _write(name: str, text: str) -> Callable[[Path], None]:
    def setup(folder: Path) -> None:
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)

    return setup


def script_cases() -> list[Case]:
    """The cases over the scripts, each run in a folder of its own."""
    cases = []

    def add(what: str, argv: list[str], *names: str, setup=None) -> None:
        cases.append(Case("scripts", what, argv=argv, names=names, setup=setup))

    numbers = {
        "train_rlvc.py": {
            "--interactions": ("0", "1.5", "ten"),
            "--seed": ("-1", "x"),
            "--hyperparams": ("compounds", "=1"),
        },
        "compare_baselines.py": {
            "--seeds": ("0",),
            "--seed0": ("-2",),
            "--eval-starts": ("0",),
            "--workers": ("0",),
        },
        "compare_compaction.py": {
            "--seeds": ("-3",),
            "--interactions": ("0",),
            "--tolerance": ("-0.1", "2"),
        },
        "learn_grasps.py": {
            "--distractors": ("9",),
            "--tip-probability": ("1.5",),
            "--cycles": ("-1", "0"),
            "--eval-trials": ("0",),
            "--c-rel": ("nan", "-1"),
            "--reliability": ("-1",),
        },
        "bench_features.py": {"--percepts": ("0",), "--words": ("1",), "--threads": ("0",)},
        "bench_maze_layouts.py": {"--layouts": ("-1",), "--workers": ("0",)},
        "bench_parallel.py": {"--workers": ("0",), "--trials": ("-5",)},
        "bench_pose.py": {"--particles": ("0",), "--workers": ("0",), "--pictures": ("-2",)},
        "bench_rljc.py": {"--seeds": ("0",), "--interactions": ("-1",)},
        "bench_se3.py": {"--repeats": ("0",)},
        "estimate_pose.py": {"--scenes": ("0",), "--particles": ("-1",), "--pictures": ("-1",)},
        "show_patches.py": {
            "--distractors": ("9", "-1"),
            "--image-size": ("0",),
            "--threads": ("0",),
        },
    }
    for script, flags in numbers.items():
        for flag, values in flags.items():
            for value in values:
                add(f"{script} {flag} {value}", [script, flag, value], flag)
    for script in (
        "train_rlvc.py",
        "compare_baselines.py",
        "compare_compaction.py",
        "bench_rljc.py",
        "bench_features.py",
    ):
        add(f"{script} --env-kwargs '[1,2]'", [script, "--env-kwargs", "[1,2]"], "--env-kwargs")
        add(f"{script} --env-kwargs unknown key", [script, "--env-kwargs", '{"speed": 3}'], "speed")
        add(
            f"{script} --env-kwargs out of range",
            [script, "--env-kwargs", '{"gamma": 1.5}'],
            "gamma",
        )
    for what, value, name in (
        ("unknown key", "seed=1", "seed"),
        ("compaction out of range", "compaction={tolerance: 1.5}", "tolerance"),
        ("structures of 0", "compaction={structures: 0}", "structures"),
        ("alpha out of range", "alpha=2", "alpha"),
        ("vocabulary_groups of 0", "vocabulary_groups=0", "vocabulary_groups"),
    ):
        add(f"train_rlvc.py --hyperparams {what}", ["train_rlvc.py", "--hyperparams", value], name)
    for script in ("train_rlvc.py", "compare_baselines.py", "compare_compaction.py"):
        add(f"{script} --env NoSuchEnv-v0", [script, "--env", "NoSuchEnv-v0"], "NoSuchEnv")
        add(
            f"{script} --env FrozenLake-v1 (no images)",
            [script, "--env", "FrozenLake-v1"],
            "FrozenLake",
        )
    add(
        "compare_baselines.py --methods nonsense",
        ["compare_baselines.py", "--methods", "dqn2"],
        "--methods",
    )
    add(
        "compare_baselines.py --device gpu", ["compare_baselines.py", "--device", "gpu"], "--device"
    )
    add(
        "compare_baselines.py --device cuda:7",
        ["compare_baselines.py", "--device", "cuda:7"],
        "--device",
    )
    add("bench_pose.py --device tpu", ["bench_pose.py", "--device", "tpu"], "--device")
    add("estimate_pose.py --device cuda:3", ["estimate_pose.py", "--device", "cuda:3"], "--device")
    add(
        "bench_pose.py --address nowhere",
        ["bench_pose.py", "--address", "no.such.host:1"],
        "--address",
    )
    add(
        "bench_maze_layouts.py --address nowhere",
        ["bench_maze_layouts.py", "--address", "no.such.host:1"],
        "--address",
    )
    add("learn_grasps.py --objects teapot", ["learn_grasps.py", "--objects", "teapot"], "teapot")
    add("bench_pose.py --objects teapot", ["bench_pose.py", "--objects", "teapot"], "teapot")
    add("show_patches.py --cameras nowhere", ["show_patches.py", "--cameras", "nowhere"], "nowhere")
    add(
        "estimate_pose.py --condition foggy",
        ["estimate_pose.py", "--condition", "foggy"],
        "--condition",
    )
    add(
        "learn_grasps.py --quick --cycles 5",
        ["learn_grasps.py", "--quick", "--cycles", "5"],
        "--cycles",
    )
    add(
        "compare_baselines.py --threads 4 --workers 2",
        ["compare_baselines.py", "--threads", "4", "--workers", "2"],
        "--threads",
    )
    add(
        "learn_grasps.py --hypothesis magic",
        ["learn_grasps.py", "--hypothesis", "magic"],
        "--hypothesis",
    )
    # Run folders
    resumes = {  # how each script goes on with a stopped run, and the file of its settings
        "train_rlvc.py": ("--resume", "settings.json", "train_rlvc"),
        "learn_grasps.py": ("--resume", "config.json", "learn_grasps"),
        "compare_baselines.py": ("--out", "comparison.json", "compare"),
    }
    for script, (flag, settings, made_by) in resumes.items():
        if flag == "--resume":
            add(f"{script} --resume a missing folder", [script, flag, "nowhere"], "--resume")
        for what, text, named in (
            ("garbage", "{not json", settings),
            ("a list", "[1, 2]", settings),
        ):

            def setup(folder, settings=settings, text=text, made_by=made_by):
                _write("run/run.json", json.dumps({"script": made_by, "commands": []}))(folder)
                _write(f"run/{settings}", text)(folder)

            add(
                f"{script} {flag} a folder with {what} as {settings}",
                [script, flag, "run"],
                named,
                setup=setup,
            )
    add(
        "train_rlvc.py --resume with other flags",
        ["train_rlvc.py", "--resume", "run", "--seed", "4"],
        "--seed",
        setup=_stopped_run("train_rlvc"),
    )
    add(
        "train_rlvc.py --resume with --seed 0 (its default)",
        ["train_rlvc.py", "--resume", "run", "--seed", "0"],
        "--seed",
        setup=_stopped_run("train_rlvc"),
    )
    add(
        "train_rlvc.py --resume with --env-kwargs",
        ["train_rlvc.py", "--resume", "run", "--env-kwargs", '{"layout_seed": 2}'],
        "--env-kwargs",
        setup=_stopped_run("train_rlvc"),
    )
    add(
        "train_rlvc.py --resume a finished run",
        ["train_rlvc.py", "--resume", "run"],
        "finished",
        setup=_finished_run("train_rlvc"),
    )
    add(
        "compare_baselines.py --out a train_rlvc.py folder",
        ["compare_baselines.py", "--out", "run", "--quick"],
        "train_rlvc",
        setup=_finished_run("train_rlvc"),
    )
    add(
        "train_rlvc.py --out a compare_baselines.py folder",
        ["train_rlvc.py", "--out", "run", "--interactions", "500"],
        "compare",
        setup=_finished_run("compare"),
    )
    add(
        "train_rlvc.py --out a file",
        ["train_rlvc.py", "--out", "file.txt"],
        "file.txt",
        setup=_write("file.txt", "x"),
    )
    add(
        "bench_grasp_ranking.py on a folder that is no run",
        ["bench_grasp_ranking.py", "empty"],
        "empty",
        setup=lambda folder: (folder / "empty").mkdir(),
    )
    add(
        "bench_grasp_ranking.py on a missing folder",
        ["bench_grasp_ranking.py", "nowhere"],
        "nowhere",
    )
    add(
        "learn_grasps.py --resume a train_rlvc.py run",
        ["learn_grasps.py", "--resume", "run"],
        "train_rlvc",
        setup=_stopped_run("train_rlvc"),
    )
    return cases


def _stopped_run(script: str) -> Callable[[Path], None]:
    def setup(folder: Path) -> None:
        run = folder / "run"
        run.mkdir(exist_ok=True)
        (run / "run.json").write_text(json.dumps({"script": script, "commands": [[script]]}))
        (run / "settings.json").write_text(
            json.dumps(
                {
                    "env_id": MAZE,
                    "env_kwargs": {},
                    "interactions": 500,
                    "seed": 0,
                    "compounds": False,
                    "compaction": False,
                }
            )
        )

    return setup


def _finished_run(script: str) -> Callable[[Path], None]:
    def setup(folder: Path) -> None:
        _stopped_run(script)(folder)
        (folder / "run" / "summary.json").write_text("{}")

    return setup
