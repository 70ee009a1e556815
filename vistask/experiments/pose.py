"""Pose-estimation benchmark on robosuite tabletop scenes: NBP against Open3D at full strength.

Object models are learned from views by the learning cameras (``LEARNING_CAMERAS``); test
scenes are seen by other cameras (``TEST_CAMERAS``), under conditions reported separately:
two or one test camera, depth noise with dropout at depth edges, other lighting, objects
lying on a side, and clutter of lookalike distractors hiding at least half of the target.

NBP and Open3D on patches see the same scene patches (every test camera merged, the table
plane removed), and NBP checks its hypotheses against the depth images (``DepthCheck``);
Open3D on dense clouds sees every valid depth pixel above the table, against the model's
dense cloud. Seconds per scene count the method and what it extracts from the
images (patches or clouds), not the rendering. Success: translation error < 2 cm and rotation
error < 15 degrees, modulo the object's symmetry. robosuite is imported only when scenes are
made.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path

import torch

from vistask.envs.objects import DEFAULT_DISTRACTORS, NoRoomError, object_name, object_spec
from vistask.envs.scene import CAMERAS, TABLE_TOP_Z
from vistask.experiments.pose_scenes import (
    CONDITIONS,
    DEFAULT_OBJECTS,
    LOOKALIKE_POOL,
    METHODS,
    MIN_VISIBLE,
    Condition,
    draw_estimate,
    learn_object_model,
    lookalikes,
    model_cloud,
    scene_cloud,
    scene_patches,
    visible_fraction,
)
from vistask.experiments.pose_summary import pose_errors, summarize
from vistask.objects import NBP, DepthCheck, ObjectModel, Open3DRegistration
from vistask.parallel import Outcome, last_line, map_runs
from vistask.vision import (
    Patches,
    PatchExtractor,
)


class PoseBenchmark:
    """Learn each object's model, then estimate its pose in test scenes with every method.

    ``PoseBenchmark(objects=("milk",), n_scenes=2).run(out)``. The arguments are kept as
    attributes of the same names.

    Args:
        objects: object kinds: presets, robosuite object classes or MJCF files
            (``vistask.envs.objects.object_spec``).
        n_scenes: test scenes per object and condition.
        conditions: names from ``CONDITIONS``.
        methods: among ``METHODS``: "nbp", "open3d" (on the scene patches NBP sees),
            "open3d_dense" (on the dense depth clouds).
        image_size: pixels (square images).
        n_rotations: object yaws shot for learning.
        voxel: down-sampling voxel (metres) of the learned patch set.
        seed: base seed of the test scenes (learning views are fixed).
        device: where NBP runs.
        nbp: the NBP estimator (default ``NBP()``).
        registration: the Open3D baseline (default ``Open3DRegistration()``).
        extractor: patch extraction of learning views and test scenes (default
            ``PatchExtractor()``).

    Raises:
        ValueError: no object, n_scenes below 1, an unknown condition, or methods empty or
            not among ``METHODS``.
    """

    def __init__(
        self,
        objects: Sequence[str] = DEFAULT_OBJECTS,
        n_scenes: int = 10,
        conditions: Sequence[str] = tuple(CONDITIONS),
        methods: Sequence[str] = METHODS,
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
        self.objects = tuple(str(o) for o in objects)
        self.n_scenes = n_scenes
        self.conditions = tuple(conditions)
        self.methods = tuple(methods)
        self.image_size = image_size
        self.n_rotations = n_rotations
        self.voxel = voxel
        self.seed = seed
        self.device = device
        self.nbp = nbp or NBP()
        self.registration = registration or Open3DRegistration()
        self.extractor = extractor or PatchExtractor()

    def learn_model(self, kind: str) -> ObjectModel:
        """``kind``'s model from its own views (``learn_object_model``), upright and lying."""
        return learn_object_model(
            kind, True, self.n_rotations, self.image_size, self.voxel, self.extractor
        )

    def make_test_scene(self, seed: int, kind: str, condition: Condition) -> tuple:
        """A test scene of ``condition`` (reproducible from ``seed``), with depth noise when
        the condition has it, and the target's visible fraction per camera (see
        ``visible_fraction``)."""
        from vistask.envs.tabletop import tabletop_world

        world = tabletop_world([kind, *LOOKALIKE_POOL])
        pool = (
            lookalikes(world, kind, condition.distractors)
            if condition.lookalikes
            else DEFAULT_DISTRACTORS
        )
        best: tuple | None = None
        tries = 1 if condition.max_visible is None else condition.max_tries
        bounds = world.bounds[object_name(kind)]
        # A long target leaves no room for its distractors that close: then they spread
        # farther, by half its longest side.
        spread = float((bounds[1] - bounds[0]).max()) / 2
        for distractor_range in (condition.distractor_range, condition.distractor_range + spread):
            for attempt in range(tries):
                try:
                    scene = world.generate(
                        seed * 100 + attempt,
                        kind,
                        condition.distractors,
                        condition.cameras,
                        self.image_size,
                        condition.tip_probability,
                        distractor_range=distractor_range,
                        distractors=pool,
                        relight=condition.relight,
                        occlude_from=CAMERAS[condition.cameras[0]].eye
                        if condition.occluders
                        else None,
                    )
                except NoRoomError:  # no room for every distractor that close: draw again
                    continue
                visible = visible_fraction(scene, world)
                if max(visible) < MIN_VISIBLE:
                    continue
                if best is None or max(visible) < max(best[1]):
                    best = (scene, visible)
                if condition.max_visible is None or max(visible) <= condition.max_visible:
                    break
            if best is not None:
                break
        if best is None:
            raise RuntimeError(f"no scene could be placed for seed {seed}")
        scene, visible = best
        if condition.depth_noise > 0:
            noise = torch.Generator().manual_seed(seed)
            scene.views = {
                name: view.with_depth_noise(condition.depth_noise, generator=noise)
                for name, view in scene.views.items()
            }
        return scene, visible

    def _estimate(self, method: str, models: tuple, scene, patches: Patches | None, seed: int):
        model, cloud = models
        if method == "nbp":
            depth = DepthCheck(scene.views.values(), floor_z=TABLE_TOP_Z)
            return self.nbp.infer(model, patches, self.device, seed, depth).pose.cpu()
        if method == "open3d":
            return self.registration.estimate_pose(model, patches, seed=seed).pose
        points, normals, colours = scene_cloud(list(scene.views.values()), self.voxel)
        return self.registration.register(
            cloud[0], points, cloud[1], normals, seed, cloud[2], colours
        ).pose

    def scene_records(
        self, models: tuple, kind: str, condition: str, index: int, picture: bool
    ) -> tuple[list[dict], dict[str, bytes]]:
        """Make test scene ``index`` of ``kind`` under ``condition`` and estimate the target's
        pose with every method.

        Args:
            models: the object model and its dense (points, normals, colours) cloud.
            kind: the target object.
            condition: a key of ``CONDITIONS``.
            index: the scene's number within the object and condition.
            picture: also draw each estimate over the test view.

        Returns:
            one record per method, and PNG pictures of the estimates (name -> bytes) if
            ``picture``.
        """
        seed = self.scene_seed(kind, condition, index)
        scene, visible = self.make_test_scene(seed, kind, CONDITIONS[condition])
        start = time.perf_counter()
        try:
            patches = scene_patches(scene, self.extractor)
        except ValueError:  # nothing in view has a contour: the patch methods find nothing
            patches = None
        patch_seconds = time.perf_counter() - start
        shape = object_spec(kind).shape_symmetry
        records, pictures = [], {}
        for method in self.methods:
            start = time.perf_counter()
            try:
                if patches is None and method != "open3d_dense":
                    raise ValueError("no patch in the scene")
                pose, failure = self._estimate(method, models, scene, patches, seed), None
            except ValueError as err:  # nothing matched the model: a failure, not a crash
                pose, failure = None, str(err)
            seconds = (
                time.perf_counter() - start + (patch_seconds if method != "open3d_dense" else 0)
            )
            record = {
                "method": method,
                "condition": condition,
                "object": scene.target,
                "seed": seed,
                "objects_in_scene": scene.objects,
                "visible_fraction": visible,
                "seconds": seconds,
                "error": failure,
                "pose": None if pose is None else pose.tolist(),
                "true_pose": scene.target_pose.tolist(),
            }
            record.update(pose_errors(pose, scene.target_pose, scene.symmetry()))
            if shape is not None:
                up_to_shape = pose_errors(pose, scene.target_pose, shape)
                record["success_up_to_shape"] = up_to_shape["success"]
            records.append(record)
            if picture and pose is not None:
                name = f"{scene.target}_{condition}_{seed}_{method}"
                pictures[name] = picture_png(scene, models[0], pose)
        return records, pictures

    def scene_seed(self, kind: str, condition: str, index: int) -> int:
        """The seed of test scene ``index`` of ``kind`` under ``condition``: a hash of the
        benchmark's seed and these names, so that it does not depend on which other objects
        or conditions run."""
        text = f"{self.seed}/{object_name(kind)}/{condition}/{index}"
        return int.from_bytes(hashlib.blake2b(text.encode(), digest_size=4).digest(), "little")

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
        this process by default, or side by side on ``workers`` cores or a Ray cluster at
        ``address``, with the same records (each worker runs one thread, as
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
        clouds = {}
        for kind in self.objects:
            start = time.perf_counter()
            given = (models or {}).get(kind)
            model = learned[kind] = given or self.learn_model(kind)
            if "open3d_dense" in self.methods:
                clouds[kind] = model_cloud(kind, self.n_rotations, self.image_size, self.voxel)
            if log:
                learning = "given" if given else f"learned in {time.perf_counter() - start:.1f} s"
                log(
                    f"{kind}: model of {len(model.patches)} patches, {model.n_classes} classes, "
                    f"depth {model.depth()}, {learning}"
                )
        jobs = [
            (self, (learned[kind], clouds.get(kind)), kind, cond, i, i < pictures)
            for kind in self.objects
            for cond in self.conditions
            for i in range(self.n_scenes)
        ]

        def report(outcome: Outcome) -> None:
            _, _, kind, cond, i, _ = outcome.item
            if not log:
                return
            if not outcome.ok:
                log(f"  {cond:11s} {kind:7s} scene {i}: FAILED {last_line(outcome.error)}")
                return
            for r in outcome.result[0]:
                t_err, r_err = r["translation_error_m"], r["rotation_error_deg"]
                log(
                    f"  {r['method']:12s} {cond:11s} {kind:7s} seed {r['seed']:>10d}: "
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
            "condition_settings": {c: asdict(CONDITIONS[c]) for c in self.conditions},
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
