"""Grasps learned for every robosuite object that fits the Panda's hand, upright and lying.

    python scripts/bench_grasp_objects.py --out runs/grasp_objects          # every object
    python scripts/bench_grasp_objects.py --objects lemon can --trials 100  # some, shorter
    python scripts/bench_grasp_objects.py --objects my.xml --trials 10 --eval-trials 10  # a try
    python scripts/bench_grasp_objects.py --address ray://head:10001 --workers 32

Each object is learned on its own pose estimates (NBP, 2 distractors, seed 0) standing
upright at a random yaw, and again laid on a random side, in each where some part of it fits
the hand. Writes OUT/summary.json (per object under "objects": sampled, best_of_10, drop_rate,
pose_error_deg, position_error_mm, symmetry, lying_sampled; the objects and the poses left out
and why; the means and the targets met), OUT/success.png,
and the two learn_grasps.py run folders OUT/upright and OUT/lying. Run it again with the same
--out to go on after a stop.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from vistask.cli import add_address, positive_int, run_main
from vistask.envs.objects import distinct_object_specs
from vistask.experiments.grasp_objects import bench_grasp_objects
from vistask.runs import run_dir


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (default runs/bench_grasp_objects-<time>)",
    )
    parser.add_argument(
        "--objects",
        nargs="+",
        default=None,
        help="robosuite object classes or MJCF files (default: every object that fits the hand)",
    )
    parser.add_argument(
        "--trials", type=positive_int, default=300, help="learning trials (at least 5: 5 cycles)"
    )
    parser.add_argument(
        "--eval-trials",
        type=positive_int,
        default=100,
        help="held-out placements each evaluation scores (4 evaluations a condition)",
    )
    parser.add_argument("--workers", type=positive_int, default=2, help="simulators at once")
    add_address(parser, "the trials")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.objects:  # refused before the run folder is made
        distinct_object_specs("objects", args.objects)
    out = run_dir("bench_grasp_objects", args.out)
    bench_grasp_objects(
        out, args.objects, args.trials, args.seed, args.workers, args.address, args.eval_trials
    )


if __name__ == "__main__":
    run_main(main, go_on="the same command with --out {out}")
