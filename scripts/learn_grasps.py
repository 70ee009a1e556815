"""Learn empirical grasp densities by trial and error on a robosuite Panda (paper 3.5).

    python scripts/learn_grasps.py --out runs/grasps          # 8 objects, 300 trials each
    python scripts/learn_grasps.py --quick                    # a small smoke run
    python scripts/learn_grasps.py --objects can my_mug.xml   # robosuite classes, MJCF files
    python scripts/learn_grasps.py --pose-source true         # ablation: act on true poses
    python scripts/learn_grasps.py --resume runs/grasps       # go on after a stop (Ctrl-C, kill)
    python scripts/learn_grasps.py --address ray://head:10001 --num-envs 32  # on a Ray cluster

Every trial estimates the object's pose from its cameras with NBP and acts on the estimate.
Writes DIR/summary.json, DIR/success.png (held-out success before and after learning, with
95% intervals), TensorBoard scalars, and per object (DIR/<object>/) its object
model, the hypothesis and empirical densities, the learner (all trials), every trial's
record (trials.jsonl: pose error, grasp, outcome, reason of failure), a picture of both
densities and pictures of estimated against true poses.
"""

from __future__ import annotations

import argparse
import inspect
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from vistask.cli import (
    add_address,
    check_resume_alone,
    non_negative_float,
    non_negative_int,
    positive_int,
    probability,
    run_main,
    stopped_run_settings,
)
from vistask.experiments.grasps import HYPOTHESES, POSE_SOURCES, GraspExperiment, format_table
from vistask.runs import run_dir


def main() -> None:
    defaults = {k: p.default for k, p in inspect.signature(GraspExperiment).parameters.items()}
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out", type=Path, default=None, help="output folder (default runs/learn_grasps-<time>)"
    )
    parser.add_argument(
        "--resume",
        type=Path,
        default=None,
        help="a stopped run's folder: go on with its settings, after its last finished cycle",
    )
    parser.add_argument(
        "--objects",
        nargs="+",
        default=list(defaults["objects"]),
        help="robosuite object classes or presets (can, BreadObject) or MJCF files (my.xml)",
    )
    parser.add_argument(
        "--hypothesis",
        choices=HYPOTHESES,
        default=defaults["hypothesis"],
        help="where the first grasps come from: pairs of the object model's patches, or the "
        "scripted teacher's grasps of its bounding box",
    )
    parser.add_argument(
        "--pose-source",
        choices=POSE_SOURCES,
        default=defaults["pose_source"],
        help="act on NBP's estimates from the cameras, or on the simulator's true poses",
    )
    budget = ("cycles", "trials_per_cycle", "eval_trials")  # None: the default, or --quick's
    parser.add_argument("--cycles", type=positive_int, help=f"default {defaults['cycles']}")
    parser.add_argument(
        "--trials-per-cycle", type=positive_int, help=f"default {defaults['trials_per_cycle']}"
    )
    parser.add_argument(
        "--eval-trials", type=positive_int, help=f"default {defaults['eval_trials']}"
    )
    parser.add_argument(
        "--distractors",
        type=non_negative_int,
        default=defaults["n_distractors"],
        help="other objects on the table",
    )
    parser.add_argument(
        "--tip-probability",
        type=probability,
        default=defaults["tip_probability"],
        help="chance that an object lies on a side",
    )
    parser.add_argument(
        "--num-envs",
        type=positive_int,
        default=defaults["num_envs"],
        help="simulators side by side",
    )
    add_address(parser, "the simulators")
    parser.add_argument(
        "--c-rel",
        type=non_negative_float,
        default=defaults["c_rel"],
        help="weight offset c / mean q",
    )
    parser.add_argument(
        "--reliability",
        type=non_negative_float,
        default=defaults["reliability"],
        help="power of the local success rate in a success's weight in the learned density "
        "(learning explores with the rate itself, or this power if lower); 0 is the paper's",
    )
    parser.add_argument(
        "--seed",
        type=non_negative_int,
        default=defaults["seed"],
        help="seed of the grasp draws and the learning placements (the held-out placements "
        "are the same for every seed)",
    )
    parser.add_argument("--quick", action="store_true", help="2 cycles of 10, 10 eval trials")
    args = parser.parse_args()
    if args.resume is not None:
        check_resume_alone(parser, args, keep=("num_envs", "address"))
    given = [f"--{name.replace('_', '-')}" for name in budget if getattr(args, name) is not None]
    if args.quick and given:
        parser.error(f"--quick sets the budget: drop {' '.join(given)}")
    quick = {"cycles": 2, "trials_per_cycle": 10, "eval_trials": 10}
    for name in budget:
        if getattr(args, name) is None:
            setattr(args, name, quick[name] if args.quick else defaults[name])
    if args.cycles * args.trials_per_cycle > 300:
        parser.error("the budget is at most 300 trials per object")
    where = {"num_envs": args.num_envs, "address": args.address}
    if args.resume is not None:
        out = args.resume
        settings = stopped_run_settings(parser, out, "config.json")
        experiment = GraspExperiment(**settings, **where)
    else:
        experiment = GraspExperiment(
            objects=args.objects,
            hypothesis=args.hypothesis,
            pose_source=args.pose_source,
            cycles=args.cycles,
            trials_per_cycle=args.trials_per_cycle,
            eval_trials=args.eval_trials,
            n_distractors=args.distractors,
            tip_probability=args.tip_probability,
            c_rel=args.c_rel,
            reliability=args.reliability,
            seed=args.seed,
            **where,
        )
        out = run_dir("learn_grasps", args.out)  # once the settings are known to be right
    summary = experiment.run(out)
    print(format_table(summary))
    print(f"wrote {out / 'summary.json'}")


if __name__ == "__main__":
    run_main(main, go_on="python scripts/learn_grasps.py --resume {out}")
