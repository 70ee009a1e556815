"""Learn empirical grasp densities by trial and error on a robosuite Panda (paper 3.5).

    python scripts/learn_grasps.py --out runs/grasps          # 3 objects, 300 trials each
    python scripts/learn_grasps.py --quick                    # a small smoke run
    python scripts/learn_grasps.py --out runs/grasps --nbp-only --nbp-trials 20
                                   # grasp with NBP poses using the densities learned there

Writes DIR/summary.json, TensorBoard scalars, and per object the hypothesis and empirical
densities, the learner (all trials) and a picture of both densities (DIR/<object>/).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from vistask.experiments.grasps import (
    ExperimentConfig,
    format_nbp_table,
    format_table,
    run_experiment,
    run_nbp,
)
from vistask.runs import run_dir


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--objects", nargs="+", default=["box", "can", "bread"])
    parser.add_argument("--hypothesis", choices=["feature", "demo"], default="feature")
    parser.add_argument("--cycles", type=int, default=5)
    parser.add_argument("--trials-per-cycle", type=int, default=60)
    parser.add_argument("--eval-trials", type=int, default=100)
    parser.add_argument("--num-envs", type=int, default=2)
    parser.add_argument("--c-rel", type=float, default=1.0, help="weight offset c / mean q")
    parser.add_argument("--candidates", type=int, default=10, help="K of best-of-K evaluation")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="2 cycles of 10, 10 eval trials")
    parser.add_argument(
        "--nbp-trials",
        type=int,
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
    out = run_dir("learn_grasps", args.out)
    config = ExperimentConfig(
        objects=tuple(args.objects),
        hypothesis=args.hypothesis,
        cycles=args.cycles,
        trials_per_cycle=args.trials_per_cycle,
        eval_trials=args.eval_trials,
        num_envs=args.num_envs,
        c_rel=args.c_rel,
        candidates=args.candidates,
        seed=args.seed,
    )
    if not args.nbp_only:
        summary = run_experiment(config, out)
        print(format_table(summary))
    if args.nbp_trials or args.nbp_only:
        nbp = run_nbp(out, config.objects, args.nbp_trials or 10, config.candidates)
        print(format_nbp_table(nbp))
    print(f"wrote {out / 'summary.json'}")


if __name__ == "__main__":
    main()
