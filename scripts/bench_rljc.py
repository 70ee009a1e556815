"""RLJC against four-action RLVC on the continuous-direction maze, over seeds (paper Fig. 10).

python scripts/bench_rljc.py                          # 5 seeds, 60,000 interactions each
python scripts/bench_rljc.py --seeds 2 --interactions 10000
"""

import argparse

from vistask.cli import json_object, positive_int, run_main
from vistask.experiments.bench_rljc import bench_rljc


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=positive_int, default=5, help="seeds 0..N-1")
    parser.add_argument("--interactions", type=positive_int, default=60_000)
    parser.add_argument("--env-kwargs", type=json_object, default={}, help="JSON dict for gym.make")
    parser.add_argument("--out", default=None, help="default runs/bench_rljc-<time>")
    args = parser.parse_args()
    bench_rljc(args.seeds, args.interactions, args.env_kwargs, args.out)


if __name__ == "__main__":
    run_main(main)
