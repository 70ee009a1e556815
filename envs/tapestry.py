"""A montage of real photographs that ship inside installed packages (never downloaded), or
one of them whole.

The paper's maze percepts were windows of a tiled montage of COIL-100 images. COIL-100 is not
shipped by any package, so the tapestry is built from the colour photographs bundled with
scikit-image, robosuite (object textures) and matplotlib (sample data). Each tile is a crop of
one photograph at a random position and scale, chosen by a seeded generator: the same seed
always gives the same tapestry.
"""

from __future__ import annotations

import importlib.util
from functools import cache
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

# (package, path inside the package) of colour photographs; all ship inside the wheels.
PHOTOS: tuple[tuple[str, str], ...] = (
    ("skimage", "data/astronaut.png"),
    ("skimage", "data/chelsea.png"),
    ("skimage", "data/coffee.png"),
    ("skimage", "data/rocket.jpg"),
    ("skimage", "data/hubble_deep_field.jpg"),
    ("skimage", "data/ihc.png"),
    ("skimage", "data/retina.jpg"),
    ("skimage", "data/motorcycle_left.png"),
    ("skimage", "data/color.png"),
    ("matplotlib", "mpl-data/sample_data/grace_hopper.jpg"),
    ("robosuite", "models/assets/textures/bread.png"),
    ("robosuite", "models/assets/textures/can.png"),
    ("robosuite", "models/assets/textures/cereal.png"),
    ("robosuite", "models/assets/textures/lemon.png"),
    ("robosuite", "models/assets/textures/soda.png"),
)


def _package_dir(package: str) -> Path:
    # find_spec locates the package without importing it (importing robosuite is slow and noisy).
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        raise ModuleNotFoundError(f"package {package!r} is needed for the tapestry photographs")
    return Path(next(iter(spec.submodule_search_locations)))


@cache
def load_photo(index: int) -> np.ndarray:
    """Photograph ``PHOTOS[index]`` as an (H, W, 3) uint8 RGB array (alpha dropped)."""
    package, relative = PHOTOS[index]
    path = _package_dir(package) / relative
    if not path.is_file():
        raise FileNotFoundError(f"bundled photograph {path} is missing; reinstall {package}")
    with Image.open(path) as photo:
        image = np.asarray(photo.convert("RGB"))
    image.setflags(write=False)
    return image


def make_tapestry(height: int, width: int, tile: int = 96, seed: int = 0) -> np.ndarray:
    """Tile an (height, width) canvas with random crops of the bundled photographs.

    Args:
        height, width: canvas size in pixels.
        tile: side of a square tile in pixels.
        seed: the same seed always gives the same tapestry.

    Returns:
        (height, width, 3) uint8 RGB image.
    """
    if height <= 0 or width <= 0 or tile <= 0:
        raise ValueError(f"tapestry size and tile must be positive, got {height}x{width}, {tile}")
    rng = np.random.default_rng(seed)
    rows, cols = -(-height // tile), -(-width // tile)
    canvas = np.zeros((rows * tile, cols * tile, 3), np.uint8)
    # Tiles come from disjoint quadrants of the photos: no photo detail appears in two tiles,
    # so aliasing comes from the task (similar-looking places), not from repeated content.
    regions = [(p, qy, qx) for p in range(len(PHOTOS)) for qy in range(2) for qx in range(2)]
    order = rng.permutation(len(regions))
    for k in range(rows * cols):
        photo_index, qy, qx = regions[order[k % len(regions)]]
        photo = load_photo(photo_index)
        h, w = photo.shape[0] // 2, photo.shape[1] // 2
        side = int(rng.uniform(0.7, 1.0) * min(h, w))
        y0 = qy * h + rng.integers(0, h - side + 1)
        x0 = qx * w + rng.integers(0, w - side + 1)
        crop = photo[y0 : y0 + side, x0 : x0 + side]
        r, c = divmod(k, cols)
        canvas[r * tile : (r + 1) * tile, c * tile : (c + 1) * tile] = cv2.resize(
            crop, (tile, tile), interpolation=cv2.INTER_AREA
        )
    return np.ascontiguousarray(canvas[:height, :width])


def photo_names() -> list[str]:
    """Names of the bundled photographs (file stems), for ``photo_canvas``."""
    return [Path(relative).stem for _, relative in PHOTOS]


def photo_canvas(name: str, side: int) -> np.ndarray:
    """One bundled photograph as a (side, side, 3) uint8 canvas: its central square, resized.

    The paper's real-image navigation (Fig. 5) moves over one large photograph. The largest
    bundled photograph with texture everywhere is ``hubble_deep_field`` (872 x 1000, a real
    photograph: galaxies of every shape and colour, 12.7 SIFT keypoints per 64-pixel window
    on average).
    """
    names = photo_names()
    if name not in names:
        raise ValueError(f"no bundled photograph {name!r}; choose one of {', '.join(names)}")
    if side <= 0:
        raise ValueError(f"canvas side must be positive, got {side}")
    photo = load_photo(names.index(name))
    h, w = photo.shape[:2]
    square = min(h, w)
    y0, x0 = (h - square) // 2, (w - square) // 2
    crop = photo[y0 : y0 + square, x0 : x0 + square]
    interpolation = cv2.INTER_AREA if side < square else cv2.INTER_CUBIC
    return np.ascontiguousarray(cv2.resize(crop, (side, side), interpolation=interpolation))
