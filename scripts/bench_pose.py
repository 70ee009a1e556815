"""Benchmark pose estimation: NBP against Open3D at full strength on the same tabletop scenes.

Usage: python scripts/bench_pose.py [--out DIR] [--objects cereal milk bread hammer can box]
       [--conditions two_cameras one_camera depth_noise lighting tipped clutter]
       [--methods nbp open3d open3d_dense] [--scenes 10] [--quick] [--seed 1000]
       [--particles 2000] [--refine-iters 3] [--threads 1] [--device cpu] [--pictures 1]
       [--workers N] [--address ray://head:10001]
Models are learned from five cameras; test scenes are seen by one or two other cameras.
Conditions (``vistask.experiments.pose_scenes.CONDITIONS``): two test cameras; one; one with 2 mm
depth noise and dropout at depth edges; other lighting; objects lying on a side; four
lookalike distractors hiding at least half of the target, with depth noise. Open3D runs on
the scene patches NBP sees ("open3d") and on the dense depth clouds ("open3d_dense"), with
RANSAC restarts, FGR, multi-scale point-to-plane ICP and coloured ICP.
Writes DIR/summary.json (per method and condition: success, ci_low, ci_high,
seconds_per_scene, median errors, per_object), DIR/results.md (the Markdown table),
DIR/pictures/ (estimates drawn over the images) and TensorBoard scalars.
--workers N spreads the scenes over N cores (one thread each), --address over a Ray cluster;
the records are the same as in one process with --threads 1."""

from __future__ import annotations

import argparse
import inspect
from pathlib import Path

import torch

from vistask.cli import add_address, non_negative_int, positive_int, run_main, torch_device
from vistask.experiments.pose import PoseBenchmark
from vistask.experiments.pose_scenes import CONDITIONS, METHODS
from vistask.experiments.pose_summary import write_results
from vistask.objects import NBP
from vistask.runs import run_dir, tensorboard


def main() -> None:
    bench_defaults = {k: p.default for k, p in inspect.signature(PoseBenchmark).parameters.items()}
    nbp_defaults = {k: p.default for k, p in inspect.signature(NBP).parameters.items()}
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="output directory")
    parser.add_argument("--objects", nargs="+", default=list(bench_defaults["objects"]))
    parser.add_argument(
        "--scenes",
        type=positive_int,
        default=bench_defaults["n_scenes"],
        help="scenes per object and condition",
    )
    parser.add_argument("--quick", action="store_true", help="2 scenes per object and condition")
    parser.add_argument(
        "--seed", type=non_negative_int, default=bench_defaults["seed"], help="first scene seed"
    )
    parser.add_argument("--particles", type=positive_int, default=nbp_defaults["n_particles"])
    parser.add_argument(
        "--refine-iters",
        type=non_negative_int,
        default=nbp_defaults["refine_iters"],
        help="top-down refinement iterations of NBP's hypotheses (0: NBP modes as they are)",
    )
    parser.add_argument(
        "--methods", nargs="+", choices=METHODS, default=list(bench_defaults["methods"])
    )
    parser.add_argument(
        "--conditions",
        nargs="+",
        choices=list(CONDITIONS),
        default=list(bench_defaults["conditions"]),
    )
    parser.add_argument(
        "--threads", type=positive_int, default=1, help="torch CPU threads (1: no contention)"
    )
    parser.add_argument(
        "--device", type=torch_device, default="cpu", help="device of NBP (e.g. cuda)"
    )
    parser.add_argument(
        "--pictures", type=non_negative_int, default=1, help="pictures per object, condition"
    )
    parser.add_argument("--workers", type=positive_int, default=1, help="scenes side by side")
    add_address(parser, "the scenes")
    args = parser.parse_args()
    out = run_dir("bench_pose", args.out)
    torch.set_num_threads(args.threads)
    bench = PoseBenchmark(
        objects=args.objects,
        n_scenes=2 if args.quick else args.scenes,
        seed=args.seed,
        device=args.device,
        methods=args.methods,
        conditions=args.conditions,
        nbp=NBP(n_particles=args.particles, refine_iters=args.refine_iters),
    )
    with tensorboard(out) as writer:
        summary = bench.run(
            out, writer, pictures=args.pictures, workers=args.workers, address=args.address
        )
    print(write_results(summary, out, "Pose estimation: NBP against Open3D"))
    print(f"wrote {out / 'summary.json'}")


if __name__ == "__main__":
    run_main(main)
