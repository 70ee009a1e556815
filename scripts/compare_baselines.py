"""Compare RLVC (with and without compound features) with SB3 DQN/PPO (CnnPolicy on
percepts), tabular Q-learning on the true state and random actions, at the same interaction
budgets, over several seeds; on an env with continuous actions, RLJC with SB3 SAC/PPO. Scored
against the oracle on the envs that have one, by mean episode reward on any other image env.

python scripts/compare_baselines.py                      # full run: 5 seeds, budgets 1k..300k
python scripts/compare_baselines.py --quick              # tiny budgets (what the tests run)
python scripts/compare_baselines.py --budgets 1000 2000 5000 10000 20000 --seeds 3
python scripts/compare_baselines.py --env vistask/VisualMountainCar-v0 --grid rlvc
python scripts/compare_baselines.py --env vistask/VisualMazeContinuous-v0 --budgets 3000 10000 30000
python scripts/compare_baselines.py --env my_envs:my/Env-v0 --methods rlvc dqn ppo random
python scripts/compare_baselines.py --address ray://head:10001   # on a running Ray cluster
python scripts/compare_baselines.py --workers 1          # one run after another, in this process
python scripts/compare_baselines.py --out runs/c         # again after a stop: runs what is missing
tensorboard --logdir runs/compare-<time>/tensorboard     # eval/return of every method overlays

The runs go side by side on this machine's cores (this process and worker processes) unless
--workers 1; --address (or RAY_ADDRESS) sends them to a Ray cluster whose nodes have vistask
installed, and --address local to a Ray started on this machine.
"""

import argparse
import sys

import torch

from vistask.cli import (
    add_address,
    json_object,
    non_negative_int,
    positive_int,
    run_main,
    torch_device,
)
from vistask.experiments.compare import compare
from vistask.experiments.comparison import DEFAULT_BUDGETS, METHODS, Comparison


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--env",
        default="vistask/VisualMaze-v0",
        help="env id of image observations, 'module:id' to import its module first",
    )
    parser.add_argument("--env-kwargs", type=json_object, default={}, help="JSON dict for gym.make")
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=None)
    parser.add_argument(
        "--budgets", nargs="+", type=positive_int, default=None, help=f"{DEFAULT_BUDGETS}"
    )
    parser.add_argument(
        "--seeds", type=positive_int, default=None, help="number of seeds (default 5)"
    )
    parser.add_argument("--seed0", type=non_negative_int, default=0, help="first seed")
    parser.add_argument(
        "--eval-starts",
        type=positive_int,
        default=None,
        help="evaluation starts, or episodes on an env without an oracle (default 100)",
    )
    parser.add_argument(
        "--grid",
        type=grid_cells,
        default=10,
        help="tabular baseline's cells per dimension of the true state, or 'rlvc': as many "
        "cells as RLVC's classes",
    )
    parser.add_argument(
        "--device", type=torch_device, default="cpu", help="torch device of the SB3 networks"
    )
    parser.add_argument(
        "--threads",
        type=positive_int,
        default=None,
        help="torch CPU threads with --workers 1 (side by side, each run has one thread)",
    )
    parser.add_argument(
        "--workers", type=positive_int, default=None, help="runs side by side (default: cores)"
    )
    add_address(parser, "the runs")
    parser.add_argument("--quick", action="store_true", help="tiny budgets, 2 seeds")
    parser.add_argument(
        "--out",
        default=None,
        help="run directory (default runs/compare-<time>); an existing one is resumed",
    )
    args = parser.parse_args()
    overrides = {
        "env_id": args.env,
        "env_kwargs": args.env_kwargs,
        "seed0": args.seed0,
        "grid": args.grid,
        "device": args.device,
    }
    for key, value in (
        ("methods", args.methods),
        ("budgets", args.budgets),
        ("seeds", args.seeds),
        ("eval_starts", args.eval_starts),
    ):
        if value is not None:
            overrides[key] = value
    if args.threads and args.workers != 1:
        parser.error("--threads acts only with --workers 1 (side by side, a run has one thread)")
    if args.threads:
        torch.set_num_threads(args.threads)
    config = Comparison.quick(**overrides) if args.quick else Comparison(**overrides)
    summary = compare(config, args.out, workers=args.workers, address=args.address)
    sys.exit(1 if summary["failed"] else 0)


def grid_cells(text: str) -> int | None:
    """``--grid``: 'rlvc' (None), or a positive integer."""
    if text == "rlvc":
        return None
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"must be 'rlvc' or a positive integer, got {text}")
    return int(text)


if __name__ == "__main__":
    run_main(main, go_on="the same command with --out {out}")
