"""One RLVC run at growing budgets: seconds by phase, peak memory of the process tree, classes
and return per budget; how time and memory grow with the interactions; predict's speed.

python scripts/bench_scale.py                                  # the maze and place navigation
python scripts/bench_scale.py --envs vistask/VisualMaze-v0 --budgets 40000 80000
"""

import argparse

from vistask.cli import add_address, non_negative_int, positive_int, run_main
from vistask.experiments.bench_scale import ENVS, bench_scale


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--envs", nargs="+", choices=list(ENVS), default=list(ENVS))
    parser.add_argument(
        "--budgets",
        type=positive_int,
        nargs="+",
        default=None,
        help="interactions of each run, for every env given (default: each env's own)",
    )
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument(
        "--workers", type=positive_int, default=1, help="runs side by side (they share cores)"
    )
    add_address(parser, "the budgets")
    parser.add_argument(
        "--out",
        default=None,
        help="default runs/bench_scale-<time>; a stopped run's folder resumes it",
    )
    args = parser.parse_args()
    budgets = None if args.budgets is None else {env: args.budgets for env in args.envs}
    bench_scale(args.envs, budgets, args.seed, args.workers, args.address, args.out)


if __name__ == "__main__":
    run_main(main, go_on="the same command with --out {out}")
