"""RLVC with its defaults against SB3 PPO (CnnPolicy, rl-zoo3's MiniGrid settings) and random
actions on public MiniGrid tasks seen as full 64x64 RGB frames: greedy success over 100
episodes at equal interactions, seeds 0-4.

python scripts/bench_gridworlds.py                                  # the full run
python scripts/bench_gridworlds.py --envs MiniGrid-DoorKey-5x5-v0 --methods rlvc --seeds 0
python scripts/bench_gridworlds.py --budgets 10000 25000 --out runs/g   # again: what is missing
python scripts/bench_gridworlds.py --address ray://head:10001       # on a running Ray cluster

Writes runs.jsonl (one line a finished run), summary.json
(summary[env][method]["success"][str(budget)]: IQM over seeds; summary[env]["rlvc"]
["percept_table"]: the same for Q solved on each RLVC run's own distinct percepts, what its
interactions allow without visual classes) and success.png.
"""

import argparse

from vistask.cli import add_address, non_negative_int, positive_int, run_main
from vistask.experiments.gridworlds import BUDGETS, GRIDWORLDS, METHODS, bench_gridworlds


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--envs", nargs="+", default=list(GRIDWORLDS), help="MiniGrid env ids")
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    parser.add_argument("--seeds", nargs="+", type=non_negative_int, default=list(range(5)))
    parser.add_argument("--budgets", nargs="+", type=positive_int, default=list(BUDGETS))
    parser.add_argument(
        "--workers", type=positive_int, default=None, help="runs side by side (default: cores)"
    )
    add_address(parser, "the runs")
    parser.add_argument("--out", default=None, help="run folder; an existing one is resumed")
    args = parser.parse_args()
    bench_gridworlds(
        args.envs, args.methods, args.seeds, args.budgets, args.out, args.workers, args.address
    )


if __name__ == "__main__":
    run_main(main, go_on="the same command with --out {out}")
