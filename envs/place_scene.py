"""The MuJoCo town of place navigation and its views: buildings and walls with photo-textured
faces, the jittered camera, rendering, and the banks of views rendered once and cached.

Every facade and wall face shows its own crop of a photograph bundled with an installed
package (``vistask.envs.tapestry.PHOTOS``), so that SIFT finds texture on it. Rendering
dominates the cost, so every state's views are rendered once into a bank from fixed jitter
seeds, kept in memory and on disk under ``$VISTASK_CACHE_DIR`` (default
``~/.cache/vistask``), keyed by a hash of the scene, the jitter, the seeds and the renderer's
version. Rendering uses MUJOCO_GL (set to "egl" here when unset).
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import os
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2
import mujoco
import numpy as np

from vistask.checks import checked
from vistask.envs.place_world import HEADING_STEPS, HEADING_VECTORS, PlaceWorld, check_int
from vistask.envs.tapestry import PHOTOS, load_photo

logger = logging.getLogger(__name__)

# Bump when a change of this module changes the pixels of a view: it is part of the cache key.
RENDER_VERSION = 1
# Training banks use jitter seeds 0..views_per_state-1, held-out views seeds from here on.
TEST_SEED_OFFSET = 1_000_000
# Held-out views a state. A policy's return on held-out views hangs on which of a state's views
# it misreads: on one tree, 8 views a state gave 0.77 of the oracle's return, 32 and 128 gave
# 0.87 (docs/results.md, "Place navigation").
TEST_VIEWS_PER_STATE = 32
FACADE_HEIGHT = 4.5  # photo-textured part of a building, from the ground (what the camera sees)
WALL_HEIGHT = 3.0  # walls that close streets
WALL_HALF_THICKNESS = 0.08
TOWN_WALL_HEIGHT = 4.0
TEXTURE_HEIGHT = 128  # pixels of a face's texture along its height
BUILDING_HALF = (0.18, 0.32)  # range of a building's half width and depth, in place spacings
BUILDING_HEIGHT = (4.0, 10.0)  # metres
REGION_SIDE = 64  # pixels at which photo regions are scored for texture
MIN_REGION_KEYPOINTS = 12  # SIFT keypoints of a region at REGION_SIDE to texture a facade


@functools.cache
def photo_regions(k: int) -> list[tuple[int, int, int, int]]:
    """Every photo of ``PHOTOS`` cut into k x k regions: (photo, row, column, texture score),
    the score being the number of SIFT keypoints of the region at ``REGION_SIDE`` pixels square."""
    sift = cv2.SIFT_create(contrastThreshold=0.02)
    regions = []
    for p in range(len(PHOTOS)):
        grey = cv2.cvtColor(load_photo(p), cv2.COLOR_RGB2GRAY)
        h, w = grey.shape[0] // k, grey.shape[1] // k
        for qy in range(k):
            for qx in range(k):
                region = grey[qy * h : (qy + 1) * h, qx * w : (qx + 1) * w]
                small = cv2.resize(region, (REGION_SIDE, REGION_SIDE), interpolation=cv2.INTER_AREA)
                regions.append((p, qy, qx, len(sift.detect(small, None))))
    return regions


# -- the scene -----------------------------------------------------------------------------------
@checked
@dataclass(frozen=True)
class Jitter:
    """Ranges of the random changes of every view, each drawn uniformly.

    Args:
        offset: largest camera offset from the place's centre along x and along y (metres).
        yaw: largest heading change, degrees either way.
        pitch: (low, high) camera pitch in degrees (positive looks up).
        height: (low, high) camera height in metres.
        sun_azimuth: (low, high) direction of the sun in degrees, counterclockwise from east.
        sun_elevation: (low, high) elevation of the sun in degrees.
        sun: (low, high) diffuse intensity of the sun.
        ambient: (low, high) ambient light intensity.
    """

    offset: float = 0.4
    yaw: float = 8.0
    pitch: tuple[float, float] = (-2.0, 6.0)
    height: tuple[float, float] = (1.4, 1.9)
    sun_azimuth: tuple[float, float] = (0.0, 360.0)
    sun_elevation: tuple[float, float] = (25.0, 75.0)
    sun: tuple[float, float] = (0.35, 0.75)
    ambient: tuple[float, float] = (0.3, 0.55)

    def __post_init__(self) -> None:
        if not (self.offset >= 0 and self.yaw >= 0):
            raise ValueError(f"jitter offset and yaw must be >= 0, got {self.offset}, {self.yaw}")
        for name in ("pitch", "height", "sun_azimuth", "sun_elevation", "sun", "ambient"):
            low, high = getattr(self, name)
            if not low <= high:
                raise ValueError(f"jitter {name} must be a (low, high) range, got {(low, high)}")
        if self.height[0] <= 0 or self.sun[0] < 0 or self.ambient[0] < 0:
            raise ValueError("jitter height must be positive and light intensities >= 0")

    @classmethod
    def none(cls) -> Jitter:
        """No jitter: every view of a state is the same (tests, pictures)."""
        return cls(
            offset=0.0,
            yaw=0.0,
            pitch=(2.0, 2.0),
            height=(1.6, 1.6),
            sun_azimuth=(120.0, 120.0),
            sun_elevation=(50.0, 50.0),
            sun=(0.55, 0.55),
            ambient=(0.4, 0.4),
        )


@dataclass(frozen=True)
class Facade:
    """A photo-textured vertical rectangle facing a street.

    Attributes:
        x, y: centre of its base line (metres).
        normal: heading (0..3) that it faces.
        width, height: metres.
        texture: index of its texture in ``PlaceScene.textures``.
    """

    x: float
    y: float
    normal: int
    width: float
    height: float
    texture: int


class PlaceScene:
    """The MuJoCo model of a ``PlaceWorld``'s town and its jittered camera views.

    Buildings fill the blocks between the streets with random footprints and heights; their
    lower ``FACADE_HEIGHT`` metres, the walls that close streets and the town wall show photo
    crops, a distinct crop of a distinct photo region for every face.

    Example:
        >>> scene = PlaceScene(PlaceWorld())
        >>> views = scene.render(np.array([[0, 1], [7, 2]]), [0, 1])  # (2, 2, 80, 80, 3) uint8

    Args:
        world: the place graph (its closed streets get walls; its ``layout_seed`` draws the
            buildings and the photo crops).
        image_size: side of the square views in pixels.
        spacing: metres between neighbouring places.
        fovy: the camera's field of view in degrees.
        jitter: ranges of the random changes of each view.

    Attributes:
        buildings: (B, 5) x, y of the centre, half width (x), half depth (y), height.
        facades: every photo-textured face.
        walls: (x0, y0, x1, y1) base line of each wall that closes a street.
        textures: (H, W, 3) uint8 texture of each facade.
        xml: the MJCF of the town; ``assets`` its texture PNGs by file name.
        key: hash of everything that decides the pixels (the disk cache's key).
    """

    def __init__(
        self,
        world: PlaceWorld,
        image_size: int = 80,
        spacing: float = 6.0,
        fovy: float = 75.0,
        jitter: Jitter | None = None,
    ) -> None:
        self.world = world
        self.image_size = check_int("image_size", image_size, 16)
        if not spacing >= 4.0:
            raise ValueError(f"spacing must be >= 4 metres (streets need room), got {spacing}")
        if not 10.0 <= fovy <= 120.0:
            raise ValueError(f"fovy must be in [10, 120] degrees, got {fovy}")
        self.spacing, self.fovy = float(spacing), float(fovy)
        self.jitter = jitter or Jitter()
        self.street_half = (0.5 - BUILDING_HALF[1]) * self.spacing  # of the narrowest street
        if self.jitter.offset >= self.street_half:
            raise ValueError(
                f"jitter offset must stay below the half width of the narrowest street "
                f"({self.street_half:.2f} m), got {self.jitter.offset}"
            )
        rng = np.random.default_rng([world.layout_seed, 1])
        self.buildings = self._draw_buildings(rng)
        self.facades: list[Facade] = []
        self.walls: list[tuple[float, float, float, float]] = []
        self._place_facades()
        self.textures = self._draw_textures(rng)
        self.xml, self.assets = self._mjcf()
        self.key = self._key()
        self._model: mujoco.MjModel | None = None

    # -- geometry ----------------------------------------------------------------------------
    def _draw_buildings(self, rng: np.random.Generator) -> np.ndarray:
        s, w = self.spacing, self.world
        rows, cols = np.divmod(np.arange((w.rows - 1) * (w.cols - 1)), w.cols - 1)
        n = len(rows)
        half = rng.uniform(*BUILDING_HALF, size=(n, 2)) * s
        height = rng.uniform(*BUILDING_HEIGHT, size=n)
        return np.column_stack([(cols + 0.5) * s, -(rows + 0.5) * s, half, height])

    def _block_gap(self, row: int, col: int, axis: int) -> float:
        """Distance from a street's centre line to the block (row, col)'s building along
        ``axis`` (0: x, 1: y), or to the town wall when the block is outside the town."""
        w = self.world
        if 0 <= row < w.rows - 1 and 0 <= col < w.cols - 1:
            return self.spacing / 2 - self.buildings[row * (w.cols - 1) + col, 2 + axis]
        return self.spacing / 2

    def _place_facades(self) -> None:
        s, eps = self.spacing, 0.01  # facades stand 1 cm off their box: no z-fighting
        for x, y, hx, hy, h in self.buildings:
            height = min(h, FACADE_HEIGHT)
            for normal, (dx, dy) in enumerate(HEADING_VECTORS):
                cx, cy = x + dx * (hx + eps), y + dy * (hy + eps)
                width = 2 * (hy if dx else hx)
                self._add(cx, cy, normal, width, height)
        w = self.world
        for place in range(w.n_places):
            row, col = divmod(place, w.cols)
            ((px, py),) = w.place_xy([place], s)
            for heading in (1, 2):  # each street once: east and south of the place
                nr, nc = row + HEADING_STEPS[heading, 0], col + HEADING_STEPS[heading, 1]
                if nr >= w.rows or nc >= w.cols or w.open[place, heading]:
                    continue
                if heading == 1:  # wall across an east-west street, between blocks N and S
                    wx = px + s / 2
                    north = self._block_gap(row - 1, col, 1)
                    south = self._block_gap(row, col, 1)
                    width, centre = north + south + 0.1, py + (north - south) / 2
                    self.walls.append((wx, centre - width / 2, wx, centre + width / 2))
                    self._add(wx - WALL_HALF_THICKNESS, centre, 3, width, WALL_HEIGHT)
                    self._add(wx + WALL_HALF_THICKNESS, centre, 1, width, WALL_HEIGHT)
                else:  # wall across a north-south street, between blocks W and E
                    wy = py - s / 2
                    west = self._block_gap(row, col - 1, 0)
                    east = self._block_gap(row, col, 0)
                    width, centre = west + east + 0.1, px + (east - west) / 2
                    self.walls.append((centre - width / 2, wy, centre + width / 2, wy))
                    self._add(centre, wy + WALL_HALF_THICKNESS, 0, width, WALL_HEIGHT)
                    self._add(centre, wy - WALL_HALF_THICKNESS, 2, width, WALL_HEIGHT)
            for heading in range(4):  # the town wall, one face per border place and side
                nr, nc = row + HEADING_STEPS[heading, 0], col + HEADING_STEPS[heading, 1]
                if 0 <= nr < w.rows and 0 <= nc < w.cols:
                    continue
                dx, dy = HEADING_VECTORS[heading]
                self._add(px + dx * s / 2, py + dy * s / 2, (heading + 2) % 4, s, TOWN_WALL_HEIGHT)

    def _add(self, x: float, y: float, normal: int, width: float, height: float) -> None:
        self.facades.append(Facade(x, y, normal, width, height, len(self.facades)))

    def _draw_textures(self, rng: np.random.Generator) -> list[np.ndarray]:
        """One crop per facade, of the facade's aspect, each from its own photo region: the
        photos are cut into k x k regions, k as small as gives twice as many regions as
        facades, and the facades get the regions with the most SIFT keypoints (skies, flat
        colour patches and smooth fruit skins have few), taken from every photo in turn."""
        k = int(np.ceil(np.sqrt(2 * len(self.facades) / len(PHOTOS))))
        regions = photo_regions(k)
        # Each photo's best region first, then each photo's second best, ...: the most
        # textured regions without letting the most textured photo take every facade.
        rank = np.empty(len(regions), dtype=np.int64)
        for p in range(len(PHOTOS)):
            mine = np.flatnonzero([region[0] == p for region in regions])
            rank[mine[np.argsort([-regions[i][3] for i in mine], kind="stable")]] = range(len(mine))
        scores = np.array([region[3] for region in regions])
        order = np.lexsort((-scores, rank))
        textured = order[scores[order] >= MIN_REGION_KEYPOINTS]
        best = (textured if len(textured) >= len(self.facades) else order)[: len(self.facades)]
        textures = []
        for facade, r in zip(self.facades, rng.permutation(best), strict=True):
            photo_index, qy, qx, _ = regions[r]
            photo = load_photo(photo_index)
            h, w = photo.shape[0] // k, photo.shape[1] // k
            aspect = facade.width / facade.height
            ch = int(rng.uniform(0.75, 1.0) * min(h, w / aspect))
            cw = max(1, int(ch * aspect))
            y0 = qy * h + rng.integers(0, h - ch + 1)
            x0 = qx * w + rng.integers(0, w - cw + 1)
            width = int(np.clip(round(TEXTURE_HEIGHT * aspect), 16, 4 * TEXTURE_HEIGHT))
            textures.append(
                cv2.resize(
                    photo[y0 : y0 + ch, x0 : x0 + cw],
                    (width, TEXTURE_HEIGHT),
                    interpolation=cv2.INTER_AREA,
                )
            )
        return textures

    # -- MuJoCo model ------------------------------------------------------------------------
    def _mjcf(self) -> tuple[str, dict[str, bytes]]:
        w, s = self.world, self.spacing
        span = np.array([(w.cols - 1) * s, (w.rows - 1) * s]) + s
        centre = np.array([(w.cols - 1) * s / 2, -(w.rows - 1) * s / 2])
        extent = float(np.linalg.norm(span))
        assets, textures, geoms = {}, [], []
        for facade, texture in zip(self.facades, self.textures, strict=True):
            name = f"face{facade.texture}"
            ok, png = cv2.imencode(".png", texture[..., ::-1])
            if not ok:
                raise RuntimeError(f"could not encode the texture of {name}")
            assets[f"{name}.png"] = png.tobytes()
            textures.append(
                f'<texture name="{name}" type="2d" file="{name}.png"/>'
                f'<material name="{name}" texture="{name}" texrepeat="1 1" texuniform="false"'
                ' specular="0.05" shininess="0.1"/>'
            )
            # The plane's x axis runs to the right of a viewer facing it, y up, z (its normal)
            # towards the viewer: the photo shows upright and unmirrored.
            nx, ny = HEADING_VECTORS[facade.normal]
            geoms.append(
                f'<geom type="plane" material="{name}" '
                f'pos="{facade.x:.4f} {facade.y:.4f} {facade.height / 2:.4f}" '
                f'size="{facade.width / 2:.4f} {facade.height / 2:.4f} 1" '
                f'xyaxes="{-ny:g} {nx:g} 0 0 0 1"/>'
            )
        # Above the facades, buildings are plain concrete of varied brightness.
        greys = np.random.default_rng([w.layout_seed, 2]).uniform(0.45, 0.8, len(self.buildings))
        for (x, y, hx, hy, h), grey in zip(self.buildings, greys, strict=True):
            geoms.append(
                f'<geom type="box" pos="{x:.4f} {y:.4f} {h / 2:.4f}" '
                f'size="{hx:.4f} {hy:.4f} {h / 2:.4f}" '
                f'rgba="{grey:.3f} {0.96 * grey:.3f} {0.9 * grey:.3f} 1"/>'
            )
        for x0, y0, x1, y1 in self.walls:
            half = (x1 - x0) / 2 + WALL_HALF_THICKNESS, (y1 - y0) / 2 + WALL_HALF_THICKNESS
            geoms.append(
                f'<geom type="box" pos="{(x0 + x1) / 2:.4f} {(y0 + y1) / 2:.4f} '
                f'{WALL_HEIGHT / 2:.4f}" size="{half[0] - 0.01:.4f} {half[1] - 0.01:.4f} '
                f'{WALL_HEIGHT / 2:.4f}" rgba="0.55 0.53 0.5 1"/>'
            )
        ground = f"{span[0] * 2:.2f} {span[1] * 2:.2f} 1"
        size = self.image_size
        xml = f"""<mujoco model="place_navigation">
  <visual>
    <global offwidth="{size}" offheight="{size}"/>
    <headlight ambient="0.3 0.3 0.3" diffuse="0 0 0" specular="0 0 0"/>
    <map znear="{0.05 / extent:.6f}" zfar="4"/>
  </visual>
  <statistic center="{centre[0]:.3f} {centre[1]:.3f} 0" extent="{extent:.3f}"/>
  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.35 0.55 0.9"
             rgb2="0.9 0.93 1" width="128" height="128"/>
    {"".join(textures)}
  </asset>
  <worldbody>
    <light name="sun" directional="true" castshadow="false" pos="0 0 50" dir="0 0 -1"
           diffuse="0.7 0.7 0.7" specular="0 0 0"/>
    <geom type="plane" pos="{centre[0]:.3f} {centre[1]:.3f} 0" size="{ground}"
          rgba="0.42 0.41 0.38 1"/>
    {"".join(geoms)}
    <camera name="eye" pos="0 0 1.6" fovy="{self.fovy:g}"/>
  </worldbody>
</mujoco>"""
        return xml, assets

    def _key(self) -> str:
        digest = hashlib.sha256()
        settings = {
            "render_version": RENDER_VERSION,
            "mujoco": mujoco.__version__,
            "gl": os.environ.get("MUJOCO_GL", ""),
            "image_size": self.image_size,
            "jitter": asdict(self.jitter),
        }
        digest.update(json.dumps(settings, sort_keys=True).encode())
        digest.update(self.xml.encode())
        for name in sorted(self.assets):
            digest.update(name.encode() + self.assets[name])
        return digest.hexdigest()

    @property
    def model(self) -> mujoco.MjModel:
        """The compiled MuJoCo model of the town (built on first use)."""
        if self._model is None:
            self._model = mujoco.MjModel.from_xml_string(self.xml, self.assets)
        return self._model

    # -- views -------------------------------------------------------------------------------
    def camera_pose(self, state, seed: int) -> dict[str, np.ndarray | float]:
        """The jittered camera and light of view ``seed`` of ``state`` (place, heading):
        ``eye`` (3,), ``forward`` (3,) unit, ``sun`` (3,) unit light direction, ``sun_level``,
        ``ambient``. The same (state, seed) always gives the same pose."""
        ((place, heading),) = self.world.check_states(state, "state")
        j = self.jitter
        rng = np.random.default_rng([int(seed), int(place), int(heading), 7])
        dx, dy = rng.uniform(-1.0, 1.0, 2) * j.offset
        yaw = np.pi / 2 * (1 - heading) + np.radians(rng.uniform(-1.0, 1.0) * j.yaw)
        pitch = np.radians(rng.uniform(*j.pitch))
        height = rng.uniform(*j.height)
        azimuth = np.radians(rng.uniform(*j.sun_azimuth))
        elevation = np.radians(rng.uniform(*j.sun_elevation))
        sun_level, ambient = rng.uniform(*j.sun), rng.uniform(*j.ambient)
        ((x, y),) = self.world.place_xy([place], self.spacing)
        forward = np.array(
            [np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)]
        )
        sun = -np.array(
            [
                np.cos(elevation) * np.cos(azimuth),
                np.cos(elevation) * np.sin(azimuth),
                np.sin(elevation),
            ]
        )
        return {
            "eye": np.array([x + dx, y + dy, height]),
            "forward": forward,
            "sun": sun,
            "sun_level": float(sun_level),
            "ambient": float(ambient),
        }

    def render(self, states, seeds: Sequence[int]) -> np.ndarray:
        """Views of every state for every seed.

        Args:
            states: (N, 2) (place, heading).
            seeds: jitter seeds (S of them).

        Returns:
            (N, S, H, W, 3) uint8 views, H = W = ``image_size``.
        """
        states = self.world.check_states(states)
        seeds = [int(s) for s in seeds]
        size = self.image_size
        out = np.empty((len(states), len(seeds), size, size, 3), np.uint8)
        if out.size == 0:
            return out
        model = self.model
        data = mujoco.MjData(model)
        try:
            renderer = mujoco.Renderer(model, size, size)
        except mujoco.FatalError as error:
            raise RuntimeError(
                f"MuJoCo could not open an OpenGL context ({error}); without a display, set "
                "MUJOCO_GL=egl (or osmesa) before anything imports mujoco"
            ) from error
        try:
            quat = np.empty(4)
            for i, state in enumerate(states):
                for k, seed in enumerate(seeds):
                    pose = self.camera_pose(state, seed)
                    forward = pose["forward"]
                    right = np.cross(forward, [0.0, 0.0, 1.0])
                    right /= np.linalg.norm(right)
                    up = np.cross(right, forward)
                    # MuJoCo cameras look along their -z with y up.
                    mujoco.mju_mat2Quat(quat, np.column_stack([right, up, -forward]).ravel())
                    model.cam_pos[0], model.cam_quat[0] = pose["eye"], quat
                    model.light_dir[0] = pose["sun"]
                    model.light_diffuse[0] = pose["sun_level"]
                    model.vis.headlight.ambient[:] = pose["ambient"]
                    mujoco.mj_kinematics(model, data)
                    mujoco.mj_camlight(model, data)
                    renderer.update_scene(data, camera=0)
                    renderer.render(out=out[i, k])
        finally:
            renderer.close()
        return out


# -- view banks ----------------------------------------------------------------------------------
_BANKS: dict[str, np.ndarray] = {}  # in-memory banks of this process, by cache key


def default_cache_dir() -> Path:
    """``$VISTASK_CACHE_DIR``, else ``~/.cache/vistask``."""
    return Path(os.environ.get("VISTASK_CACHE_DIR") or "~/.cache/vistask").expanduser()


def clear_memory_cache() -> None:
    """Forget the view banks held in memory (the disk cache stays)."""
    _BANKS.clear()


def view_bank(
    scene: PlaceScene,
    seeds: Sequence[int],
    cache_dir: str | os.PathLike | None = None,
    disk_cache: bool = True,
) -> np.ndarray:
    """Views of every state of ``scene.world`` for every jitter seed, from memory, the disk
    cache, or rendered (and then cached).

    Returns:
        (states, len(seeds), H, W, 3) uint8, read-only; state index ``place * 4 + heading``.
    """
    seeds = [int(s) for s in seeds]
    key = hashlib.sha256(f"{scene.key}:{seeds}".encode()).hexdigest()[:32]
    if key in _BANKS:
        return _BANKS[key]
    n_states, size = scene.world.n_states, scene.image_size
    shape = (n_states, len(seeds), size, size, 3)
    path = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
    path = path / "place_navigation" / f"views-{key}.npy"
    bank = None
    if disk_cache and path.is_file():
        try:
            bank = np.load(path)
        except (OSError, ValueError) as error:  # a damaged file: render again
            logger.warning("ignoring unreadable view cache %s: %s", path, error)
        if bank is not None and (bank.shape != shape or bank.dtype != np.uint8):
            logger.warning("ignoring view cache %s of shape %s", path, bank.shape)
            bank = None
    if bank is None:
        start = time.perf_counter()
        bank = scene.render(PlaceWorld.states_of(np.arange(n_states)), seeds)
        seconds = time.perf_counter() - start
        logger.info(
            "rendered %d views in %.1f s (%.1f ms a view)",
            n_states * len(seeds),
            seconds,
            1000 * seconds / max(1, n_states * len(seeds)),
        )
        if disk_cache:
            _save_atomically(path, bank)
    bank.setflags(write=False)
    _BANKS[key] = bank
    return bank


def _save_atomically(path: Path, array: np.ndarray) -> None:
    """Write ``array`` to ``path`` through a temporary file and a rename, so that a reader in
    another process sees either no file or the whole file."""
    temporary = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".tmp", delete=False) as file:
            temporary = Path(file.name)
            np.save(file, array)
        temporary.chmod(0o644)  # temporary files are private; the cache is not
        os.replace(temporary, path)
    except OSError as error:  # a read-only home still gets its views, only slower next time
        logger.warning("could not cache views at %s: %s", path, error)
        if temporary is not None:
            temporary.unlink(missing_ok=True)


# -- pictures --------------------------------------------------------------------------------------
def draw_town(
    world: PlaceWorld, scene: PlaceScene, state=None, pixels_per_metre: float = 12.0
) -> np.ndarray:
    """Top-down map of the town: buildings (their photo-textured faces in each photo's mean
    colour), the town wall, closed streets (red bars), open streets (thin lines), places
    (numbered), the goal place (green) and, given a state, the agent (blue arrow).

    Returns:
        (H, W, 3) uint8 RGB image, north up.
    """
    s, ppm, margin = scene.spacing, float(pixels_per_metre), 10
    if not ppm > 0:
        raise ValueError(f"pixels_per_metre must be positive, got {pixels_per_metre}")
    width = int(np.ceil(world.cols * s * ppm)) + 2 * margin
    height = int(np.ceil(world.rows * s * ppm)) + 2 * margin

    def pixel(x: float, y: float) -> tuple[int, int]:
        return round((x + s / 2) * ppm) + margin, round((-y + s / 2) * ppm) + margin

    image = np.full((height, width, 3), 200, np.uint8)
    cv2.rectangle(
        image,
        pixel(-s / 2, s / 2),
        pixel(world.cols * s - s / 2, -world.rows * s + s / 2),
        (120, 120, 120),
        3,
    )
    for x, y, hx, hy, _ in scene.buildings:
        cv2.rectangle(image, pixel(x - hx, y + hy), pixel(x + hx, y - hy), (95, 95, 95), -1)
    for facade, texture in zip(scene.facades, scene.textures, strict=True):
        colour = tuple(int(c) for c in texture.reshape(-1, 3).mean(axis=0))
        nx, ny = HEADING_VECTORS[facade.normal]
        half = facade.width / 2
        a = pixel(facade.x - ny * half, facade.y + nx * half)
        b = pixel(facade.x + ny * half, facade.y - nx * half)
        cv2.line(image, a, b, colour, max(2, round(0.25 * ppm)))
    xy = world.place_xy(np.arange(world.n_places), s)
    for place in range(world.n_places):
        row, col = divmod(place, world.cols)
        for heading in (1, 2):
            nr, nc = row + HEADING_STEPS[heading, 0], col + HEADING_STEPS[heading, 1]
            if nr < world.rows and nc < world.cols and world.open[place, heading]:
                a, b = pixel(*xy[place]), pixel(*xy[nr * world.cols + nc])
                cv2.line(image, a, b, (255, 255, 255), 1)
    for x0, y0, x1, y1 in scene.walls:
        cv2.line(image, pixel(x0, y0), pixel(x1, y1), (220, 30, 30), max(3, round(0.4 * ppm)))
    radius = max(4, round(0.5 * ppm))
    for place in range(world.n_places):
        centre = pixel(*xy[place])
        goal = place == world.goal
        r = round(1.5 * radius) if goal else radius
        cv2.circle(image, centre, r, (30, 180, 30) if goal else (250, 250, 250), -1)
        cv2.circle(image, centre, r, (40, 40, 40), 1)
        text = str(place)
        scale = 0.3 * radius / 6
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
        origin = (centre[0] - tw // 2, centre[1] + th // 2)
        cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1, cv2.LINE_AA)
    if state is not None:
        ((place, heading),) = world.check_states(state, "state")
        start = xy[place]
        tip = start + HEADING_VECTORS[heading] * s * 0.4
        cv2.arrowedLine(
            image,
            pixel(*start),
            pixel(*tip),
            (30, 60, 230),
            max(2, round(0.2 * ppm)),
            tipLength=0.35,
        )
    return image
