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

import functools
import hashlib
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from vistask.envs.objects import DEFAULT_DISTRACTORS, object_name, object_spec
from vistask.envs.scene import CAMERAS, LEARNING_CAMERAS, TABLE_TOP_Z, TEST_CAMERAS
from vistask.experiments.statistics import success_interval
from vistask.objects import NBP, DepthCheck, ObjectModel, Open3DRegistration
from vistask.objects.registration import view_cloud
from vistask.parallel import Outcome, map_runs
from vistask.runs import write_summary
from vistask.vision import (
    Patches,
    PatchExtractor,
    RGBDView,
    object_patch_set,
    object_surface,
    pose_error,
    view_patches,
)

DEFAULT_OBJECTS = ("cereal", "milk", "bread", "hammer", "can", "box")
METHODS = ("nbp", "open3d", "open3d_dense")
SUCCESS_TRANSLATION_M = 0.02
SUCCESS_ROTATION_DEG = 15.0
TABLE_MARGIN_M = 0.004
"""Points lower than this above the table top belong to the table plane."""
SCENE_HALF_WIDTH_M = 0.4
"""Dense clouds keep the points above the table within this of its centre."""
LOOKALIKE_POOL = (*DEFAULT_DISTRACTORS, "lemon", "bottle", "cube", "round_nut", "square_nut")
"""Objects that lookalike distractors are chosen from (nearest in mean colour)."""
MIN_VISIBLE = 0.15
"""An occluded target still shows at least this fraction in some camera: a target hidden
entirely is not a pose problem."""


@dataclass(frozen=True)
class Condition:
    """How test scenes are made.

    Attributes:
        cameras: the test cameras (none of them used for learning).
        distractors: distractor objects on the table.
        lookalikes: draw the distractors from the ``distractors`` objects of
            ``LOOKALIKE_POOL`` nearest to the target in mean colour.
        occluders: stand the two tallest distractors between the target and the first
            camera (``vistask.envs.objects.place_occluders``).
        max_visible: draw scenes (seeds derived from the scene's) until the target shows
            at most this fraction of its pixels in every camera (and at least
            ``MIN_VISIBLE`` in one); None takes the first draw.
        depth_noise: standard deviation of the depth noise (metres); pixels at depth
            edges drop out with probability 0.5.
        relight: change the lighting at random.
        tip_probability: chance that an object that may tip lies on a side.
        distractor_range: the other distractors' x and y are uniform in +-this (metres)
            around the table centre; the target's in +-0.08.
        max_tries: draws at most; then the most occluded draw is kept.
    """

    cameras: tuple[str, ...] = TEST_CAMERAS[:1]
    distractors: int = 0
    lookalikes: bool = False
    occluders: bool = False
    max_visible: float | None = None
    depth_noise: float = 0.0
    relight: bool = False
    tip_probability: float = 0.0
    distractor_range: float = 0.12
    max_tries: int = 60


CONDITIONS: dict[str, Condition] = {
    "two_cameras": Condition(cameras=TEST_CAMERAS),
    "one_camera": Condition(),
    "depth_noise": Condition(depth_noise=0.002),
    "lighting": Condition(relight=True),
    "tipped": Condition(tip_probability=1.0),
    "clutter": Condition(
        distractors=4,
        lookalikes=True,
        occluders=True,
        max_visible=0.5,
        depth_noise=0.002,
        distractor_range=0.15,
    ),
}


def visible_fraction(scene, world) -> list[float]:
    """Per camera, the target's pixels seen in ``scene`` over those seen with the
    distractors removed (1: not occluded). Re-renders the target alone at its pose in
    ``world`` (the ``TabletopWorld`` the scene came from)."""
    if len(scene.objects) == 1:
        return [1.0] * len(scene.views)
    world.arrange([scene.target], scene.target_pose[None], max_steps=0)
    fractions = []
    for name, view in scene.views.items():
        cam = view.camera
        alone = world.render(name, [scene.target], cam.height, cam.width).mask(0).sum()
        fractions.append(float(view.mask(0).sum()) / max(int(alone), 1))
    return fractions


def lookalikes(world, target: str, k: int) -> list[str]:
    """The ``k`` objects of ``LOOKALIKE_POOL`` (other than ``target``) nearest to it in mean
    colour, each rendered alone, upright, by the top and front cameras."""
    colours = _mean_colours(world)
    name = object_name(target)
    others = [o for o in colours if o != name]
    distance = {o: float(np.linalg.norm(colours[o] - colours[name])) for o in others}
    return sorted(others, key=distance.get)[:k]


@functools.cache
def _mean_colours(world) -> dict[str, np.ndarray]:
    """Mean RGB in [0, 1] of every object of ``world``, rendered alone (once per world)."""
    from vistask.envs.objects import drop_pose, rest_rotation

    colours = {}
    for kind in world.kinds:
        rot = rest_rotation(world.specs[kind])
        upright = drop_pose(world.bounds[kind], rot, (0.0, 0.0), TABLE_TOP_Z)
        world.arrange([kind], upright[None].float())
        pixels = [
            view.rgb[view.mask(0)].float()
            for view in (world.render(c, [kind], 64, 64) for c in ("top", "front"))
        ]
        colours[kind] = torch.cat(pixels).mean(0).numpy() / 255.0
    return colours


def scene_patches(scene, extractor: PatchExtractor | None = None) -> Patches:
    """World-frame patches of every view of a ``Scene``, without the table plane."""
    patches = Patches.cat([view_patches(v, extractor=extractor) for v in scene.views.values()])
    return patches.select(patches.positions[:, 2] > TABLE_TOP_Z + TABLE_MARGIN_M)


def scene_cloud(views: Sequence[RGBDView], voxel: float) -> tuple[torch.Tensor, ...]:
    """Every valid depth pixel of ``views`` above the table (within ``SCENE_HALF_WIDTH_M``
    of its centre), per view down-sampled to ``voxel`` with normals turned towards its
    camera (``view_cloud``): (N, 3) world points, normals and colours in [0, 1]."""
    parts = []
    for view in views:
        p, c = view.point_cloud()
        keep = (p[:, 2] > TABLE_TOP_Z + TABLE_MARGIN_M) & (p[:, :2].abs() < SCENE_HALF_WIDTH_M).all(
            1
        )
        if keep.sum() >= 3:
            parts.append(view_cloud(p[keep], c[keep], view.camera.cam_to_world[:3, 3], voxel))
    if not parts:
        raise ValueError("no depth pixel above the table")
    return tuple(torch.cat(column) for column in zip(*parts, strict=True))


def draw_estimate(view, model: ObjectModel, pose: torch.Tensor, scale: int = 2) -> np.ndarray:
    """The model's patches back-projected into ``view`` at ``pose`` (7,) (paper Fig. 14).

    Returns:
        (scale * H, scale * W, 3) uint8 RGB picture.
    """
    from vistask.vision.draw import draw_patches

    world = model.patches.transform(pose.float().cpu())
    return draw_patches(view.rgb, view.camera, world, length=0.008, scale=scale)


def learn_object_model(
    kind: str,
    tipped: bool = True,
    n_rotations: int = 4,
    image_size: int = 256,
    voxel: float = 0.004,
    extractor: PatchExtractor | None = None,
) -> ObjectModel:
    """The object model of ``kind`` from its own views by the learning cameras: upright at
    ``n_rotations`` yaws, and laid on its sides too when ``tipped`` (and it may tip), one
    patch per ``voxel``, with its surface's colours from the same views."""
    from vistask.envs.tabletop import object_views

    patches, surfaces = [], []
    for side in _rest_sides(kind, tipped):
        views, poses = object_views(kind, n_rotations, LEARNING_CAMERAS, image_size, side)
        patches.append(object_patch_set(views, poses, 0, extractor, voxel))
        surfaces.append(object_surface(views, poses, 0, voxel))
    return ObjectModel.learn(Patches.cat(patches), object_name(kind), surface=torch.cat(surfaces))


def _rest_sides(kind: str, tipped: bool) -> tuple[bool, ...]:
    """The ``tipped`` flags of the views an object is learned from: upright, and lying too
    when ``tipped`` and it may tip."""
    return (False, True) if tipped and object_spec(kind).can_tip else (False,)


def model_cloud(kind: str, n_rotations: int, image_size: int, voxel: float) -> tuple:
    """The dense object-frame cloud of the views ``learn_object_model`` learns from: per
    view, the object's pixels down-sampled to ``voxel`` with normals turned towards the
    camera (``view_cloud``), then moved into the object's frame.

    Returns:
        (N, 3) object-frame points, normals and colours.
    """
    import roma

    from vistask.envs.tabletop import object_views

    parts = []
    for side in _rest_sides(kind, True):
        views, poses = object_views(kind, n_rotations, LEARNING_CAMERAS, image_size, side)
        for view, pose in zip(views, poses, strict=True):
            if view.mask(0).sum() < 3:
                continue
            points, colours = view.point_cloud(view.mask(0))
            eye = view.camera.cam_to_world[:3, 3]
            p, n, c = view_cloud(points, colours, eye, voxel)
            R = roma.unitquat_to_rotmat(pose[3:])
            parts.append(((p - pose[:3]) @ R, n @ R, c))
    return tuple(torch.cat(column) for column in zip(*parts, strict=True))


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
        for attempt in range(tries):
            try:
                scene = world.generate(
                    seed * 100 + attempt,
                    kind,
                    condition.distractors,
                    condition.cameras,
                    self.image_size,
                    condition.tip_probability,
                    distractor_range=condition.distractor_range,
                    distractors=pool,
                    relight=condition.relight,
                    occlude_from=CAMERAS[condition.cameras[0]].eye if condition.occluders else None,
                )
            except RuntimeError:  # no room for every distractor that close: draw again
                continue
            visible = visible_fraction(scene, world)
            if max(visible) < MIN_VISIBLE:
                continue
            if best is None or max(visible) < max(best[1]):
                best = (scene, visible)
            if condition.max_visible is None or max(visible) <= condition.max_visible:
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
            record.update(_errors(pose, scene.target_pose, scene.symmetry()))
            if shape is not None:
                up_to_shape = _errors(pose, scene.target_pose, shape)
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
            model = learned[kind] = (models or {}).get(kind) or self.learn_model(kind)
            if "open3d_dense" in self.methods:
                clouds[kind] = model_cloud(kind, self.n_rotations, self.image_size, self.voxel)
            if log:
                log(
                    f"{kind}: model of {len(model.patches)} patches, {model.n_classes} classes, "
                    f"depth {model.depth()}, learned in {time.perf_counter() - start:.1f} s"
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
                log(f"  {cond:11s} {kind:7s} scene {i}: FAILED {outcome.error.splitlines()[-1]}")
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


def _errors(pose: torch.Tensor | None, truth: torch.Tensor, symmetry) -> dict:
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
                    f"| {100 * s['median_translation_error_m']:.2f} "
                    f"| {s['median_rotation_error_deg']:.1f} | {s['seconds_per_scene']:.2f} "
                    f"| {100 * s['mean_visible_fraction']:.0f}% |"
                )
    return "\n".join(lines)


def write_results(summary: dict, out: Path, title: str = "Pose estimation") -> str:
    """Write ``summary.json`` and ``results.md`` to ``out``; returns the Markdown table."""
    out.mkdir(parents=True, exist_ok=True)
    table = markdown_table(summary)
    write_summary(out / "summary.json", summary)
    note = (
        f"Success: translation error < {100 * SUCCESS_TRANSLATION_M:g} cm and rotation error "
        f"< {SUCCESS_ROTATION_DEG:g} deg, modulo the object's symmetry; 95% Wilson intervals. "
        "Seconds per scene: what the method extracts from the images (patches or clouds) plus "
        "the method (rendering excluded). Visible: the target's visible pixels over its "
        "pixels with the distractors removed, in the camera that sees most of it (mean)."
    )
    (out / "results.md").write_text(f"# {title}\n\n{table}\n\n{note}\n")
    return table
