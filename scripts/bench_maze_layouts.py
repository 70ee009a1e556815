"""RLVC's default configuration on 10 random maze layouts, each scored against its oracle.

python scripts/bench_maze_layouts.py                 # layouts 1-10, writes summary.json
python scripts/bench_maze_layouts.py --layouts 3 7   # some layouts only
python scripts/bench_maze_layouts.py --workers 2     # two runs side by side
"""

import argparse

from vistask.cli import add_address, non_negative_int, positive_int, run_main
from vistask.experiments.maze_layouts import bench_maze_layouts


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--layouts", nargs="+", type=non_negative_int, default=list(range(1, 11)))
    parser.add_argument("--seed", type=non_negative_int, default=0, help="the agent's seed")
    parser.add_argument("--out", default=None, help="default runs/bench_maze_layouts-<time>")
    parser.add_argument("--workers", type=positive_int, default=1, help="runs side by side")
    add_address(parser, "the layouts")
    args = parser.parse_args()
    bench_maze_layouts(
        args.layouts, seed=args.seed, out=args.out, workers=args.workers, address=args.address
    )


if __name__ == "__main__":
    run_main(main)
