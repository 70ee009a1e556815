"""Local descriptors at interest points, from OpenCV.

SIFT on the grey image gives keypoints that follow the tapestry as the window slides: the same
photo detail yields nearly the same descriptor in every percept that shows it, which is what
"feature f is present" needs. The paper used colour differential invariants; ``color_weight``
appends the mean chromaticity around each keypoint to the SIFT descriptor in the same spirit.
"""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from vistask.checks import check_at_least, check_integers, checked

SIFT_NORM = 512.0  # OpenCV scales SIFT descriptors to about this Euclidean norm
# Distinct views whose keypoints ``SiftExtractor`` keeps when percepts are made of views: about
# 13 kB each at 24 keypoints; the mountain car shows 1528 distinct views in 44,000 percepts.
VIEW_CACHE = 10_000
# OpenCV's SIFT descriptor samples gradients up to about 4 keypoint sizes from its centre
# (3 x sigma a bin, 4 + 1 bins across, sigma half the size); closer to the view's edge it
# reads pixels that change as the view moves.
SUPPORT_RADIUS = 4.0
# Views whose shorter side is under this many pixels are enlarged twice by ``choose_enlarge``
# (``enlarge="auto"``) where that keeps at least as many keypoints.
SMALL_VIEW = 56
# Views of a first database that ``choose_enlarge`` counts keypoints on, evenly spaced.
ENLARGE_SAMPLE = 256


@checked
@dataclass
class Keypoints:
    """Keypoints of one image: ``xy`` (K, 2) pixel (x, y), ``descriptors`` (K, D) and
    ``scale`` (K,) (the diameter of the keypoint's neighbourhood, in pixels), float32."""

    xy: np.ndarray
    descriptors: np.ndarray
    scale: np.ndarray

    def __len__(self) -> int:
        return len(self.xy)


@checked
def check_image(image: np.ndarray) -> np.ndarray:
    """Validate an RGB uint8 image (H, W, 3) or a grey one (H, W) and return it."""
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8:
        raise TypeError(
            f"expected an image as a uint8 numpy array, got {type(image).__name__}"
            + (f" of dtype {image.dtype}" if isinstance(image, np.ndarray) else "")
        )
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise ValueError(f"expected an (H, W, 3) RGB or (H, W) grey image, got shape {image.shape}")
    return image


@checked
def check_image_space(space, user: str) -> None:
    """Raise a clear error unless the Gymnasium ``space`` holds (H, W, 3) RGB or (H, W) grey
    uint8 images."""
    from gymnasium import spaces

    shape = getattr(space, "shape", None) or ()
    if not (
        isinstance(space, spaces.Box)
        and space.dtype == np.uint8
        and (len(shape) == 2 or (len(shape) == 3 and shape[2] == 3))
    ):
        raise TypeError(
            f"{user} needs (H, W, 3) or (H, W) uint8 image observations, got observation "
            f"space {space}; {_image_hint(space)}"
        )


def _image_hint(space) -> str:
    """How to turn observations of ``space`` into (H, W, 3) or (H, W) uint8 images."""
    from gymnasium import spaces

    shape = tuple(getattr(space, "shape", None) or ())
    if isinstance(space, spaces.Dict):
        images = [k for k, s in space.spaces.items() if isinstance(s, spaces.Box) and s.shape]
        if images:  # observations that hold an image: keep it alone
            k = images[0]
            return (
                f"keep the image alone: gymnasium.wrappers.TransformObservation(env, "
                f"lambda o: o[{k!r}], env.observation_space[{k!r}])"
            )
    if not isinstance(space, spaces.Box) or len(shape) not in (2, 3):
        return "render an env to pixels with gymnasium.wrappers.AddRenderObservation"

    def transform(what: str, f: str, new_shape: tuple) -> str:
        return (
            f"{what}: gymnasium.wrappers.TransformObservation(env, {f}, "
            f"gymnasium.spaces.Box(0, 255, {new_shape}, np.uint8))"
        )

    if space.dtype != np.uint8:
        return transform(
            "with views in [0, 1], make them uint8",
            "lambda o: (o * 255).round().astype(np.uint8)",
            shape,
        )
    if len(shape) == 3 and 1 in (shape[0], shape[2]):
        grey = shape[:2] if shape[2] == 1 else shape[1:]
        return f"drop the channel axis: gymnasium.wrappers.ReshapeObservation(env, {grey})"
    if len(shape) == 3 and shape[0] == 3 and shape[2] != 3:
        return transform(
            "move the channels last", "lambda o: o.transpose(1, 2, 0)", (*shape[1:], shape[0])
        )
    if len(shape) == 3 and shape[2] == 4:
        return transform("drop the alpha channel", "lambda o: o[..., :3]", (*shape[:2], 3))
    return "give the images 1 (grey) or 3 (RGB) channels"


def image_digest(image: np.ndarray) -> tuple:
    """Cache key of an image: its shape and Python's 64-bit (SipHash) hash of its pixels,
    4x cheaper than a cryptographic digest. Two of 100,000 distinct views collide with
    probability about 3e-10; the key lives in one process, so the per-process salt is harmless."""
    return image.shape, hash(image.tobytes())


def extract_once(
    cache: dict, images: Sequence[np.ndarray], extract: Callable[[list], list], cache_size: int
) -> list:
    """``extract`` of every image, run once per distinct image: repeats, within ``images`` or
    in ``cache`` from earlier calls, are looked up by ``image_digest``. The new results join
    ``cache``, which is emptied first when they would take it past ``cache_size`` (0: nothing
    is cached)."""
    keys = [image_digest(image) for image in images]
    todo = {}
    for key, image in zip(keys, images, strict=True):
        if key not in cache:
            todo.setdefault(key, image)
    found = dict(zip(todo, extract(list(todo.values())), strict=True)) if todo else {}
    results = [found[key] if key in found else cache[key] for key in keys]
    if found and cache_size:  # after the lookup: a full cache is emptied below
        if len(cache) + len(found) > cache_size:
            cache.clear()  # simpler than LRU, and rare: caches hold thousands of images
        cache.update(found)
    return results


def _allowed_threads() -> int:
    # Ray runs each task with OMP_NUM_THREADS set to its CPUs, as vistask.parallel's workers
    # run with 1: runs side by side would otherwise each start a thread per core.
    allowed = os.environ.get("OMP_NUM_THREADS", "")
    return int(allowed) if allowed.isdigit() and int(allowed) > 0 else os.cpu_count() or 1


@checked
class SiftExtractor:
    """SIFT keypoints and descriptors (optionally with colour), one image or a batch.

    Example:
        >>> extractor = SiftExtractor()
        >>> kps = extractor(image)                  # Keypoints of one (H, W, 3) uint8 image
        >>> batch = extractor.batch(list_of_images)  # in a thread pool
        >>> beside = SiftExtractor(panel_widths=(96, 96))  # (H, 192, 3) percepts of two views

    Args:
        contrast_threshold: SIFT's detection threshold; lower finds more, weaker keypoints.
        max_keypoints: keep at most this many strongest keypoints per image (0: all).
        color_weight: weight of the 2-D chromaticity appended to each descriptor (0: grey SIFT).
        threads: worker threads for ``batch`` (default: ``OMP_NUM_THREADS`` where it is set, as
            Ray and ``vistask.parallel``'s workers set it, else all cores). OpenCV releases the GIL.
        panel_widths: the widths in pixels, left to right, of the views that a percept shows
            side by side (empty: one view). SIFT runs on each view alone, so that no keypoint
            straddles two views, and the ``max_keypoints`` strongest of all views are kept.
            Each distinct view is extracted once and remembered (up to ``VIEW_CACHE`` views):
            a view recurs far more often than the whole percept (the mountain car's road
            window shows 641 distinct views and its gauge 887 in a run's 44,000 percepts).
        enlarge: SIFT runs on each view enlarged this many times (bilinear), which finds the
            finer details of small views; an enlarged view keeps only the keypoints whose
            descriptor lies inside it (``SUPPORT_RADIUS`` sizes from its edges), as the others
            change as the view moves. Default 1: the view as it is, every keypoint.
    """

    def __init__(
        self,
        contrast_threshold: float = 0.02,
        max_keypoints: int = 0,
        color_weight: float = 0.0,
        threads: int | None = None,
        panel_widths: Sequence[int] = (),
        enlarge: int = 1,
    ) -> None:
        if contrast_threshold <= 0 or max_keypoints < 0 or color_weight < 0:
            raise ValueError("contrast_threshold must be > 0, max_keypoints and color_weight >= 0")
        check_integers(enlarge=enlarge)
        check_at_least(1, enlarge=enlarge)
        if any(not isinstance(w, int | np.integer) or w < 1 for w in panel_widths):
            raise ValueError(f"panel_widths must be positive integers, got {panel_widths!r}")
        self.contrast_threshold = float(contrast_threshold)
        self.max_keypoints = int(max_keypoints)
        self.color_weight = float(color_weight)
        if threads is not None:
            check_at_least(1, threads=threads)
        self.threads = threads or _allowed_threads()
        self.panel_widths = tuple(int(w) for w in panel_widths)
        self.enlarge = int(enlarge)
        self._edges = np.cumsum((0, *self.panel_widths))  # the views' left and right edges
        self._local = threading.local()
        self._pool: ThreadPoolExecutor | None = None
        self._views: dict[tuple, tuple[Keypoints, np.ndarray]] = {}  # digest -> (kps, responses)

    def __getstate__(self) -> dict:
        # OpenCV detectors, thread-locals and the pool do not pickle; they are rebuilt on demand.
        state = {k: v for k, v in self.__dict__.items() if k not in ("_local", "_pool")}
        return {**state, "_views": {}}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._local = threading.local()
        self._pool = None

    @property
    def descriptor_size(self) -> int:
        """Length of a descriptor (128 for SIFT, plus 2 with colour)."""
        return 128 + (2 if self.color_weight > 0 else 0)

    def config(self) -> dict:
        """Constructor arguments that change the output (saved with vocabularies)."""
        config = {
            "contrast_threshold": self.contrast_threshold,
            "max_keypoints": self.max_keypoints,
            "color_weight": self.color_weight,
            "panel_widths": self.panel_widths,
        }
        # Only when set: vocabularies saved before it existed keep their fingerprint.
        return config if self.enlarge == 1 else {**config, "enlarge": self.enlarge}

    def _sift(self) -> cv2.SIFT:
        # One detector per thread: OpenCV objects are not documented as thread-safe.
        if not hasattr(self._local, "sift"):
            # An enlarged view drops keypoints before keeping the strongest: it counts them itself.
            strongest = self.max_keypoints if self.enlarge == 1 else 0
            self._local.sift = cv2.SIFT_create(
                nfeatures=strongest, contrastThreshold=self.contrast_threshold
            )
        return self._local.sift

    def __call__(self, image: np.ndarray) -> Keypoints:
        """Keypoints of one (H, W, 3) or (H, W) uint8 image."""
        if self.panel_widths:
            return self.batch([image])[0]
        return self._detect(check_image(image))[0]

    def _detect(self, image: np.ndarray) -> tuple[Keypoints, np.ndarray]:
        """Keypoints of one checked image, and their SIFT responses (K,)."""
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        if self.enlarge == 1:
            points, descriptors = self._sift().detectAndCompute(grey, None)
        else:
            points, descriptors = self._detect_enlarged(grey)
        if descriptors is None or not len(points):
            empty, none = np.zeros((0, self.descriptor_size), np.float32), np.zeros(0, np.float32)
            return Keypoints(np.zeros((0, 2), np.float32), empty, none), none
        xy = np.array([p.pt for p in points], np.float32).reshape(-1, 2) / self.enlarge
        scale = np.array([p.size for p in points], np.float32) / self.enlarge
        if self.color_weight > 0:
            descriptors = np.hstack([descriptors, self._chromaticity(image, xy)])
        keypoints = Keypoints(xy, descriptors.astype(np.float32, copy=False), scale)
        return keypoints, np.array([p.response for p in points], np.float32)

    def _detect_enlarged(self, grey: np.ndarray) -> tuple[list, np.ndarray | None]:
        """SIFT's keypoints (in the enlarged view's pixels) and descriptors of the grey view
        enlarged ``enlarge`` times: those whose descriptor lies inside, the strongest first."""
        h, w = grey.shape
        size = (w * self.enlarge, h * self.enlarge)
        big = cv2.resize(grey, size, interpolation=cv2.INTER_LINEAR)
        sift = self._sift()
        points = sift.detect(big, None)
        inside = [
            p
            for p in points
            if min(p.pt[0], p.pt[1], big.shape[1] - p.pt[0], big.shape[0] - p.pt[1])
            >= SUPPORT_RADIUS * p.size
        ]
        inside.sort(key=lambda p: -p.response)  # stable: ties keep SIFT's order
        if self.max_keypoints:
            inside = inside[: self.max_keypoints]
        if not inside:
            return [], None
        return sift.compute(big, inside)

    def _chromaticity(self, image: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """(K, 2) mean (r, g) chromaticity in a 7x7 box at each keypoint, scaled to SIFT's norm."""
        if image.ndim == 2:
            return np.full((len(xy), 2), SIFT_NORM * self.color_weight / 3, np.float32)
        rgb = image.astype(np.float32) + 1.0
        chroma = rgb[..., :2] / rgb.sum(axis=2, keepdims=True)
        chroma = cv2.blur(chroma, (7, 7))
        h, w = chroma.shape[:2]
        col = np.clip(np.rint(xy[:, 0]).astype(int), 0, w - 1)
        row = np.clip(np.rint(xy[:, 1]).astype(int), 0, h - 1)
        return chroma[row, col] * (SIFT_NORM * self.color_weight)

    def batch(self, images: Sequence[np.ndarray]) -> list[Keypoints]:
        """Keypoints of every image, computed in ``threads`` worker threads (order kept); with
        ``panel_widths``, each distinct view once."""
        if not self.panel_widths:
            return [kps for kps, _ in self._map(self._detect, [check_image(i) for i in images])]
        views = [view for image in images for view in self._split(check_image(image))]
        detected = extract_once(
            self._views, views, lambda todo: self._map(self._detect, todo), VIEW_CACHE
        )
        n = len(self.panel_widths)
        return [self._merge(detected[i : i + n]) for i in range(0, len(detected), n)]

    def _split(self, image: np.ndarray) -> list[np.ndarray]:
        """The views of one percept, left to right."""
        if sum(self.panel_widths) != image.shape[1]:
            raise ValueError(
                f"panel_widths {self.panel_widths} add up to {sum(self.panel_widths)} pixels, "
                f"but the image is {image.shape[1]} wide: give the widths of the views it "
                "shows side by side, or no panel_widths for one view"
            )
        return [np.ascontiguousarray(image[:, a:b]) for a, b in itertools.pairwise(self._edges)]

    def _merge(self, views: list[tuple[Keypoints, np.ndarray]]) -> Keypoints:
        """One percept's keypoints from its views' (keypoints, responses), left to right: each
        view's x moved by its left edge, the ``max_keypoints`` strongest of all kept."""
        shifts = [np.array([left, 0], np.float32) for left in self._edges[:-1]]
        xy = np.concatenate([k.xy + shift for (k, _), shift in zip(views, shifts, strict=True)])
        strongest = np.argsort(-np.concatenate([r for _, r in views]), kind="stable")
        if self.max_keypoints:
            strongest = strongest[: self.max_keypoints]
        descriptors = np.concatenate([k.descriptors for k, _ in views])
        scale = np.concatenate([k.scale for k, _ in views])
        return Keypoints(xy[strongest], descriptors[strongest], scale[strongest])

    def _map(self, detect, images: Sequence[np.ndarray]) -> list:
        """``detect`` of every image, in ``threads`` worker threads (order kept)."""
        if self.threads <= 1 or len(images) < 2 * self.threads:
            return [detect(image) for image in images]
        # The pool lives as long as the extractor, and each thread takes the next image until
        # none is left: control loops send thousands of small batches, where a pool per batch
        # and a future per image cost 5-20% of the extraction, and equal shares wait for the
        # slower one.
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="sift")
        results = [None] * len(images)
        following = itertools.count()  # the next image: each thread takes one when it is free

        def work() -> None:
            while (i := next(following)) < len(images):
                results[i] = detect(images[i])

        # The pool fills the cores; OpenCV's own threads inside each call would oversubscribe
        # them (whole runs 7-10% slower), so they are off while the pool works.
        opencv_threads = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            for done in [self._pool.submit(work) for _ in range(self.threads)]:
                done.result()
        finally:
            cv2.setNumThreads(opencv_threads)
        return results


@checked
def choose_enlarge(
    views: Sequence[np.ndarray],
    contrast_threshold: float,
    max_keypoints: int,
    panel_widths: Sequence[int] = (),
) -> int:
    """The ``enlarge`` that ``"auto"`` means for these views: 2 where their shorter side (of
    each panel, with ``panel_widths``) is under ``SMALL_VIEW`` pixels and ``ENLARGE_SAMPLE`` of
    them, evenly spaced, keep at least as many keypoints a view enlarged twice as they are;
    else 1 (smooth views keep fewer keypoints enlarged).

    Example:
        >>> choose_enlarge(first_database_percepts, 0.005, 24)  # 32 x 32 photo views
        2
    """
    height, width = np.asarray(views[0]).shape[:2]
    if min(height, *(panel_widths or (width,))) >= SMALL_VIEW:
        return 1
    picked = np.linspace(0, len(views) - 1, min(ENLARGE_SAMPLE, len(views))).astype(int)
    sample = [views[i] for i in picked]

    def kept(factor: int) -> float:
        sift = SiftExtractor(
            contrast_threshold, max_keypoints, panel_widths=panel_widths, enlarge=factor
        )
        return float(np.mean([len(k) for k in sift.batch(sample)]))

    return 2 if kept(2) >= kept(1) else 1
