"""Learn empirical grasp densities by trial and error on a robosuite Panda (paper 3.5).

    python scripts/learn_grasps.py --out runs/grasps          # 3 objects, 300 trials each
    python scripts/learn_grasps.py --quick                    # a small smoke run
    python scripts/learn_grasps.py --resume runs/grasps       # go on after a stop (Ctrl-C, kill)
    python scripts/learn_grasps.py --address ray://head:10001 --num-envs 32  # on a Ray cluster
    python scripts/learn_grasps.py --out runs/grasps --nbp-only --nbp-trials 20
                                   # grasp with NBP poses using the densities learned there

Writes DIR/summary.json, TensorBoard scalars, and per object the hypothesis and empirical
densities, the learner (all trials) and a picture of both densities (DIR/<object>/).
"""

from __future__ import annotations

import argparse
import inspect
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from vistask.cli import (
    interrupt_on_sigterm,
    non_negative_float,
    non_negative_int,
    positive_int,
    stopped_run_settings,
)
from vistask.experiments.grasps import (
    HYPOTHESES,
    GraspExperiment,
    format_nbp_table,
    format_table,
    run_nbp,
)
from vistask.runs import run_dir


def main() -> None:
    defaults = {k: p.default for k, p in inspect.signature(GraspExperiment).parameters.items()}
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument(
        "--resume",
        type=Path,
        default=None,
        help="a stopped run's folder: go on with its settings, after its last finished cycle",
    )
    parser.add_argument("--objects", nargs="+", default=list(defaults["objects"]))
    parser.add_argument("--hypothesis", choices=HYPOTHESES, default=defaults["hypothesis"])
    parser.add_argument("--cycles", type=positive_int, default=defaults["cycles"])
    parser.add_argument(
        "--trials-per-cycle", type=positive_int, default=defaults["trials_per_cycle"]
    )
    parser.add_argument("--eval-trials", type=positive_int, default=defaults["eval_trials"])
    parser.add_argument(
        "--num-envs",
        type=positive_int,
        default=defaults["num_envs"],
        help="simulators side by side",
    )
    parser.add_argument(
        "--address", default=None, help="Ray cluster for the simulators (default: local processes)"
    )
    parser.add_argument(
        "--c-rel",
        type=non_negative_float,
        default=defaults["c_rel"],
        help="weight offset c / mean q",
    )
    parser.add_argument(
        "--candidates",
        type=positive_int,
        default=defaults["candidates"],
        help="K of best-of-K evaluation",
    )
    parser.add_argument("--seed", type=int, default=defaults["seed"])
    parser.add_argument("--quick", action="store_true", help="2 cycles of 10, 10 eval trials")
    parser.add_argument(
        "--nbp-trials",
        type=non_negative_int,
        default=0,
        help="afterwards, grasp this many held-out scenes per object with the pose from NBP",
    )
    parser.add_argument(
        "--nbp-only", action="store_true", help="skip learning: use the densities in --out"
    )
    args = parser.parse_args()
    if args.cycles * args.trials_per_cycle > 300:
        parser.error("the budget is at most 300 trials per object")
    if args.quick:
        args.cycles, args.trials_per_cycle, args.eval_trials = 2, 10, 10
    where = {"num_envs": args.num_envs, "address": args.address}
    if args.resume is not None:
        out = args.resume
        settings = stopped_run_settings(parser, out, "config.json")
        experiment = GraspExperiment(**settings, **where)
    else:
        out = run_dir("learn_grasps", args.out)
        experiment = GraspExperiment(
            objects=args.objects,
            hypothesis=args.hypothesis,
            cycles=args.cycles,
            trials_per_cycle=args.trials_per_cycle,
            eval_trials=args.eval_trials,
            c_rel=args.c_rel,
            candidates=args.candidates,
            seed=args.seed,
            **where,
        )
    interrupt_on_sigterm()
    if not args.nbp_only:
        summary = experiment.run(out)
        print(format_table(summary))
    if args.nbp_trials or args.nbp_only:
        nbp = run_nbp(out, experiment.objects, args.nbp_trials or 10, experiment.candidates)
        print(format_nbp_table(nbp))
    print(f"wrote {out / 'summary.json'}")


if __name__ == "__main__":
    main()
