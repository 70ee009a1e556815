"""Benchmark pose estimation: NBP vs Open3D (FPFH + RANSAC + ICP) on the same tabletop scenes.

Usage: python scripts/bench_pose.py [--out DIR] [--objects cereal milk bread hammer can box]
       [--scenes 10] [--quick] [--seed 1000] [--particles 2000] [--refine-iters 3]
       [--methods nbp open3d] [--threads 1] [--device cpu] [--pictures 1]
Clean scenes have no distractor; cluttered ones have 3-4 and are drawn until the target is
partly hidden in some camera. Writes DIR/summary.json (per method and condition:
success_rate, median errors, seconds_per_scene, occlusion, per_object), DIR/results.md (the
Markdown table), DIR/pictures/ (estimates drawn over the images) and TensorBoard scalars."""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from torch.utils.tensorboard import SummaryWriter

from vistask.runs import run_dir
from vistask.objects import BenchConfig, NBPConfig, run_benchmark, write_results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="output directory")
    parser.add_argument("--objects", nargs="+", default=list(BenchConfig.objects))
    parser.add_argument("--scenes", type=int, default=10, help="scenes per object and condition")
    parser.add_argument("--quick", action="store_true", help="2 scenes per object and condition")
    parser.add_argument("--seed", type=int, default=BenchConfig.seed, help="first scene seed")
    parser.add_argument("--particles", type=int, default=NBPConfig.n_particles)
    parser.add_argument(
        "--refine-iters",
        type=int,
        default=NBPConfig.refine_iters,
        help="top-down refinement iterations of NBP's hypotheses (0: NBP modes as they are)",
    )
    parser.add_argument("--methods", nargs="+", default=["nbp", "open3d"])
    parser.add_argument(
        "--threads", type=int, default=1, help="torch CPU threads (1: no contention)"
    )
    parser.add_argument("--device", default="cpu", help="device of NBP (e.g. cuda)")
    parser.add_argument("--pictures", type=int, default=1, help="pictures per object, condition")
    args = parser.parse_args()
    out = run_dir("bench_pose", args.out)
    torch.set_num_threads(args.threads)
    cfg = BenchConfig(
        objects=tuple(args.objects),
        n_scenes=2 if args.quick else args.scenes,
        seed=args.seed,
        device=args.device,
        methods=tuple(args.methods),
        nbp=NBPConfig(n_particles=args.particles, refine_iters=args.refine_iters),
    )
    with SummaryWriter(str(out)) as writer:
        summary = run_benchmark(cfg, out, writer, pictures=args.pictures)
    print(write_results(summary, out, "Pose estimation: NBP vs Open3D"))
    print(f"wrote {out / 'summary.json'}")


if __name__ == "__main__":
    main()
