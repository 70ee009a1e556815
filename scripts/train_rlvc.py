r"""Train RLVC on an image env (RLJC if its actions are continuous); on the envs with an
oracle, compare the greedy policy with the oracle's.

python scripts/train_rlvc.py                       # the visual maze, 40,000 interactions
python scripts/train_rlvc.py --seed 3 --out runs/s3
python scripts/train_rlvc.py --env-kwargs '{"layout_seed": 7}'   # another maze layout
python scripts/train_rlvc.py --env vistask/VisualMountainCar-v0   # paper Figs. 6-7
python scripts/train_rlvc.py --env vistask/VisualMountainCar-v0 \
    --hyperparams 'compaction={structures: 1}'     # the car's settings, one class structure
python scripts/train_rlvc.py --hyperparams compounds=true 'compaction={tolerance: 0.01}'
python scripts/train_rlvc.py --env vistask/VisualMazeContinuous-v0   # RLJC, paper Fig. 10
python scripts/train_rlvc.py --resume runs/s3      # go on after a stop (Ctrl-C, kill)
"""

import argparse
from pathlib import Path

import gymnasium as gym

import vistask.envs  # noqa: F401  (registers the environments)
from vistask.agents import RLJCAgent, RLVCAgent
from vistask.cli import (
    check_resume_alone,
    json_object,
    non_negative_int,
    positive_int,
    run_main,
    stopped_run_settings,
)
from vistask.experiments.hyperparams import agent_kwargs, hyperparams_for, parse_overrides
from vistask.experiments.train_rljc import train_rljc
from vistask.experiments.train_rlvc import train_rlvc


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
    parser.add_argument(
        "--hyperparams",
        nargs="+",
        default=[],
        metavar="KEY=VALUE",
        help="RLVCAgent arguments over the env's entry in vistask/experiments/hyperparams/"
        "rlvc.yml, each value read as YAML (compounds=true 'compaction={tolerance: 0.01}')",
    )
    parser.add_argument(
        "--resume",
        type=Path,
        default=None,
        help="a stopped run's folder: go on with its settings from its last checkpoint",
    )
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args()
    try:
        overrides = parse_overrides(args.hyperparams)
    except ValueError as error:
        parser.error(f"argument --hyperparams: {error}")
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
        overrides = saved.pop("hyperparams", {})
        run = {**saved, "out": args.resume, "progress": run["progress"]}
        args.env, args.env_kwargs = saved["env_id"], saved["env_kwargs"]
    env = gym.make(args.env, **args.env_kwargs)
    env.close()
    continuous = isinstance(env.action_space, gym.spaces.Box)
    learner = RLJCAgent if continuous else RLVCAgent
    try:  # an unknown key or a wrong value fails here, before the run's folder is made
        learner(None, **agent_kwargs(hyperparams_for(args.env, overrides, learner)))
    except (TypeError, ValueError) as error:
        parser.error(f"argument --hyperparams: {error}")
    (train_rljc if continuous else train_rlvc)(**run, hyperparams=overrides)


if __name__ == "__main__":
    run_main(main, go_on="python scripts/train_rlvc.py --resume {out}")
