"""Grasps learned for every robosuite object that fits the Panda's hand, upright and lying,
behind ``scripts/bench_grasp_objects.py``.

Each object is learned twice with ``GraspExperiment`` (its pose estimated by NBP in every
trial, distractors on the table): once standing upright at a random yaw, once laid on a random
side, where it settles in a stable pose. Each is a ``learn_grasps.py`` run folder
(``<out>/upright``, ``<out>/lying``), so that a stopped bench goes on where it stopped.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vistask.experiments.grasps import BEST_OF, GraspExperiment
from vistask.runs import write_summary

CONDITIONS = {"upright": 0.0, "lying": 1.0}
"""The placements of each run, as ``GraspExperiment``'s chance that the object lies on a side."""

TARGETS = {"mean_sampled": 0.85, "mean_best_of_10": 0.93, "lowest_sampled": 0.70, "lying": 0.75}
"""What a grasp learner should reach over the objects: the means of sampled and best-of-10
held-out success, the lowest sampled success of any object, the mean success lying."""


def graspable_objects() -> tuple[list[str], dict[str, str]]:
    """The robosuite object classes whose narrowest extent fits between the Panda's open
    fingers, and the others with the reason each is left out."""
    from vistask.envs.grasp_trial import PANDA_MAX_OPENING
    from vistask.envs.object_shape import surface_points
    from vistask.envs.objects import _robosuite_classes, object_spec

    kept, left_out = [], {}
    for name in sorted(_robosuite_classes()):
        if name in ("MujocoObject", "MujocoXMLObject"):
            continue  # the bases of every object, not objects
        try:
            spec = object_spec(name)
        except ValueError as error:
            left_out[name] = str(error)
            continue
        points = surface_points(spec.make("probe"), n=4000)
        narrowest = float((points.max(0).values - points.min(0).values).min())
        if narrowest >= PANDA_MAX_OPENING:
            left_out[name] = (
                f"its narrowest extent, {1000 * narrowest:.0f} mm, does not fit between the "
                f"open fingers ({1000 * PANDA_MAX_OPENING:.0f} mm)"
            )
        else:
            kept.append(name)
    return kept, left_out


def object_row(upright: dict[str, Any], lying: dict[str, Any] | None, spec) -> dict[str, Any]:
    """One object's figures from its runs' summaries (``summarize_object``)."""
    symmetry, error_cm = spec.symmetry, upright["mean_pose_error_cm"]
    axis = None if symmetry.axis is None else [round(v, 3) for v in symmetry.axis.tolist()]
    return {
        "sampled": upright["empirical_success"],
        "best_of_10": upright[f"best_of_{BEST_OF}_success"],
        "drop_rate": upright["failure_reasons"].get("dropped", 0)
        / upright["eval_trials_per_measure"],
        "pose_error_deg": upright["mean_pose_error_deg"],
        "position_error_mm": None if error_cm is None else 10 * error_cm,
        "symmetry": {"rotations": len(symmetry.rotations), "axis": axis},
        "ranking_width": upright["ranking_width"],
        "lying_sampled": None if lying is None else lying["empirical_success"],
        "lying_best_of_10": None if lying is None else lying[f"best_of_{BEST_OF}_success"],
    }


def summarize(objects: dict[str, dict[str, Any]], left_out: dict[str, str]) -> dict[str, Any]:
    """The bench's summary: per object its row, the means and which targets are met."""
    rows = list(objects.values())
    sampled = [r["sampled"] for r in rows]
    lying = [r["lying_sampled"] for r in rows if r["lying_sampled"] is not None]
    means = {
        "mean_sampled": sum(sampled) / len(rows),
        "mean_best_of_10": sum(r["best_of_10"] for r in rows) / len(rows),
        "lowest_sampled": min(sampled),
        "lying": sum(lying) / len(lying) if lying else None,
    }
    met = {k: v is not None and v >= TARGETS[k] for k, v in means.items()}
    met["best_of_10_at_least_sampled"] = all(r["best_of_10"] >= r["sampled"] for r in rows)
    return {"objects": objects, "left_out": left_out, **means, "targets": TARGETS, "met": met}


def format_table(summary: dict[str, Any]) -> str:
    """A text table of the per-object figures and the means."""
    cell = lambda v, f: "-" if v is None else format(v, f)  # noqa: E731
    rows = [
        f"{'object':<20} {'sampled':>8} {'best of 10':>10} {'drops':>6} {'pose deg':>8} "
        f"{'pose mm':>8} {'lying':>6}"
    ]
    for name, r in summary["objects"].items():
        rows.append(
            f"{name:<20} {r['sampled']:>8.2f} {r['best_of_10']:>10.2f} {r['drop_rate']:>6.2f} "
            f"{cell(r['pose_error_deg'], '.1f'):>8} {cell(r['position_error_mm'], '.1f'):>8} "
            f"{cell(r['lying_sampled'], '.2f'):>6}"
        )
    rows.append(
        f"{'mean':<20} {summary['mean_sampled']:>8.2f} {summary['mean_best_of_10']:>10.2f} "
        f"{'':>6} {'':>8} {'':>8} {cell(summary['lying'], '.2f'):>6}"
    )
    return "\n".join(rows)


def bar_chart(summary: dict[str, Any], path: Path) -> None:
    """Sampled, best-of-10 and lying success per object, with the targets as lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    names = list(summary["objects"])
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(max(6.0, 0.7 * len(names)), 4))
    for k, (key, label) in enumerate(
        (("sampled", "sampled"), ("best_of_10", "best of 10"), ("lying_sampled", "lying"))
    ):
        values = [summary["objects"][n][key] or 0.0 for n in names]
        ax.bar(x + (k - 1) * 0.27, values, 0.27, label=label)
    ax.axhline(TARGETS["mean_sampled"], color="grey", ls="--", lw=0.8)
    ax.set(xticks=x, ylim=(0, 1.05), ylabel="held-out success")
    ax.set_xticklabels(names, rotation=45, ha="right")
    ax.legend(loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def bench_grasp_objects(
    out: Path,
    objects: Sequence[str] | None = None,
    trials: int = 300,
    seed: int = 0,
    num_envs: int = 2,
    address: str | None = None,
) -> dict[str, Any]:
    """Learn and score grasps of ``objects`` (default: ``graspable_objects()``) upright and
    lying, ``trials`` learning trials each in 5 cycles; write ``out/summary.json`` (see
    ``summarize``), ``out/success.png`` and print the table. Objects that cannot lie on a
    side (round about a vertical axis) have no lying run."""
    from vistask.envs.objects import object_name, object_spec

    left_out: dict[str, str] = {}
    if objects is None:
        objects, left_out = graspable_objects()
    cycles = 5
    if trials < cycles:
        raise ValueError(f"trials must be at least {cycles} (one per cycle), got {trials}")
    runs = {}
    for condition, tip in CONDITIONS.items():
        kinds = [k for k in objects if tip == 0.0 or object_spec(k).can_tip]
        if not kinds:
            continue
        experiment = GraspExperiment(
            objects=kinds,
            cycles=cycles,
            trials_per_cycle=trials // cycles,
            tip_probability=tip,
            num_envs=num_envs,
            seed=seed,
            address=address,
        )
        runs[condition] = experiment.run(out / condition, pictures=0)["objects"]
    rows = {}
    for kind in objects:
        name = object_name(kind)
        lying = runs.get("lying", {}).get(name)
        rows[name] = object_row(runs["upright"][name], lying, object_spec(kind))
    summary = summarize(rows, left_out)
    write_summary(out / "summary.json", summary)
    bar_chart(summary, out / "success.png")
    print(format_table(summary))
    print(json.dumps(summary["met"]))
    return summary
