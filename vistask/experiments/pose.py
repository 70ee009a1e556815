"""Pose-estimation benchmark on robosuite tabletop scenes: NBP and the Open3D baseline.

Both methods see the same scene patches (every camera merged, the table plane removed) and
the same model points. Seconds per scene count patch extraction plus the method, not the
rendering. Success: translation error < 2 cm and rotation error < 15 degrees, modulo the
object's symmetry. robosuite is imported only when scenes are made.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from vistask.objects import NBP, ObjectModel, Open3DRegistration
from vistask.parallel import Outcome, map_runs
from vistask.runs import write_summary
from vistask.vision import Patches, PatchExtractor, pose_error, view_patches

DEFAULT_OBJECTS = ("cereal", "milk", "bread", "hammer", "can", "box")
DEFAULT_CAMERAS = ("front", "left", "top")
METHODS = ("nbp", "open3d")
SUCCESS_TRANSLATION_M = 0.02
SUCCESS_ROTATION_DEG = 15.0
TABLE_MARGIN_M = 0.004
"""Patches lower than this above the table top belong to the table plane."""
OCCLUDED = 0.9
"""A target with less than this fraction of its pixels visible in a view is occluded there."""


@dataclass(frozen=True)
class Condition:
    """How test scenes are made.

    Attributes:
        distractors: scene index -> number of distractor objects.
        distractor_range: distractors' x and y are uniform in +-this (metres); the target's
            in +-0.08, so a smaller range crowds the distractors around it.
        occluded: draw scenes (seeds derived from the scene's) until the target is partly
            hidden (below ``OCCLUDED`` visible) in at least one camera; with few cameras
            and sparse tables that happens in only about one scene in ten.
        max_tries: draws at most; then the most occluded draw is kept.
    """

    distractors: Callable[[int], int]
    distractor_range: float = 0.2
    occluded: bool = False
    max_tries: int = 30


CONDITIONS: dict[str, Condition] = {
    "clean": Condition(lambda i: 0),
    "clutter": Condition(lambda i: 3 + i % 2, distractor_range=0.15, occluded=True),
}


def visible_fraction(scene) -> list[float]:
    """Per camera, the target's pixels seen in ``scene`` over those seen with the
    distractors removed (1: not occluded). Re-renders the target alone at its pose."""
    from vistask.envs.tabletop import tabletop_world

    if len(scene.objects) == 1:
        return [1.0] * len(scene.views)
    world = tabletop_world()
    world.arrange([scene.target], scene.target_pose[None], max_steps=0)
    fractions = []
    for name, view in scene.views.items():
        cam = view.camera
        alone = world.render(name, [scene.target], cam.height, cam.width).mask(0).sum()
        fractions.append(float(view.mask(0).sum()) / max(int(alone), 1))
    return fractions


def scene_patches(scene, extractor: PatchExtractor | None = None) -> Patches:
    """World-frame patches of every view of a ``Scene``, without the table plane."""
    from vistask.envs.tabletop import TABLE_TOP_Z

    patches = Patches.cat([view_patches(v, extractor=extractor) for v in scene.views.values()])
    return patches.select(patches.positions[:, 2] > TABLE_TOP_Z + TABLE_MARGIN_M)


def draw_estimate(view, model: ObjectModel, pose: torch.Tensor, scale: int = 2) -> np.ndarray:
    """The model's patches back-projected into ``view`` at ``pose`` (7,) (paper Fig. 14).

    Returns:
        (scale * H, scale * W, 3) uint8 RGB picture.
    """
    from vistask.vision.draw import draw_patches

    world = model.patches.transform(pose.float().cpu())
    return draw_patches(view.rgb, view.camera, world, length=0.008, scale=scale)


class PoseBenchmark:
    """Learn each object's model, then estimate its pose in test scenes with every method.

    ``PoseBenchmark(objects=("milk",), n_scenes=2).run(out)``. The arguments are kept as
    attributes of the same names.

    Args:
        objects: object kinds (``vistask.envs.tabletop.OBJECTS``).
        n_scenes: test scenes per object and condition.
        conditions: names from ``CONDITIONS``.
        methods: "nbp" and/or "open3d".
        cameras: cameras of the learning views and of the test scenes.
        image_size: pixels (square images).
        n_rotations: object yaws shot for learning.
        voxel: down-sampling voxel (metres) of the learned patch set.
        seed: base seed of the test scenes (learning views are fixed).
        device: where NBP runs.
        nbp: the NBP estimator (default ``NBP()``).
        registration: the Open3D baseline (default ``Open3DRegistration()``).
        extractor: patch extraction of learning views and test scenes (default
            ``PatchExtractor()``). Models are learned with ``ObjectModel.learn``'s defaults;
            pass others to ``run`` as ``models``.

    Raises:
        ValueError: no object, n_scenes below 1, an unknown condition, or methods empty or
            not among ``METHODS``.
    """

    def __init__(
        self,
        objects: Sequence[str] = DEFAULT_OBJECTS,
        n_scenes: int = 10,
        conditions: Sequence[str] = ("clean", "clutter"),
        methods: Sequence[str] = METHODS,
        cameras: Sequence[str] = DEFAULT_CAMERAS,
        image_size: int = 256,
        n_rotations: int = 4,
        voxel: float = 0.004,
        seed: int = 1000,
        device: str = "cpu",
        nbp: NBP | None = None,
        registration: Open3DRegistration | None = None,
        extractor: PatchExtractor | None = None,
    ) -> None:
        if not objects:
            raise ValueError(f"objects must name at least one object kind, got {objects!r}")
        if n_scenes < 1:
            raise ValueError(f"n_scenes must be >= 1, got {n_scenes}")
        unknown = set(conditions) - set(CONDITIONS)
        if unknown:
            raise ValueError(f"unknown conditions {sorted(unknown)}; known: {sorted(CONDITIONS)}")
        if set(methods) - set(METHODS) or not methods:
            raise ValueError(f"methods must be among {METHODS} (at least one), got {methods}")
        self.objects = tuple(objects)
        self.n_scenes = n_scenes
        self.conditions = tuple(conditions)
        self.methods = tuple(methods)
        self.cameras = tuple(cameras)
        self.image_size = image_size
        self.n_rotations = n_rotations
        self.voxel = voxel
        self.seed = seed
        self.device = device
        self.nbp = nbp or NBP()
        self.registration = registration or Open3DRegistration()
        self.extractor = extractor or PatchExtractor()

    def learn_model(self, kind: str) -> ObjectModel:
        """Render ``kind`` alone at ``n_rotations`` yaws, merge its patches, learn its model."""
        from vistask.envs.tabletop import object_patches

        patches = object_patches(
            kind,
            self.n_rotations,
            self.cameras,
            self.image_size,
            extractor=self.extractor,
            voxel=self.voxel,
        )
        return ObjectModel.learn(patches, kind)

    def make_test_scene(self, seed: int, kind: str, condition: Condition, index: int) -> tuple:
        """A test scene of ``condition`` (reproducible from ``seed``) and the target's visible
        fraction per camera (see ``visible_fraction``)."""
        from vistask.envs.tabletop import tabletop_world

        world = tabletop_world()
        n = condition.distractors(index)
        best: tuple | None = None
        for attempt in range(condition.max_tries if condition.occluded else 1):
            try:
                scene = world.generate(
                    seed * 100 + attempt,
                    kind,
                    n,
                    self.cameras,
                    self.image_size,
                    distractor_range=condition.distractor_range,
                )
            except RuntimeError:  # no room for every distractor that close: draw again
                continue
            visible = visible_fraction(scene)
            if best is None or min(visible) < min(best[1]):
                best = (scene, visible)
            if not condition.occluded or min(visible) < OCCLUDED:
                break
        if best is None:
            raise RuntimeError(f"no scene could be placed for seed {seed}")
        return best

    def _estimate(self, method: str, model: ObjectModel, patches: Patches, seed: int):
        if method == "nbp":
            return self.nbp.infer(model, patches, device=self.device, seed=seed).pose.cpu()
        return self.registration.estimate_pose(model, patches, seed=seed).pose

    def _run_method(
        self, method: str, model: ObjectModel, patches: Patches, scene, seed: int
    ) -> dict:
        """Estimate the target's pose in ``scene`` with ``method``; the record of the attempt."""
        start = time.perf_counter()
        try:
            pose = self._estimate(method, model, patches, seed)
        except ValueError as err:  # nothing matched the model: a failure, not a crash
            pose, failure = None, str(err)
        else:
            failure = None
        seconds = time.perf_counter() - start
        if pose is None:
            t_err, r_err = float("inf"), 180.0
        else:
            te, re = pose_error(pose, scene.target_pose, scene.symmetry())
            t_err, r_err = float(te), float(re)
        return {
            "method": method,
            "condition": None,
            "object": scene.target,
            "seed": seed,
            "scene_seed": scene.seed,
            "objects_in_scene": scene.objects,
            "translation_error_m": t_err,
            "rotation_error_deg": r_err,
            "success": t_err < SUCCESS_TRANSLATION_M and r_err < SUCCESS_ROTATION_DEG,
            "seconds": seconds,
            "error": failure,
            "pose": None if pose is None else pose.tolist(),
            "true_pose": scene.target_pose.tolist(),
        }

    def scene_records(
        self, model: ObjectModel, kind: str, condition: str, index: int, picture: bool
    ) -> tuple[list[dict], dict[str, bytes]]:
        """Make test scene ``index`` of ``kind`` under ``condition`` and estimate the target's
        pose with every method.

        Returns:
            one record per method, and PNG pictures of the estimates (name -> bytes) if
            ``picture``.
        """
        seed = self.scene_seed(kind, condition, index)
        scene, visible = self.make_test_scene(seed, kind, CONDITIONS[condition], index)
        start = time.perf_counter()
        patches = scene_patches(scene, self.extractor)
        patch_seconds = time.perf_counter() - start
        records, pictures = [], {}
        for method in self.methods:
            record = self._run_method(method, model, patches, scene, seed)
            record["seconds"] += patch_seconds
            record["condition"], record["visible_fraction"] = condition, visible
            records.append(record)
            if picture and record["pose"] is not None:
                name = f"{kind}_{condition}_{seed}_{method}"
                pictures[name] = picture_png(scene, model, torch.tensor(record["pose"]))
        return records, pictures

    def scene_seed(self, kind: str, condition: str, index: int) -> int:
        """The seed of test scene ``index`` of ``kind`` under ``condition``."""
        o, c = self.objects.index(kind), self.conditions.index(condition)
        return self.seed + 10_000 * o + 1_000 * c + index

    def run(
        self,
        out: Path | None = None,
        writer=None,
        pictures: int = 0,
        log: Callable[[str], None] | None = print,
        models: dict[str, ObjectModel] | None = None,
        workers: int | None = 1,
        address: str | None = None,
    ) -> dict:
        """Learn each object's model, estimate its pose in every test scene with every method.

        The scenes are independent runs (``vistask.parallel.map_runs``): one after another in
        this process by default, or side by side on ``workers`` local Ray workers or a Ray
        cluster at ``address``, with the same records (each Ray worker runs one thread, as
        ``scripts/bench_pose.py`` does by default). A scene that fails is reported under
        ``failed`` and the others go on.

        Args:
            out: run directory (pictures go to ``out/pictures``); None writes nothing.
            writer: optional ``torch.utils.tensorboard.SummaryWriter`` for per-scene scalars.
            pictures: per object and condition, how many scenes get a picture of each method's
                estimate drawn over the first camera's image.
            log: progress printer, or None.
            models: already learned models by object kind (the others are learned here).
            workers: scenes side by side (1: in this process; None: all cores).
            address: Ray cluster to run the scenes on (default ``RAY_ADDRESS``).

        Returns:
            summary dict (see ``summarize``) with the per-scene ``records``, the scenes that
            failed (``failed``) and the settings (``config``).
        """
        learned: dict[str, ObjectModel] = {}
        for kind in self.objects:
            start = time.perf_counter()
            model = learned[kind] = (models or {}).get(kind) or self.learn_model(kind)
            if log:
                log(
                    f"{kind}: model of {len(model.patches)} patches, {model.n_classes} classes, "
                    f"depth {model.depth()}, learned in {time.perf_counter() - start:.1f} s"
                )
        jobs = [
            (self, learned[kind], kind, cond, i, i < pictures)
            for kind in self.objects
            for cond in self.conditions
            for i in range(self.n_scenes)
        ]

        def report(outcome: Outcome) -> None:
            _, _, kind, cond, i, _ = outcome.item
            if not log:
                return
            if not outcome.ok:
                log(f"  {cond:7s} {kind:7s} scene {i}: FAILED {outcome.error.splitlines()[-1]}")
                return
            for r in outcome.result[0]:
                t_err, r_err = r["translation_error_m"], r["rotation_error_deg"]
                log(
                    f"  {r['method']:6s} {cond:7s} {kind:7s} seed {r['seed']}: "
                    f"{t_err * 100:6.2f} cm {r_err:6.1f} deg {r['seconds']:5.2f} s"
                    f"{'' if r['success'] else '  FAIL'}"
                )

        outcomes = map_runs(_scene_records, jobs, workers, address, report)
        order = {id(job): k for k, job in enumerate(jobs)}
        outcomes.sort(key=lambda o: order[id(o.item)])
        records, failed = [], []
        for step, outcome in enumerate(outcomes):
            _, _, kind, cond, i, _ = outcome.item
            if not outcome.ok:
                failed.append(
                    {"object": kind, "condition": cond, "scene": i, "error": outcome.error}
                )
                continue
            scene_records, scene_pictures = outcome.result
            records += scene_records
            if writer is not None:
                for r in scene_records:
                    tag = f"{r['method']}/{cond}/{kind}"
                    writer.add_scalar(
                        f"{tag}/translation_error_m", min(r["translation_error_m"], 1.0), step
                    )
                    writer.add_scalar(f"{tag}/rotation_error_deg", r["rotation_error_deg"], step)
                    writer.add_scalar(f"{tag}/seconds", r["seconds"], step)
                    writer.add_scalar(f"{tag}/success", float(r["success"]), step)
            if out is not None:
                for name, png in scene_pictures.items():
                    (out / "pictures").mkdir(parents=True, exist_ok=True)
                    (out / "pictures" / f"{name}.png").write_bytes(png)
        if not records:
            raise RuntimeError("every scene failed:\n" + "\n".join(f["error"] for f in failed))
        summary = summarize(records)
        summary["config"] = {
            "objects": self.objects,
            "n_scenes": self.n_scenes,
            "conditions": self.conditions,
            "methods": self.methods,
            "cameras": self.cameras,
            "image_size": self.image_size,
            "n_rotations": self.n_rotations,
            "voxel": self.voxel,
            "seed": self.seed,
            "device": self.device,
            "model": {kind: model.params for kind, model in learned.items()},
            "nbp": vars(self.nbp),
            "registration": vars(self.registration),
            "patches": vars(self.extractor),
        }
        summary["records"] = records
        summary["failed"] = failed
        return summary


def _scene_records(job: tuple) -> tuple[list[dict], dict[str, bytes]]:
    """``PoseBenchmark.scene_records`` as a function of one picklable argument."""
    bench, model, kind, condition, index, picture = job
    return bench.scene_records(model, kind, condition, index, picture)


def picture_png(scene, model: ObjectModel, pose: torch.Tensor) -> bytes:
    """PNG bytes of ``pose``'s model points drawn over the scene's first camera image."""
    import cv2

    view = next(iter(scene.views.values()))
    ok, png = cv2.imencode(".png", draw_estimate(view, model, pose)[:, :, ::-1])
    if not ok:
        raise RuntimeError("OpenCV could not encode the picture as PNG")
    return png.tobytes()


def _stats(rows: list[dict]) -> dict:
    return {
        "n_scenes": len(rows),
        "success_rate": sum(r["success"] for r in rows) / len(rows),
        "median_translation_error_m": statistics.median(r["translation_error_m"] for r in rows),
        "median_rotation_error_deg": statistics.median(r["rotation_error_deg"] for r in rows),
        "seconds_per_scene": statistics.fmean(r["seconds"] for r in rows),
        "mean_visible_fraction": statistics.fmean(min(r["visible_fraction"]) for r in rows),
        "occluded_scenes": sum(min(r["visible_fraction"]) < OCCLUDED for r in rows) / len(rows),
    }


def summarize(records: list[dict]) -> dict:
    """Per method and condition: overall figures plus ``per_object`` ones.

    Returns:
        {method: {condition: {success_rate, median_translation_error_m,
        median_rotation_error_deg, seconds_per_scene, n_scenes, mean_visible_fraction (in
        the most occluded camera), occluded_scenes (share with a camera below ``OCCLUDED``),
        per_object: {kind: {...}}}}}
    """
    summary: dict = {}
    for method in dict.fromkeys(r["method"] for r in records):
        summary[method] = {}
        for cond in dict.fromkeys(r["condition"] for r in records):
            rows = [r for r in records if r["method"] == method and r["condition"] == cond]
            if not rows:
                continue
            entry = _stats(rows)
            entry["per_object"] = {
                kind: _stats([r for r in rows if r["object"] == kind])
                for kind in dict.fromkeys(r["object"] for r in rows)
            }
            summary[method][cond] = entry
    return summary


def markdown_table(summary: dict) -> str:
    """Markdown table: one row per method, condition and object (and "all")."""
    lines = [
        "| method | condition | object | scenes | success | median t err (cm) "
        "| median r err (deg) | s / scene | visible | occluded |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for method in METHODS:
        for cond, entry in summary.get(method, {}).items():
            rows = [*entry["per_object"].items(), ("**all**", entry)]
            for kind, s in rows:
                lines.append(
                    f"| {method} | {cond} | {kind} | {s['n_scenes']} "
                    f"| {100 * s['success_rate']:.0f}% "
                    f"| {100 * s['median_translation_error_m']:.2f} "
                    f"| {s['median_rotation_error_deg']:.1f} | {s['seconds_per_scene']:.2f} "
                    f"| {100 * s['mean_visible_fraction']:.0f}% "
                    f"| {100 * s['occluded_scenes']:.0f}% |"
                )
    return "\n".join(lines)


def write_results(summary: dict, out: Path, title: str = "Pose estimation") -> str:
    """Write ``summary.json`` and ``results.md`` to ``out``; returns the Markdown table."""
    out.mkdir(parents=True, exist_ok=True)
    table = markdown_table(summary)
    write_summary(out / "summary.json", summary)
    note = (
        f"Success: translation error < {100 * SUCCESS_TRANSLATION_M:g} cm and rotation error "
        f"< {SUCCESS_ROTATION_DEG:g} deg, modulo the object's symmetry. Seconds per scene: "
        "patch extraction plus the method (rendering excluded). Visible: the target's visible "
        "pixels over its pixels with the distractors removed, in the most occluded camera "
        f"(mean); occluded: scenes where that is below {100 * OCCLUDED:.0f}%."
    )
    (out / "results.md").write_text(f"# {title}\n\n{table}\n\n{note}\n")
    return table
