"""Benchmark the visual-feature front end on maze percepts: ms and features per percept."""

import argparse

from vistask.cli import json_object, non_negative_int, positive_int, run_main
from vistask.experiments.bench_features import bench_features


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--percepts", type=positive_int, default=2000)
    parser.add_argument("--words", type=positive_int, default=8192)
    parser.add_argument("--env-kwargs", type=json_object, default={})
    parser.add_argument("--threads", type=positive_int, default=None, help="extraction threads")
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--out", default=None, help="default runs/bench_features-<time>")
    args = parser.parse_args()
    bench_features(
        args.percepts,
        args.words,
        args.env_kwargs,
        threads=args.threads,
        seed=args.seed,
        out=args.out,
    )


if __name__ == "__main__":
    run_main(main)
