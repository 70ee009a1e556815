"""Local descriptors at interest points, from OpenCV.

SIFT on the grey image gives keypoints that follow the tapestry as the window slides: the same
photo detail yields nearly the same descriptor in every percept that shows it, which is what
"feature f is present" needs. The paper used colour differential invariants; ``color_weight``
appends the mean chromaticity around each keypoint to the SIFT descriptor in the same spirit.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

SIFT_NORM = 512.0  # OpenCV scales SIFT descriptors to about this Euclidean norm


@dataclass
class Keypoints:
    """Keypoints of one image: ``xy`` (K, 2) pixel (x, y), ``descriptors`` (K, D) and
    ``scale`` (K,) (the diameter of the keypoint's neighbourhood, in pixels), float32."""

    xy: np.ndarray
    descriptors: np.ndarray
    scale: np.ndarray

    def __len__(self) -> int:
        return len(self.xy)


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
            f"space {space}; render an env to pixels with gymnasium.wrappers.AddRenderObservation"
        )


def _allowed_threads() -> int:
    # Ray runs each task with OMP_NUM_THREADS set to its CPUs, as vistask.parallel's workers
    # run with 1: runs side by side would otherwise each start a thread per core.
    allowed = os.environ.get("OMP_NUM_THREADS", "")
    return int(allowed) if allowed.isdigit() and int(allowed) > 0 else os.cpu_count() or 1


class SiftExtractor:
    """SIFT keypoints and descriptors (optionally with colour), one image or a batch.

    Example:
        >>> extractor = SiftExtractor()
        >>> kps = extractor(image)                  # Keypoints of one (H, W, 3) uint8 image
        >>> batch = extractor.batch(list_of_images)  # in a thread pool

    Args:
        contrast_threshold: SIFT's detection threshold; lower finds more, weaker keypoints.
        max_keypoints: keep at most this many strongest keypoints per image (0: all).
        color_weight: weight of the 2-D chromaticity appended to each descriptor (0: grey SIFT).
        threads: worker threads for ``batch`` (default: ``OMP_NUM_THREADS`` where it is set, as
            Ray and ``vistask.parallel``'s workers set it, else all cores). OpenCV releases the GIL.
    """

    def __init__(
        self,
        contrast_threshold: float = 0.02,
        max_keypoints: int = 0,
        color_weight: float = 0.0,
        threads: int | None = None,
    ) -> None:
        if contrast_threshold <= 0 or max_keypoints < 0 or color_weight < 0:
            raise ValueError("contrast_threshold must be > 0, max_keypoints and color_weight >= 0")
        self.contrast_threshold = float(contrast_threshold)
        self.max_keypoints = int(max_keypoints)
        self.color_weight = float(color_weight)
        self.threads = threads or _allowed_threads()
        self._local = threading.local()
        self._pool: ThreadPoolExecutor | None = None

    def __getstate__(self) -> dict:
        # OpenCV detectors, thread-locals and the pool do not pickle; they are rebuilt on demand.
        return {k: v for k, v in self.__dict__.items() if k not in ("_local", "_pool")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._local = threading.local()
        self._pool = None

    @property
    def descriptor_size(self) -> int:
        return 128 + (2 if self.color_weight > 0 else 0)

    def config(self) -> dict:
        """Constructor arguments that change the output (saved with vocabularies)."""
        return {
            "contrast_threshold": self.contrast_threshold,
            "max_keypoints": self.max_keypoints,
            "color_weight": self.color_weight,
        }

    def _sift(self) -> cv2.SIFT:
        # One detector per thread: OpenCV objects are not documented as thread-safe.
        if not hasattr(self._local, "sift"):
            self._local.sift = cv2.SIFT_create(
                nfeatures=self.max_keypoints, contrastThreshold=self.contrast_threshold
            )
        return self._local.sift

    def __call__(self, image: np.ndarray) -> Keypoints:
        image = check_image(image)
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        points, descriptors = self._sift().detectAndCompute(grey, None)
        if descriptors is None:
            empty = np.zeros((0, self.descriptor_size), np.float32)
            return Keypoints(np.zeros((0, 2), np.float32), empty, np.zeros(0, np.float32))
        xy = np.array([p.pt for p in points], np.float32).reshape(-1, 2)
        scale = np.array([p.size for p in points], np.float32)
        if self.color_weight > 0:
            descriptors = np.hstack([descriptors, self._chromaticity(image, xy)])
        return Keypoints(xy, descriptors.astype(np.float32, copy=False), scale)

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
        """Keypoints of every image, computed in ``threads`` worker threads (order kept)."""
        if self.threads <= 1 or len(images) < 2 * self.threads:
            return [self(image) for image in images]
        # The pool lives as long as the extractor, and each thread takes one contiguous share:
        # control loops send thousands of small batches, where a pool per batch and a future
        # per image cost 5-20% of the extraction.
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="sift")
        shares = np.array_split(np.arange(len(images)), self.threads)
        # The pool fills the cores; OpenCV's own threads inside each call would oversubscribe
        # them (whole runs 7-10% slower), so they are off while the pool works.
        opencv_threads = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            parts = list(self._pool.map(lambda share: [self(images[i]) for i in share], shares))
        finally:
            cv2.setNumThreads(opencv_threads)
        return [keypoints for part in parts for keypoints in part]
