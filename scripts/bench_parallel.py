"""Runs side by side: the quick comparison on 1 worker and on N worker processes and N Ray
workers, grasp trials in AsyncVectorEnv processes and Ray actors on 1 and N workers, and one
RLVC run on 1 and N threads; speed-ups and whether the results stay identical.

python scripts/bench_parallel.py                        # workers 1 and all cores, 200 trials
python scripts/bench_parallel.py --parts grasps --trials 60 --workers 1 2 4
python scripts/bench_parallel.py --parts one_run          # one maze run on 1 and 2 threads
"""

import argparse
import os

os.environ.setdefault("MUJOCO_GL", "egl")

from vistask.cli import positive_int, run_main
from vistask.experiments.bench_parallel import bench_parallel


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--workers", type=positive_int, nargs="+", default=None)
    parser.add_argument("--trials", type=positive_int, default=200, help="grasp trials")
    parser.add_argument(
        "--parts",
        nargs="+",
        choices=("comparison", "grasps", "one_run"),
        default=["comparison", "grasps", "one_run"],
    )
    parser.add_argument("--out", default=None, help="default runs/bench_parallel-<time>")
    args = parser.parse_args()
    bench_parallel(args.workers, args.trials, args.parts, args.out)


if __name__ == "__main__":
    run_main(main)
