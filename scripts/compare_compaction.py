"""Tree RLVC against BDD RLVC (compaction, paper Fig. 9): classes, features, return, test error.

python scripts/compare_compaction.py                                   # the visual maze
python scripts/compare_compaction.py --env-kwargs '{"photo": "hubble_deep_field"}'  # Fig. 5
python scripts/compare_compaction.py --env vistask/PlaceNavigation-v0
python scripts/compare_compaction.py --env vistask/PlaceNavigation-v0 \
    --env-kwargs '{"views_per_state": 512}' --interactions 600000   # tree 0.91, BDD 0.94
"""

import argparse

from vistask.cli import json_object, non_negative_int, positive_int, run_main, unit_fraction
from vistask.experiments.compare_compaction import METHODS, compare_compaction


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--env", default="vistask/VisualMaze-v0", help="Gymnasium env id")
    parser.add_argument("--env-kwargs", type=json_object, default={}, help="JSON dict for gym.make")
    parser.add_argument("--seeds", type=non_negative_int, nargs="+", default=[0])
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    parser.add_argument("--interactions", type=positive_int, default=30_000)
    parser.add_argument(
        "--compact-every", type=positive_int, default=None, help="also compact every N stages"
    )
    parser.add_argument("--tolerance", type=unit_fraction, default=0.02)
    parser.add_argument(
        "--max-stages",
        type=positive_int,
        default=None,
        help="agents' stage cap per database (default: the env's hyperparameters, else 300)",
    )
    parser.add_argument(
        "--contrast-threshold",
        type=unit_fraction,
        default=None,
        help="SIFT's detection threshold (default: the env's hyperparameters, else 0.005)",
    )
    parser.add_argument(
        "--out",
        default=None,
        help="default runs/compare_compaction-<time>; a stopped run's folder resumes it",
    )
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args()
    compare_compaction(
        env_id=args.env,
        env_kwargs=args.env_kwargs,
        seeds=args.seeds,
        methods=args.methods,
        interactions=args.interactions,
        compact_every=args.compact_every,
        tolerance=args.tolerance,
        max_stages=args.max_stages,
        contrast_threshold=args.contrast_threshold,
        out=args.out,
        progress=not args.no_progress,
    )


if __name__ == "__main__":
    run_main(main, go_on="the same command with --out {out}")
