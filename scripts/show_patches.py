"""Render tabletop scenes, extract 3-D oriented patches, time it and save pictures.

Usage: python scripts/show_patches.py [--out DIR] [--target cereal] [--scenes 5]
       [--cameras front left] [--image-size 256] [--threads 1]
Writes DIR/summary.json (seconds per scene, patches per view), DIR/patches_<camera>.png
(patches of the first scene drawn over its images) and DIR/object_patches.png (the
target's object-frame patch set merged from several views, as a 3-D scatter).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import matplotlib
import torch

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from vistask.cli import positive_int, run_main
from vistask.envs.tabletop import benchmark_scenes, make_scene, object_patches
from vistask.runs import print_table, run_dir, write_summary
from vistask.vision import view_patches
from vistask.vision.draw import draw_patches


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="output directory")
    parser.add_argument(
        "--target", default="cereal", help="a robosuite object class (e.g. can) or an MJCF file"
    )
    parser.add_argument(
        "--scenes", type=positive_int, default=5, help="scenes to time (seeds 0..N-1)"
    )
    parser.add_argument(
        "--distractors", type=int, choices=range(5), default=None, help="0-4 (default: random)"
    )
    parser.add_argument("--cameras", nargs="+", default=["front"])
    parser.add_argument("--image-size", type=positive_int, default=256)
    parser.add_argument("--threads", type=positive_int, default=1, help="torch CPU threads")
    args = parser.parse_args()
    out = run_dir("show_patches", args.out)
    torch.set_num_threads(args.threads)

    summary: dict[str, float | str] = {"target": args.target, "image_size": args.image_size}
    summary["cameras"] = " ".join(args.cameras)
    summary.update(
        benchmark_scenes(
            list(range(args.scenes)), args.target, args.distractors, args.cameras, args.image_size
        )
    )

    scene = make_scene(0, args.target, args.distractors, args.cameras, args.image_size)
    for name, view in scene.views.items():
        picture = draw_patches(view.rgb, view.camera, view_patches(view))
        cv2.imwrite(str(out / f"patches_{name}.png"), picture[:, :, ::-1])
    start = time.perf_counter()
    model = object_patches(args.target, image_size=args.image_size)
    summary["object_patch_set_seconds"] = time.perf_counter() - start
    summary["object_patch_set_size"] = len(model)
    _scatter(model, out / "object_patches.png", args.target)

    print_table(summary)
    print(f"wrote {write_summary(out, summary)}")


def _scatter(patches, path: Path, title: str) -> None:
    fig = plt.figure(figsize=(6, 6))
    ax = fig.add_subplot(projection="3d")
    p, d = patches.positions.numpy(), 0.004 * patches.directions.numpy()
    ax.quiver(
        p[:, 0], p[:, 1], p[:, 2], d[:, 0], d[:, 1], d[:, 2], colors=patches.colors[:, 0].numpy()
    )
    ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=2, c=patches.colors[:, 1].numpy())
    ax.set_title(f"{title}: {len(patches)} patches, object frame (m)")
    ax.set_box_aspect(tuple(p.max(0) - p.min(0)))
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    run_main(main)
