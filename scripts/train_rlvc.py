"""Train RLVC on an image maze and compare its greedy policy with the oracle's.

python scripts/train_rlvc.py          # VisualMaze-v0, the paper's protocol: 3 databases of 10,000
python scripts/train_rlvc.py --interactions 10000 --databases 1   # one random database
python scripts/train_rlvc.py --databases 0.5,0.25,0.25   # databases of unequal sizes
python scripts/train_rlvc.py --max-keypoints 0    # every SIFT keypoint (24 strongest by default)
python scripts/train_rlvc.py --blocked-is-stuck   # act as if blocked moves were dead ends
python scripts/train_rlvc.py --interactions 5000 --databases 1 --env-kwargs '{"step": 0.08}'
"""

import argparse
import json

from vistask.experiments.train_rlvc import train_rlvc


def databases(text: str) -> int | tuple[float, ...]:
    return int(text) if text.isdigit() else tuple(float(f) for f in text.split(","))


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--env", default="vistask/VisualMaze-v0")
    parser.add_argument("--env-kwargs", type=json.loads, default={}, help="JSON dict for gym.make")
    parser.add_argument(
        "--interactions", type=int, default=30_000, help="in all, over the databases"
    )
    parser.add_argument("--words", type=int, default=8192, help="vocabulary size")
    parser.add_argument(
        "--groups",
        type=int,
        default=64,
        help="coarse groups of the two-level vocabulary (0: flat vocabulary, exact matching)",
    )
    parser.add_argument("--alpha", type=float, default=0.05, help="t-test significance level")
    parser.add_argument("--min-count", type=int, default=10)
    parser.add_argument("--max-stages", type=int, default=300)
    parser.add_argument(
        "--databases",
        type=databases,
        default=3,
        help="number of equal databases, or budget fractions of successive databases (0.5,0.5); "
        "the first is random, later ones are collected epsilon-greedily on the current classes "
        "and added to the earlier ones",
    )
    parser.add_argument(
        "--blocked-is-stuck",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="act on Q solved with blocked moves (the same image again) as dead ends",
    )
    parser.add_argument(
        "--max-keypoints",
        type=int,
        default=24,
        help="SIFT keypoints kept per percept, strongest first (0: all); fewer is faster",
    )
    parser.add_argument(
        "--envs", type=int, default=128, help="episodes collected side by side on the classes"
    )
    parser.add_argument("--eval-starts", type=int, default=100)
    parser.add_argument("--eval-every", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--out", default=None, help="run directory (default runs/train_rlvc-<time>)"
    )
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args()
    train_rlvc(
        env_id=args.env,
        env_kwargs=args.env_kwargs,
        interactions=args.interactions,
        n_words=args.words,
        vocabulary_groups=args.groups,
        alpha=args.alpha,
        min_count=args.min_count,
        max_stages=args.max_stages,
        databases=args.databases,
        blocked_is_stuck=args.blocked_is_stuck,
        max_keypoints=args.max_keypoints,
        n_envs=args.envs,
        eval_starts=args.eval_starts,
        eval_every=args.eval_every,
        seed=args.seed,
        out=args.out,
        progress=not args.no_progress,
    )


if __name__ == "__main__":
    main()
