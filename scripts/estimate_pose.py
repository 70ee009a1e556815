"""Learn an object model, render test scenes, estimate the object's pose by NBP.

Usage: python scripts/estimate_pose.py [--out DIR] [--object cereal] [--scenes 5]
       [--condition clutter] [--particles 2000] [--threads 1] [--device cpu] [--pictures 5]
Writes DIR/summary.json, DIR/results.md, DIR/model.pt (the learned model), TensorBoard
scalars in DIR and DIR/pictures/*.png: the model's patches back-projected into the first
camera's image at the estimated pose (paper Fig. 14).
"""

from __future__ import annotations

import argparse
import inspect
from pathlib import Path

import torch

from vistask.cli import non_negative_int, positive_int, run_main, torch_device
from vistask.envs.objects import named_object_spec
from vistask.experiments.pose import PoseBenchmark
from vistask.experiments.pose_scenes import CONDITIONS
from vistask.experiments.pose_summary import write_results
from vistask.objects import NBP
from vistask.runs import run_dir, tensorboard


def main() -> None:
    nbp_defaults = {k: p.default for k, p in inspect.signature(NBP).parameters.items()}
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=None, help="output directory")
    parser.add_argument(
        "--object", default="cereal", help="a robosuite object class (e.g. can) or an MJCF file"
    )
    parser.add_argument("--scenes", type=positive_int, default=5)
    parser.add_argument("--condition", default="clutter", choices=sorted(CONDITIONS))
    parser.add_argument("--particles", type=positive_int, default=nbp_defaults["n_particles"])
    parser.add_argument(
        "--threads", type=positive_int, default=1, help="torch CPU threads (1: no contention)"
    )
    parser.add_argument(
        "--device", type=torch_device, default="cpu", help="device of NBP (e.g. cuda)"
    )
    parser.add_argument("--pictures", type=non_negative_int, default=5, help="scenes drawn")
    args = parser.parse_args()
    named_object_spec("object", args.object)  # refused before the run folder is made
    out = run_dir("estimate_pose", args.out)
    torch.set_num_threads(args.threads)
    bench = PoseBenchmark(
        objects=(args.object,),
        n_scenes=args.scenes,
        conditions=(args.condition,),
        methods=("nbp",),
        device=args.device,
        nbp=NBP(n_particles=args.particles),
    )
    model = bench.learn_model(args.object)
    model.save(out / "model.pt")
    with tensorboard(out) as writer:
        summary = bench.run(out, writer, pictures=args.pictures, models={args.object: model})
    summary["model"] = {
        "structure": repr(model.structure()),
        "patches": len(model.patches),
        "classes": model.n_classes,
        "depth": model.depth(),
    }
    print(write_results(summary, out, f"NBP pose estimation: {args.object}"))
    print(f"wrote {out / 'summary.json'}")


if __name__ == "__main__":
    run_main(main)
