"""Train RLVC on an image env; on the visual maze, compare its greedy policy with the oracle's.

python scripts/train_rlvc.py                       # the visual maze, 30,000 interactions
python scripts/train_rlvc.py --seed 3 --out runs/s3
python scripts/train_rlvc.py --env-kwargs '{"layout_seed": 7}'   # another maze layout
python scripts/train_rlvc.py --env vistask/VisualMountainCar-v0 --compounds   # paper Figs. 6-7
"""

import argparse
import json

from vistask.cli import positive_int
from vistask.experiments.train_rlvc import train_rlvc


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--env", default="vistask/VisualMaze-v0", help="Gymnasium env id")
    parser.add_argument("--env-kwargs", type=json.loads, default={}, help="JSON dict for gym.make")
    parser.add_argument("--interactions", type=positive_int, default=30_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--out", default=None, help="run directory (default runs/train_rlvc-<time>)"
    )
    parser.add_argument("--compounds", action="store_true", help="let RLVC make compound features")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args()
    train_rlvc(
        env_id=args.env,
        env_kwargs=args.env_kwargs,
        interactions=args.interactions,
        seed=args.seed,
        out=args.out,
        progress=not args.no_progress,
        compounds=args.compounds,
    )


if __name__ == "__main__":
    main()
