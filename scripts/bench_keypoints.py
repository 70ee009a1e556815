"""Whether SIFT's keypoints of a maze view stay put as the view moves, by view size: keypoints
a view, and how many a view moved 4 pixels shows again at the same place with the same
descriptor, each view as it is and enlarged twice (RLVCAgent's enlarge).

python scripts/bench_keypoints.py                      # windows 32, 48, 64, 96
python scripts/bench_keypoints.py --windows 32 --enlarge 1 2 3
"""

import argparse

from vistask.cli import non_negative_int, positive_int, run_main
from vistask.experiments.bench_keypoints import bench_keypoints


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--windows", nargs="+", type=positive_int, default=[32, 48, 64, 96])
    parser.add_argument("--enlarge", nargs="+", type=positive_int, default=[1, 2])
    parser.add_argument("--views", type=positive_int, default=300)
    parser.add_argument("--shift", type=positive_int, default=4, help="pixels the view moves")
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--out", default=None, help="default runs/bench_keypoints-<time>")
    args = parser.parse_args()
    bench_keypoints(
        tuple(args.windows), tuple(args.enlarge), args.views, args.shift, args.seed, args.out
    )


if __name__ == "__main__":
    run_main(main)
