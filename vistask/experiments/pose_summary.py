"""The pose benchmark's scoring and summary: errors modulo symmetry, success rates with
intervals per condition and object, and the table written beside ``summary.json``."""

from __future__ import annotations

import math
import statistics
from pathlib import Path

import torch

from vistask.experiments.pose_scenes import METHODS, SUCCESS_ROTATION_DEG, SUCCESS_TRANSLATION_M
from vistask.experiments.statistics import success_interval
from vistask.runs import write_summary
from vistask.vision import (
    pose_error,
)


def pose_errors(pose: torch.Tensor | None, truth: torch.Tensor, symmetry) -> dict:
    """Translation and rotation errors of ``pose`` (None: nothing found) and success."""
    if pose is None:
        t_err, r_err = float("inf"), 180.0
    else:
        te, re = pose_error(pose, truth, symmetry)
        t_err, r_err = float(te), float(re)
    return {
        "translation_error_m": t_err,
        "rotation_error_deg": r_err,
        "success": t_err < SUCCESS_TRANSLATION_M and r_err < SUCCESS_ROTATION_DEG,
    }


def _stats(rows: list[dict], key: str = "success") -> dict:
    wins, n = sum(r[key] for r in rows), len(rows)
    low, high = success_interval(wins, n)
    return {
        "n_scenes": n,
        "success": wins / n,
        "ci_low": low,
        "ci_high": high,
        "median_translation_error_m": statistics.median(r["translation_error_m"] for r in rows),
        "median_rotation_error_deg": statistics.median(r["rotation_error_deg"] for r in rows),
        "seconds_per_scene": statistics.fmean(r["seconds"] for r in rows),
        "mean_visible_fraction": statistics.fmean(max(r["visible_fraction"]) for r in rows),
    }


def summarize(records: list[dict]) -> dict:
    """Per method and condition: overall figures plus ``per_object`` ones.

    Returns:
        {method: {condition: {success, ci_low, ci_high (95% Wilson interval),
        median_translation_error_m, median_rotation_error_deg, seconds_per_scene, n_scenes,
        mean_visible_fraction (in the camera that sees most of the target), per_object:
        {kind: {...}}, up_to_shape: {kind: {...}} for objects whose texture alone breaks a
        symmetry of their shape, scored modulo the shape's symmetry}}}
    """
    summary: dict = {}
    for method in dict.fromkeys(r["method"] for r in records):
        summary[method] = {}
        for cond in dict.fromkeys(r["condition"] for r in records):
            rows = [r for r in records if r["method"] == method and r["condition"] == cond]
            if not rows:
                continue
            entry = _stats(rows)
            kinds = dict.fromkeys(r["object"] for r in rows)
            entry["per_object"] = {k: _stats([r for r in rows if r["object"] == k]) for k in kinds}
            entry["up_to_shape"] = {
                k: _stats([r for r in rows if r["object"] == k], "success_up_to_shape")
                for k in kinds
                if all("success_up_to_shape" in r for r in rows if r["object"] == k)
            }
            summary[method][cond] = entry
    return summary


def markdown_table(summary: dict) -> str:
    """Markdown table: one row per method, condition and object (and "all"); objects whose
    texture alone breaks a symmetry of their shape get a second row scored up to it."""
    lines = [
        "| method | condition | object | scenes | success (95% CI) | median t err (cm) "
        "| median r err (deg) | s / scene | visible |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for method in METHODS:
        for cond, entry in summary.get(method, {}).items():
            rows = [
                *entry["per_object"].items(),
                *((f"{k} (shape only)", v) for k, v in entry["up_to_shape"].items()),
                ("**all**", entry),
            ]
            for kind, s in rows:
                lines.append(
                    f"| {method} | {cond} | {kind} | {s['n_scenes']} "
                    f"| {100 * s['success']:.0f}% ({100 * s['ci_low']:.0f}-"
                    f"{100 * s['ci_high']:.0f}) "
                    f"| {_median_cm(s['median_translation_error_m'])} "
                    f"| {s['median_rotation_error_deg']:.1f} | {s['seconds_per_scene']:.2f} "
                    f"| {100 * s['mean_visible_fraction']:.0f}% |"
                )
    return "\n".join(lines)


def _median_cm(metres: float) -> str:
    # A method that found no pose in half the scenes or more has no finite median error.
    return f"{100 * metres:.2f}" if math.isfinite(metres) else "none found"


def write_results(summary: dict, out: Path, title: str = "Pose estimation") -> str:
    """Write ``summary.json`` and ``results.md`` to ``out``; returns the Markdown table."""
    out.mkdir(parents=True, exist_ok=True)
    table = markdown_table(summary)
    write_summary(out / "summary.json", summary)
    note = (
        f"Success: translation error < {100 * SUCCESS_TRANSLATION_M:g} cm and rotation error "
        f"< {SUCCESS_ROTATION_DEG:g} deg, modulo the object's symmetry; 95% Wilson intervals. "
        "Seconds per scene: what the method extracts from the images (patches or clouds) plus "
        "the method (rendering excluded). Median errors: 'none found' where the method found "
        "no pose in half the scenes or more. Visible: the target's visible pixels over its "
        "pixels with the distractors removed, in the camera that sees most of it (mean)."
    )
    (out / "results.md").write_text(f"# {title}\n\n{table}\n\n{note}\n")
    return table
