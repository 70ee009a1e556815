"""RLVC's default configuration on 10 random maze layouts, each scored against its oracle.

python scripts/bench_maze_layouts.py                 # layouts 1-10, writes summary.json
python scripts/bench_maze_layouts.py --layouts 3 7   # some layouts only
"""

import argparse

from vistask.experiments.maze_layouts import bench_maze_layouts


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--layouts", nargs="+", type=int, default=list(range(1, 11)))
    parser.add_argument("--seed", type=int, default=0, help="the agent's seed")
    parser.add_argument("--out", default=None, help="default runs/bench_maze_layouts-<time>")
    args = parser.parse_args()
    bench_maze_layouts(args.layouts, seed=args.seed, out=args.out)


if __name__ == "__main__":
    main()
