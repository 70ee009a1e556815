"""Rank the best-of-10 candidates of learned grasp densities by success rates at several widths.

    python scripts/bench_grasp_ranking.py runs/grasps                 # every finished object
    python scripts/bench_grasp_ranking.py runs/grasps runs/grasps_s1 --placements 20

Executes all 10 candidates that a finished ``learn_grasps.py`` run drew on each held-out
placement (acting on the poses it estimated there; kept in <object>/candidates.pt), then
prints the best-of-10 success of each ranking and writes it to <first run>/ranking.json.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from vistask.cli import positive_int, run_main
from vistask.experiments.grasp_ranking import bench_grasp_ranking


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("runs", type=Path, nargs="+", help="finished learn_grasps.py folders")
    parser.add_argument(
        "--placements", type=positive_int, default=None, help="the first N held-out placements"
    )
    parser.add_argument("--out", type=Path, default=None, help="default <first run>/ranking.json")
    args = parser.parse_args()
    bench_grasp_ranking(args.runs, args.placements, args.out)


if __name__ == "__main__":
    run_main(main)
