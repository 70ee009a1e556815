"""Grasps learned for every robosuite object that fits the Panda's hand, upright and lying,
behind ``scripts/bench_grasp_objects.py``.

Each object is learned with ``GraspExperiment`` (its pose estimated by NBP in every trial,
distractors on the table) standing upright at a random yaw, and again laid on a random side,
where it settles in a stable pose: in each of the two where some part of it fits the hand
(``pose_misfits``). Each is a ``learn_grasps.py`` run folder (``<out>/upright``,
``<out>/lying``), so that a stopped bench goes on where it stopped.
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


def robosuite_objects() -> tuple[list[str], dict[str, str]]:
    """The classes of ``robosuite.models.objects`` that build a graspable object, and the
    others with the reason each is left out (a fixture, visual geoms only, arguments with no
    default). Whether an object fits the hand is ``pose_misfits``'s to say."""
    from vistask.envs.objects import _robosuite_classes, object_spec

    kept, left_out = [], {}
    for name in sorted(_robosuite_classes()):
        if name in ("MujocoObject", "MujocoXMLObject"):
            continue  # the bases of every object, not objects
        try:
            object_spec(name)
        except ValueError as error:
            left_out[name] = str(error)
        else:
            kept.append(name)
    return kept, left_out


def object_row(
    upright: dict[str, Any] | None, lying: dict[str, Any] | None, spec
) -> dict[str, Any]:
    """One object's figures from its runs' summaries (``summarize_object``); None for those of
    a condition it was not learned in."""
    symmetry = spec.symmetry
    axis = None if symmetry.axis is None else [round(v, 3) for v in symmetry.axis.tolist()]
    row: dict[str, Any] = dict.fromkeys(
        ("sampled", "best_of_10", "drop_rate", "pose_error_deg", "position_error_mm")
    )
    row |= {"symmetry": {"rotations": len(symmetry.rotations), "axis": axis}, "ranking_width": None}
    if upright is not None:
        error_cm = upright["mean_pose_error_cm"]
        row |= {
            "sampled": upright["empirical_success"],
            "best_of_10": upright[f"best_of_{BEST_OF}_success"],
            "drop_rate": upright["failure_reasons"].get("dropped", 0)
            / upright["eval_trials_per_measure"],
            "pose_error_deg": upright["mean_pose_error_deg"],
            "position_error_mm": None if error_cm is None else 10 * error_cm,
            "ranking_width": upright["ranking_width"],
        }
    row["lying_sampled"] = None if lying is None else lying["empirical_success"]
    row["lying_best_of_10"] = None if lying is None else lying[f"best_of_{BEST_OF}_success"]
    return row


def summarize(
    objects: dict[str, dict[str, Any]],
    left_out: dict[str, str],
    poses_left_out: dict[str, dict[str, str]],
) -> dict[str, Any]:
    """The bench's summary: per object its row, the objects and the poses left out with
    their reasons, the means (of the objects learned upright, and lying) and which targets
    are met."""
    upright = [r for r in objects.values() if r["sampled"] is not None]
    lying = [r["lying_sampled"] for r in objects.values() if r["lying_sampled"] is not None]
    sampled = [r["sampled"] for r in upright]
    mean = lambda values: sum(values) / len(values) if values else None  # noqa: E731
    means = {
        "mean_sampled": mean(sampled),
        "mean_best_of_10": mean([r["best_of_10"] for r in upright]),
        "lowest_sampled": min(sampled, default=None),
        "lying": mean(lying),
    }
    met = {k: v is not None and v >= TARGETS[k] for k, v in means.items()}
    met["best_of_10_at_least_sampled"] = all(r["best_of_10"] >= r["sampled"] for r in upright)
    return {
        "objects": objects,
        "left_out": left_out,
        "poses_left_out": poses_left_out,
        **means,
        "targets": TARGETS,
        "met": met,
    }


def format_table(summary: dict[str, Any]) -> str:
    """A text table of the per-object figures and the means."""
    cell = lambda v, f: "-" if v is None else format(v, f)  # noqa: E731
    rows = [
        f"{'object':<20} {'sampled':>8} {'best of 10':>10} {'drops':>6} {'pose deg':>8} "
        f"{'pose mm':>8} {'lying':>6}"
    ]
    for name, r in summary["objects"].items():
        rows.append(
            f"{name:<20} {cell(r['sampled'], '.2f'):>8} {cell(r['best_of_10'], '.2f'):>10} "
            f"{cell(r['drop_rate'], '.2f'):>6} {cell(r['pose_error_deg'], '.1f'):>8} "
            f"{cell(r['position_error_mm'], '.1f'):>8} {cell(r['lying_sampled'], '.2f'):>6}"
        )
    rows.append(
        f"{'mean':<20} {cell(summary['mean_sampled'], '.2f'):>8} "
        f"{cell(summary['mean_best_of_10'], '.2f'):>10} {'':>6} {'':>8} {'':>8} "
        f"{cell(summary['lying'], '.2f'):>6}"
    )
    for name, reasons in summary["poses_left_out"].items():
        rows += [f"{name} not learned {c}: {why}" for c, why in reasons.items()]
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
        values = [np.nan if (v := summary["objects"][n][key]) is None else v for n in names]
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
    eval_trials: int = 100,
) -> dict[str, Any]:
    """Learn and score grasps of ``objects`` (default: ``robosuite_objects()``) upright and
    lying, ``trials`` learning trials each in 5 cycles, scored on ``eval_trials`` held-out
    placements (four times: before and after learning, sampled and best of 10); write
    ``out/summary.json`` (see ``summarize``), ``out/success.png`` and print the table. An
    object is learned in the conditions it fits the hand in (``pose_misfits``)."""
    from vistask.envs.hand_fit import pose_misfits
    from vistask.envs.objects import object_spec

    left_out: dict[str, str] = {}
    if objects is None:
        objects, left_out = robosuite_objects()
    cycles = 5
    if trials < cycles:
        raise ValueError(f"trials must be at least {cycles} (one per cycle), got {trials}")
    specs = {kind: object_spec(kind) for kind in objects}
    misfits = {kind: pose_misfits(spec) for kind, spec in specs.items()}
    runs: dict[str, dict[str, Any]] = {}
    for condition, tip in CONDITIONS.items():
        kinds = [k for k in objects if condition not in misfits[k]]
        if not kinds:
            continue
        experiment = GraspExperiment(
            objects=kinds,
            cycles=cycles,
            trials_per_cycle=trials // cycles,
            eval_trials=eval_trials,
            tip_probability=tip,
            num_envs=num_envs,
            seed=seed,
            address=address,
        )
        runs[condition] = experiment.run(out / condition, pictures=0)["objects"]
    rows, poses_left_out = {}, {}
    for kind, spec in specs.items():
        name = spec.name
        if len(misfits[kind]) == len(CONDITIONS):
            left_out[kind] = "; ".join(f"{c}: {why}" for c, why in misfits[kind].items())
            continue
        if misfits[kind]:
            poses_left_out[name] = misfits[kind]
        upright = runs.get("upright", {}).get(name)
        rows[name] = object_row(upright, runs.get("lying", {}).get(name), spec)
    summary = summarize(rows, left_out, poses_left_out)
    write_summary(out / "summary.json", summary)
    bar_chart(summary, out / "success.png")
    print(format_table(summary))
    print(json.dumps(summary["met"]))
    return summary
