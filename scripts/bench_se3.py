"""Benchmark SE(3) kernel density evaluation: dense and cut-off kernel-pair throughput.

Usage: python scripts/bench_se3.py [--out DIR] [--device cpu|cuda] [--threads N]
Writes DIR/summary.json with dense_pairs_per_s, cutoff_effective_pairs_per_s,
speedup_vs_numpy (CPU) and cuda_* figures when CUDA is available.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from vistask.cli import positive_int, run_main, torch_device
from vistask.experiments.bench_se3 import run_benchmark
from vistask.runs import print_table, run_dir, write_summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="output directory")
    parser.add_argument(
        "--device",
        type=torch_device,
        default=None,
        help="only this device (default: CPU, plus CUDA when available)",
    )
    parser.add_argument(
        "--threads",
        type=positive_int,
        default=1,
        help="torch CPU threads (default 1: on a shared 2-core machine OpenMP "
        "threads stall whenever another process holds a core)",
    )
    parser.add_argument("--repeats", type=positive_int, default=5)
    args = parser.parse_args()
    out = run_dir("bench_se3", args.out)
    torch.set_num_threads(args.threads)

    devices = [args.device] if args.device else ["cpu"] + (["cuda"] * torch.cuda.is_available())
    summary: dict[str, float] = {}
    for device in devices:
        figures = run_benchmark(device=device, repeats=args.repeats)
        prefix = "" if device == "cpu" else "cuda_"
        summary.update({prefix + key: value for key, value in figures.items()})

    print_table(summary)
    print(f"wrote {write_summary(out, summary)}")


if __name__ == "__main__":
    run_main(main)
