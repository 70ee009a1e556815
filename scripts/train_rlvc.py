r"""Train RLVC on an image env (RLJC if its actions are continuous); on the envs with an
oracle, compare the greedy policy with the oracle's.

python scripts/train_rlvc.py                       # the visual maze, 40,000 interactions
python scripts/train_rlvc.py --seed 3 --out runs/s3
python scripts/train_rlvc.py --env-kwargs '{"layout_seed": 7}'   # another maze layout
python scripts/train_rlvc.py --env vistask/VisualMountainCar-v0 --compounds   # paper Figs. 6-7
python scripts/train_rlvc.py --env vistask/VisualMountainCar-v0 --compounds --compaction
python scripts/train_rlvc.py --env vistask/VisualMountainCar-v0 --compounds --compaction \
    --compaction-tolerance 0.01 --structures 11 --vocabulary-groups 16 \
    --env-kwargs '{"max_episode_steps": 20}'       # the README's car
python scripts/train_rlvc.py --env vistask/VisualMazeContinuous-v0   # RLJC, paper Fig. 10
python scripts/train_rlvc.py --resume runs/s3      # go on after a stop (Ctrl-C, kill)
"""

import argparse
from pathlib import Path

import gymnasium as gym

import vistask.envs  # noqa: F401  (registers the environments)
from vistask.cli import (
    check_resume_alone,
    interrupt_on_sigterm,
    json_object,
    non_negative_int,
    positive_int,
    run_main,
    stopped_run_settings,
    unit_fraction,
)
from vistask.experiments.train_rljc import train_rljc
from vistask.experiments.train_rlvc import train_rlvc
from vistask.features.vocabulary import VOCABULARY_GROUPS


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--env", default="vistask/VisualMaze-v0", help="Gymnasium env id")
    parser.add_argument("--env-kwargs", type=json_object, default={}, help="JSON dict for gym.make")
    parser.add_argument(
        "--interactions",
        type=positive_int,
        default=None,
        help="default 40,000 for RLVC, 60,000 for RLJC (the joint space needs more)",
    )
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument(
        "--out", default=None, help="default runs/train_rlvc-<time> (RLJC: train_rljc-<time>)"
    )
    parser.add_argument("--compounds", action="store_true", help="let RLVC make compound features")
    parser.add_argument(
        "--compaction", action="store_true", help="RLVC's classes in a BDD, merged by compaction"
    )
    parser.add_argument(
        "--compaction-tolerance",
        type=unit_fraction,
        default=None,
        help="with --compaction: merge classes whose values differ by at most this share of "
        "their range (default 0.02; 0.01 does better on the car)",
    )
    parser.add_argument(
        "--structures",
        type=positive_int,
        default=1,
        help="with --compaction: when learning ends, fuse this many class structures, the "
        "learned one and others on bootstrap samples of its interactions (RLVC.fuse)",
    )
    parser.add_argument(
        "--vocabulary-groups",
        type=positive_int,
        default=None,
        help="coarse groups of the vocabulary, the parts of compound features (default 64; "
        "16 on the car: coarser parts)",
    )
    parser.add_argument(
        "--resume",
        type=Path,
        default=None,
        help="a stopped run's folder: go on with its settings from its last checkpoint",
    )
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args()
    if args.compaction_tolerance is not None and not args.compaction:
        parser.error("--compaction-tolerance needs --compaction")
    if args.structures > 1 and not args.compaction:
        parser.error("--structures needs --compaction")
    run = dict(env_id=args.env, env_kwargs=args.env_kwargs, seed=args.seed, out=args.out)
    run["progress"] = not args.no_progress
    if args.interactions is not None:
        run["interactions"] = args.interactions
    if args.resume is not None:
        check_resume_alone(parser, args, keep=("no_progress",))
        runs = ("train_rlvc", "train_rljc")  # the library functions that write its runs
        saved = stopped_run_settings(parser, args.resume, "settings.json", runs)
        if (args.resume / "summary.json").exists():
            parser.error(f"argument --resume: {args.resume} holds a finished run (summary.json)")
        args.compounds = saved.pop("compounds", False)
        args.compaction = saved.pop("compaction", False)
        args.compaction_tolerance = saved.pop("compaction_tolerance", None)
        args.structures = saved.pop("structures", 1)
        args.vocabulary_groups = saved.pop("vocabulary_groups", None)
        run = {**saved, "out": args.resume, "progress": run["progress"]}
        args.env, args.env_kwargs = saved["env_id"], saved["env_kwargs"]
    interrupt_on_sigterm()
    env = gym.make(args.env, **args.env_kwargs)
    env.close()
    if isinstance(env.action_space, gym.spaces.Box):
        if args.compounds or args.compaction or args.vocabulary_groups is not None:
            parser.error(
                "--compounds, --compaction and --vocabulary-groups apply to RLVC (discrete "
                "actions), not RLJC"
            )
        train_rljc(**run)
    else:
        train_rlvc(
            **run,
            compounds=args.compounds,
            compaction=args.compaction,
            compaction_tolerance=args.compaction_tolerance,
            structures=args.structures,
            vocabulary_groups=args.vocabulary_groups or VOCABULARY_GROUPS,
        )


if __name__ == "__main__":
    run_main(main)
