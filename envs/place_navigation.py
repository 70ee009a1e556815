"""Navigation between the places of a small town seen through a jittered camera: the paper's
Fig. 8 outdoor task, simulated with MuJoCo.

The town is a rows x cols grid of places (street crossings). Buildings stand in the blocks
between the streets, walls close some streets (so that the graph of places is a little maze),
and a wall surrounds the town. Every facade and wall face shows its own crop of a photograph
bundled with an installed package (``vistask.envs.tapestry.PHOTOS``), so that SIFT finds
texture on it.

State: (place, heading); place = row * cols + column, row 0 on the north edge; heading 0..3 =
N, E, S, W (``HEADING_NAMES``). World coordinates (MuJoCo): x east, y north, z up, metres;
place (row, column) stands at (column * spacing, -row * spacing).

Percepts: the camera view from the place along the heading, jittered on every visit (camera
position within the place, heading, pitch, height, sun and ambient light: ``Jitter``), as two
photographs taken at one spot are never the same. Rendering dominates the cost, so every
state's views are rendered once into a bank from fixed jitter seeds, kept in memory and on
disk under ``$VISTASK_CACHE_DIR`` (default ``~/.cache/vistask``), keyed by a hash of the
scene, the jitter, the seeds and the renderer's version; a visit shows a view drawn from the
bank. Held-out views (``test_views``) come from other jitter seeds.

Rendering uses MUJOCO_GL (set to "egl" here when unset).
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
import os
import tempfile
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import ClassVar

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2
import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding

from vistask.envs.batched import BatchedCopies
from vistask.envs.maze_oracle import EvaluationResult, Policy
from vistask.envs.tapestry import PHOTOS, load_photo

logger = logging.getLogger(__name__)

PLACE_ACTION_NAMES: tuple[str, ...] = ("left", "right", "forward")
LEFT, RIGHT, FORWARD = range(3)
HEADING_NAMES: tuple[str, ...] = ("N", "E", "S", "W")
# (row, column) change of a move along each heading; row 0 is the north edge.
HEADING_STEPS = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]])
# Unit vector of each heading in world (x east, y north).
HEADING_VECTORS = np.array([[0.0, 1.0], [1.0, 0.0], [0.0, -1.0], [-1.0, 0.0]])

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


def _check_int(name: str, value, low: int) -> int:
    if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


# -- the place graph ---------------------------------------------------------------------------
@dataclass(frozen=True)
class PlaceWorld:
    """The graph of places and its true dynamics, shared by the env, its vector env, the oracle
    and the pictures.

    Example:
        >>> world = PlaceWorld(rows=5, cols=5, layout_seed=0)
        >>> world.n_places, world.n_states
        (25, 100)
        >>> world.step(np.array([[0, 1]]), np.array([FORWARD]))  # from place 0 facing east

    Args:
        rows, cols: the grid of places (>= 2 each).
        layout_seed: draws the closed streets (and the scene: buildings, photo crops).
        goal: the goal place (default: the south-east corner, ``rows * cols - 1``).
        extra_open: fraction of the streets outside a random spanning tree of the grid that are
            open; the others are closed by walls (0: a perfect maze, 1: every street open).
        gamma: the task's discount factor.
        reward: reward for reaching the goal place.

    Attributes:
        open: (places, 4) bool: the street from the place along each heading is open (the
            town's edge counts as closed).
        next_state: (states, 3) successor state index of each state index and action.
    """

    rows: int = 5
    cols: int = 5
    layout_seed: int = 0
    goal: int | None = None
    extra_open: float = 0.3
    gamma: float = 0.9
    reward: float = 100.0
    open: np.ndarray = field(init=False, repr=False, compare=False)
    next_state: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        _check_int("rows", self.rows, 2)
        _check_int("cols", self.cols, 2)
        _check_int("layout_seed", self.layout_seed, 0)
        if self.goal is None:
            object.__setattr__(self, "goal", self.rows * self.cols - 1)
        if not isinstance(self.goal, int | np.integer) or not 0 <= self.goal < self.n_places:
            raise ValueError(f"goal must be a place in 0..{self.n_places - 1}, got {self.goal!r}")
        object.__setattr__(self, "goal", int(self.goal))
        if not 0 <= self.extra_open <= 1:
            raise ValueError(f"extra_open must be in [0, 1], got {self.extra_open}")
        if not 0 <= self.gamma < 1:
            raise ValueError(f"gamma must be in [0, 1), got {self.gamma}")
        open_ = _draw_streets(self.rows, self.cols, self.layout_seed, self.extra_open)
        open_.setflags(write=False)
        object.__setattr__(self, "open", open_)
        places = np.arange(self.n_places)
        row, col = np.divmod(places, self.cols)
        table = np.empty((self.n_states, 3), dtype=np.int64)
        for h in range(4):
            s = places * 4 + h
            table[s, LEFT] = places * 4 + (h + 3) % 4
            table[s, RIGHT] = places * 4 + (h + 1) % 4
            ahead = (row + HEADING_STEPS[h, 0]) * self.cols + col + HEADING_STEPS[h, 1]
            table[s, FORWARD] = np.where(open_[:, h], ahead, places) * 4 + h
        table.setflags(write=False)
        object.__setattr__(self, "next_state", table)

    @property
    def n_places(self) -> int:
        return self.rows * self.cols

    @property
    def n_states(self) -> int:
        return 4 * self.n_places

    @property
    def start_states(self) -> np.ndarray:
        """(n, 2) every (place, heading) off the goal place, in state-index order."""
        states = self.states_of(np.arange(self.n_states))
        return states[states[:, 0] != self.goal]

    def check_states(self, states, what: str = "states") -> np.ndarray:
        """``states`` as an (N, 2) int array of (place, heading), or a ValueError naming
        ``what``. A single (place, heading) pair becomes (1, 2)."""
        array = np.asarray(states)
        if array.ndim == 1:
            array = array[None]
        if (
            array.ndim != 2
            or array.shape[1] != 2
            or not (np.issubdtype(array.dtype, np.integer) or array.size == 0)
        ):
            raise ValueError(f"{what} must be (place, heading) integer pairs, got {states!r}")
        array = array.astype(np.int64)
        bad = (array[:, 0] < 0) | (array[:, 0] >= self.n_places)
        bad |= (array[:, 1] < 0) | (array[:, 1] > 3)
        if bad.any():
            raise ValueError(
                f"{what}: places must lie in 0..{self.n_places - 1} and headings in 0..3"
                f" ({', '.join(HEADING_NAMES)}), got {array[bad].tolist()}"
            )
        return array

    def index(self, states) -> np.ndarray:
        """(N,) state indices ``place * 4 + heading`` of (N, 2) states."""
        states = self.check_states(states)
        return states[:, 0] * 4 + states[:, 1]

    @staticmethod
    def states_of(indices) -> np.ndarray:
        """(N, 2) (place, heading) of (N,) state indices."""
        indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        return np.stack(np.divmod(indices, 4), axis=1)

    def place_xy(self, places, spacing: float) -> np.ndarray:
        """(N, 2) world (x east, y north) of places, with ``spacing`` metres between places."""
        row, col = np.divmod(np.asarray(places, dtype=np.int64).reshape(-1), self.cols)
        return np.stack([col * spacing, -row * spacing], axis=1).astype(np.float64)

    def step(self, states, actions) -> tuple[np.ndarray, np.ndarray]:
        """Apply the true dynamics to a batch.

        Args:
            states: (N, 2) (place, heading).
            actions: (N,) action ids in 0..2 (``PLACE_ACTION_NAMES``).

        Returns:
            new states (N, 2) and (N,) bool "the goal place was reached by this move".
        """
        states = self.check_states(states)
        actions = np.asarray(actions).reshape(-1)
        if (
            len(actions) != len(states)
            or not np.issubdtype(actions.dtype, np.integer)
            or (len(actions) and (actions.min() < 0 or actions.max() > 2))
        ):
            raise ValueError(f"expected {len(states)} integer actions in 0..2, got {actions!r}")
        new = self.states_of(self.next_state[states[:, 0] * 4 + states[:, 1], actions])
        reached = (new[:, 0] == self.goal) & (states[:, 0] != self.goal)
        return new, reached

    def sample_start(self, rng: np.random.Generator) -> np.ndarray:
        """(2,) a uniformly random state off the goal place."""
        starts = self.start_states
        return starts[rng.integers(len(starts))].copy()


def _draw_streets(rows: int, cols: int, seed: int, extra_open: float) -> np.ndarray:
    """(rows * cols, 4) open streets: a random spanning tree of the grid (every place reaches
    every other) plus ``extra_open`` of the remaining streets."""
    rng = np.random.default_rng(seed)
    edges = [(p, p + 1, 1) for p in range(rows * cols) if p % cols < cols - 1]
    edges += [(p, p + cols, 2) for p in range(rows * cols - cols)]
    parent = list(range(rows * cols))

    def root(p: int) -> int:
        while parent[p] != p:
            parent[p] = parent[parent[p]]
            p = parent[p]
        return p

    tree, rest = [], []
    for k in rng.permutation(len(edges)):  # Kruskal's algorithm on random edge weights
        a, b, _ = edges[k]
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[ra] = rb
            tree.append(edges[k])
        else:
            rest.append(edges[k])
    chosen = tree + rest[: round(extra_open * len(rest))]
    open_ = np.zeros((rows * cols, 4), dtype=bool)
    for a, b, heading in chosen:  # heading from a to b: E (1) or S (2)
        open_[a, heading] = open_[b, (heading + 2) % 4] = True
    return open_


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
        self.image_size = _check_int("image_size", image_size, 16)
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


# -- environments --------------------------------------------------------------------------------
class PlaceNavigationEnv(gym.Env):
    """Walk through a small town to the goal place, seeing only a jittered camera view.

    Observation: (image_size, image_size, 3) uint8 RGB view from the place along the heading,
    drawn on every visit from the state's bank of ``views_per_state`` jittered views.
    Actions: ``Discrete(3)``: turn left, turn right (quarter turns), forward (to the next place
    along the heading if the street is open, else stay) (``PLACE_ACTION_NAMES``). Reward 100
    when the goal place is reached (terminated), 0 otherwise; ``gamma`` = 0.9. Starts are
    uniform over the states off the goal place, or ``options={"state": (place, heading)}``.
    ``info["state"]`` holds the true (place, heading), also as ``info["position"]``, the name
    under which ``vistask.rlvc.collect`` records true states (oracles and plots only; agents
    must not use it).

    The first use of the views renders the bank (4 ms a view with EGL on two CPU cores: 14 s
    for the default 100 states x 32 views, 61 MB) and caches it on disk; an env in another
    process loads it in 0.1 s.

    Example:
        >>> import gymnasium as gym, vistask.envs
        >>> env = gym.make("vistask/PlaceNavigation-v0")
        >>> obs, info = env.reset(seed=0, options={"state": (0, 1)})  # place 0, facing east
        >>> obs.shape, info["state"]
        ((80, 80, 3), array([0, 1]))
        >>> obs, reward, terminated, truncated, info = env.step(2)  # forward

    Args:
        rows, cols, layout_seed, goal, extra_open, gamma: see ``PlaceWorld``.
        image_size: side of the square views in pixels.
        views_per_state: jittered views rendered per state (the bank).
        spacing, fovy: see ``PlaceScene``.
        jitter: ranges of the per-view jitter (default ``Jitter()``).
        cache_dir: folder of the disk cache (default ``default_cache_dir()``).
        disk_cache: read and write the disk cache (else render in every new process).
        render_mode: ``None`` or ``"rgb_array"`` (a top-down map, ``draw_world``).
    """

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(
        self,
        rows: int = 5,
        cols: int = 5,
        layout_seed: int = 0,
        goal: int | None = None,
        extra_open: float = 0.3,
        gamma: float = 0.9,
        image_size: int = 80,
        views_per_state: int = 32,
        spacing: float = 6.0,
        fovy: float = 75.0,
        jitter: Jitter | None = None,
        cache_dir: str | os.PathLike | None = None,
        disk_cache: bool = True,
        render_mode: str | None = None,
    ) -> None:
        self.world = PlaceWorld(rows, cols, layout_seed, goal, extra_open, gamma)
        self.scene = PlaceScene(self.world, image_size, spacing, fovy, jitter)
        self.views_per_state = _check_int("views_per_state", views_per_state, 1)
        if self.views_per_state > TEST_SEED_OFFSET:
            raise ValueError(f"views_per_state must be <= {TEST_SEED_OFFSET}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.gamma = self.world.gamma
        self.cache_dir, self.disk_cache = cache_dir, bool(disk_cache)
        self.render_mode = render_mode
        self.observation_space = spaces.Box(0, 255, (image_size, image_size, 3), np.uint8)
        self.action_space = spaces.Discrete(len(PLACE_ACTION_NAMES))
        self.state = self.world.start_states[0].copy()
        self._views: np.ndarray | None = None

    @property
    def views(self) -> np.ndarray:
        """(states, views_per_state, H, W, 3) uint8 bank of training views (jitter seeds
        0..views_per_state-1), loaded or rendered on first use; index ``place * 4 + heading``.
        """
        if self._views is None:
            seeds = range(self.views_per_state)
            self._views = view_bank(self.scene, seeds, self.cache_dir, self.disk_cache)
        return self._views

    def test_bank(self, per_state: int = TEST_VIEWS_PER_STATE) -> np.ndarray:
        """(states, per_state, H, W, 3) uint8 held-out views: jitter seeds from
        ``TEST_SEED_OFFSET`` on, never in a training bank (cached like it)."""
        per_state = _check_int("per_state", per_state, 1)
        seeds = range(TEST_SEED_OFFSET, TEST_SEED_OFFSET + per_state)
        return view_bank(self.scene, seeds, self.cache_dir, self.disk_cache)

    def test_views(self, per_state: int = TEST_VIEWS_PER_STATE) -> tuple[np.ndarray, np.ndarray]:
        """Held-out views of every state (see ``test_bank``).

        Returns:
            images (N, H, W, 3) uint8 and their states (N, 2) (place, heading), N = states *
            per_state, state-major.
        """
        return self._flat(self.test_bank(per_state))

    def training_views(self) -> tuple[np.ndarray, np.ndarray]:
        """The training bank (``views``) as images (N, H, W, 3) uint8 and their states (N, 2),
        N = states * views_per_state, state-major."""
        return self._flat(self.views)

    def _flat(self, bank: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        states = self.world.states_of(np.arange(self.world.n_states))
        return bank.reshape(-1, *bank.shape[2:]), np.repeat(states, bank.shape[1], axis=0)

    def percept(self, state, view: int) -> np.ndarray:
        """View ``view`` of the bank of ``state`` (place, heading) (a fresh array)."""
        index = self.world.index(state)[0]
        if not 0 <= view < self.views_per_state:
            raise ValueError(f"view must be in 0..{self.views_per_state - 1}, got {view}")
        return self.views[index, view].copy()

    def _observe(self) -> np.ndarray:
        return self.percept(self.state, int(self.np_random.integers(self.views_per_state)))

    def _info(self) -> dict:
        return {"state": self.state.copy(), "position": self.state.copy()}

    # -- gymnasium API -----------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        if "state" in options:
            state = self.world.check_states(options["state"], "start state")
            if len(state) != 1:
                raise ValueError(f"start state must be one (place, heading), got {state.tolist()}")
            if state[0, 0] == self.world.goal:
                raise ValueError(f"start state {state[0].tolist()} is on the goal place")
            self.state = state[0].copy()
        else:
            self.state = self.world.sample_start(self.np_random)
        return self._observe(), self._info()

    def step(self, action):
        if not self.action_space.contains(action):
            raise ValueError(
                f"invalid action {action!r}: expected an int in 0..2"
                f" ({', '.join(PLACE_ACTION_NAMES)})"
            )
        new, reached = self.world.step(self.state[None], np.array([int(action)]))
        self.state = new[0]
        terminated = bool(reached[0])
        reward = self.world.reward if terminated else 0.0
        return self._observe(), reward, terminated, False, self._info()

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        return draw_world(self, self.state)

    def vector_copies(
        self, num_envs: int, max_episode_steps: int | None = None
    ) -> PlaceNavigationVectorEnv:
        """``num_envs`` copies of this env (same world and view bank) stepped as one batch."""
        return PlaceNavigationVectorEnv.like(self, num_envs, max_episode_steps)


class PlaceNavigationVectorEnv(BatchedCopies):
    """``num_envs`` place-navigation envs stepped as one batch: one table look-up for all.

    Each copy draws its start and its views from its own generator, exactly as a
    ``PlaceNavigationEnv`` reset with the same seed would, so the batch gives the same episodes
    as ``num_envs`` separate envs. Autoreset is off: reset ended copies with
    ``reset(options={"reset_mask": mask})``; ``options={"states": (num_envs, 2)}`` starts the
    reset copies at given states. ``infos["state"]`` (and ``infos["position"]``) hold the true
    states.

    Example:
        >>> envs = gym.make_vec("vistask/PlaceNavigation-v0", num_envs=16,
        ...                     vectorization_mode="vector_entry_point")
        >>> obs, infos = envs.reset(seed=0)       # obs (16, 80, 80, 3); copy i seeded 0 + i
        >>> obs, rewards, terminated, truncated, infos = envs.step(envs.action_space.sample())

    Args:
        num_envs: number of copies.
        max_episode_steps: truncate episodes after this many steps (None: never).
        **kwargs: ``PlaceNavigationEnv`` arguments.
    """

    def __init__(self, num_envs: int = 1, max_episode_steps: int | None = None, **kwargs) -> None:
        self._attach(PlaceNavigationEnv(**kwargs), num_envs, max_episode_steps)

    @classmethod
    def like(
        cls, env: PlaceNavigationEnv, num_envs: int, max_episode_steps: int | None = None
    ) -> PlaceNavigationVectorEnv:
        """Copies of an existing env, sharing its (read-only) view bank."""
        envs = cls.__new__(cls)
        envs._attach(env, num_envs, max_episode_steps)
        return envs

    def _attach(
        self, env: PlaceNavigationEnv, num_envs: int, max_episode_steps: int | None
    ) -> None:
        super()._attach(env, num_envs, max_episode_steps)
        self.env = env
        self.states = np.tile(env.world.start_states[0], (num_envs, 1))
        self.shown = np.zeros(num_envs, dtype=np.int64)  # bank index of each copy's view

    @property
    def gamma(self) -> float:
        return self.env.gamma

    def _draw_views(self, mask: np.ndarray) -> np.ndarray:
        """New views for the copies in ``mask`` (each from its own generator); (num_envs, H, W,
        3) the views of all copies."""
        for i in np.flatnonzero(mask):
            self.shown[i] = self.rngs[i].integers(self.env.views_per_state)
        return self.env.views[self.env.world.index(self.states), self.shown]

    def _infos(self, mask: np.ndarray) -> dict:
        return {
            "state": self.states.copy(),
            "_state": mask.copy(),
            "position": self.states.copy(),
            "_position": mask.copy(),
        }

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        options = options or {}
        world, starts = self.env.world, None
        if "states" in options:
            starts = world.check_states(options["states"], "start states")
            if len(starts) != self.num_envs or (starts[:, 0] == world.goal).any():
                raise ValueError(
                    f"options['states'] must be {self.num_envs} (place, heading) off the goal"
                    f" place {world.goal}, got {starts.tolist()}"
                )
        mask = self._reset_copies(seed, options)
        for i in np.flatnonzero(mask):
            self.states[i] = world.sample_start(self.rngs[i]) if starts is None else starts[i]
        return self._draw_views(mask), self._infos(mask)

    def step(self, actions):
        actions = self._check_actions(actions)
        self.states, terminated = self.env.world.step(self.states, actions)
        truncated = self._count_step()
        rewards = np.where(terminated, self.env.world.reward, 0.0)
        every = np.ones(self.num_envs, dtype=bool)
        return self._draw_views(every), rewards, terminated, truncated, self._infos(every)


# -- oracle and evaluation -----------------------------------------------------------------------
DEFAULT_MAX_STEPS = 50  # the time limit of vistask/PlaceNavigation-v0


def _navigation(env: gym.Env, user: str) -> PlaceNavigationEnv:
    nav = env.unwrapped
    if not isinstance(nav, PlaceNavigationEnv):
        raise TypeError(f"{user} needs a PlaceNavigationEnv, got {type(nav).__name__}")
    return nav


class PlaceOracle:
    """Shortest paths over (place, heading) states, by breadth-first search back from the goal.

    A state k actions away from the goal place has the optimal discounted return
    ``reward * gamma ** (k - 1)``: the reward arrives with the k-th action, discounted k - 1
    times (returns are sum_t gamma^t r_{t+1}, as ``evaluate_policy`` scores the maze).

    Example:
        >>> env = gym.make("vistask/PlaceNavigation-v0")
        >>> oracle = PlaceOracle(env)
        >>> oracle.values[0, 1]                  # V of place 0 facing east
        >>> oracle.optimal_actions((0, 1))       # (3,) bool: every optimal action
        >>> result = oracle.evaluate(lambda percepts, states: agent_actions(percepts))
        >>> result.mean, oracle.return_ratio(result)

    Args:
        env: a place-navigation env (``gym.make`` of it or the raw class).

    Attributes:
        env: the unwrapped env.
        steps: (places, 4) fewest actions from each state to the goal place (0 on it, -1 where
            it cannot be reached, which a connected town never has).
        values: (places, 4) optimal discounted returns (0 on the goal place).
        q: (places, 4, 3) optimal action values (0 on the goal place).
    """

    def __init__(self, env: gym.Env) -> None:
        self.env = _navigation(env, "PlaceOracle")
        world = self.world
        successor = world.next_state  # (states, 3)
        place = np.arange(world.n_states) // 4
        steps = np.where(place == world.goal, 0, -1)
        predecessors: list[list[int]] = [[] for _ in range(world.n_states)]
        for state, following in enumerate(successor.tolist()):
            for t in following:
                predecessors[t].append(state)
        queue = deque(np.flatnonzero(steps == 0).tolist())
        while queue:
            t = queue.popleft()
            for s in predecessors[t]:
                if steps[s] < 0:
                    steps[s] = steps[t] + 1
                    queue.append(s)
        values = np.where(steps > 0, world.reward * world.gamma ** (steps - 1.0), 0.0)
        into_goal = (place[successor] == world.goal) & (place != world.goal)[:, None]
        q = np.where(into_goal, world.reward, world.gamma * values[successor])
        q[place == world.goal] = 0.0
        self.steps = steps.reshape(world.n_places, 4)
        self.values = values.reshape(world.n_places, 4)
        self.q = q.reshape(world.n_places, 4, 3)

    @property
    def world(self) -> PlaceWorld:
        return self.env.world

    def value(self, states) -> np.ndarray:
        """(N,) optimal values of (N, 2) states (place, heading)."""
        states = self.world.check_states(states)
        return self.values[states[:, 0], states[:, 1]]

    def optimal_actions(self, states) -> np.ndarray:
        """Bool mask of every optimal action (ties included): (3,) for one (place, heading),
        (N, 3) for (N, 2) states. On the goal place every action counts as optimal."""
        array = self.world.check_states(states)
        q = self.q[array[:, 0], array[:, 1]]
        mask = np.isclose(q, q.max(axis=1, keepdims=True), rtol=1e-12, atol=1e-9)
        return mask[0] if np.asarray(states).ndim == 1 else mask

    def act(self, states) -> np.ndarray:
        """(N,) an optimal action of each state (forward when it is one, else left, else
        right)."""
        mask = self.optimal_actions(self.world.check_states(states))
        return np.where(mask[:, FORWARD], FORWARD, np.where(mask[:, LEFT], LEFT, RIGHT))

    def as_policy(self) -> Policy:
        """The oracle as a ``Policy`` ``(percepts, states) -> actions`` (reads true states)."""
        return lambda percepts, states: self.act(states)

    def optimal_return(self, starts=None) -> float:
        """Mean optimal discounted return from ``starts`` (default ``evaluation_starts``)."""
        starts = self.world.start_states if starts is None else starts
        return float(self.value(starts).mean())

    def evaluate(
        self,
        policy: Policy,
        starts=None,
        max_steps: int = DEFAULT_MAX_STEPS,
        seed: int = 0,
        views: str = "test",
        per_state: int = TEST_VIEWS_PER_STATE,
    ) -> EvaluationResult:
        """Run ``policy`` once from each start, all episodes in lockstep, and return the
        discounted returns sum_t gamma^t r_{t+1}.

        Episode i draws its views from its own generator seeded ``seed + i``; with
        ``views="train"`` exactly as ``env.reset(seed=seed + i, options={"state": start})``
        followed by ``env.step`` would, so a batched policy is scored as if each episode ran
        alone in the env.

        Args:
            policy: batched ``policy(percepts (k, H, W, 3), states (k, 2)) -> (k,) actions``
                (see ``Policy``); a visual agent must ignore the states.
            starts: (n, 2) start states (default ``evaluation_starts``: every state off the
                goal place).
            max_steps: episode cut-off (the registered env's time limit).
            seed: base seed of the view draws.
            views: ``"test"``: held-out views (``env.test_bank(per_state)``), never seen in
                training; ``"train"``: the env's own bank.
            per_state: held-out views per state with ``views="test"``.
        """
        world = self.world
        starts = world.start_states if starts is None else world.check_states(starts, "starts")
        if (starts[:, 0] == world.goal).any():
            raise ValueError(f"starts must lie off the goal place {world.goal}")
        _check_int("max_steps", max_steps, 1)
        if views == "test":
            bank = self.env.test_bank(per_state)
        elif views == "train":
            bank = self.env.views
        else:
            raise ValueError(f"views must be 'test' or 'train', got {views!r}")
        n, per = len(starts), bank.shape[1]
        rngs = [seeding.np_random(seed + i)[0] for i in range(n)]  # as env.reset(seed=seed + i)
        states = starts.copy()
        shown = np.array([rng.integers(per) for rng in rngs])
        returns, steps = np.zeros(n), np.full(n, max_steps)
        live = np.arange(n)
        for t in range(max_steps):
            percepts = bank[world.index(states[live]), shown[live]]
            actions = np.asarray(policy(percepts, states[live].copy())).reshape(-1)
            if (
                len(actions) != len(live)
                or not np.issubdtype(actions.dtype, np.integer)
                or actions.min() < 0
                or actions.max() > 2
            ):
                raise ValueError(f"policy must return {len(live)} integer actions in 0..2")
            states[live], reached = world.step(states[live], actions)
            returns[live[reached]] = world.gamma**t * world.reward
            steps[live[reached]] = t + 1
            live = live[~reached]
            if len(live) == 0:
                break
            for i in live:
                shown[i] = rngs[i].integers(per)
        return EvaluationResult(returns, steps)

    def return_ratio(self, result: EvaluationResult | Policy, starts=None, **kwargs) -> float:
        """Mean discounted return of a policy (or of its ``evaluate`` result) over the
        oracle's, from the same starts (1: optimal).

        Args:
            result: an ``EvaluationResult`` from ``starts``, or a policy to ``evaluate``.
            starts: the start states (default ``evaluation_starts``).
            **kwargs: ``evaluate`` arguments when ``result`` is a policy.
        """
        if not isinstance(result, EvaluationResult):
            result = self.evaluate(result, starts, **kwargs)
        return result.mean / self.optimal_return(starts)


def evaluation_starts(env: gym.Env, n: int | None = None, seed: int = 12345) -> np.ndarray:
    """The fixed evaluation start set: (n, 2) states off the goal place; every one of them
    (state-index order) when ``n`` is None, else ``n`` drawn without replacement with
    ``seed`` (with replacement when ``n`` exceeds their number)."""
    states = _navigation(env, "evaluation_starts").world.start_states
    if n is None:
        return states
    _check_int("n", n, 1)
    rng = np.random.default_rng(seed)
    return states[rng.choice(len(states), size=n, replace=n > len(states))]


# -- pictures ------------------------------------------------------------------------------------
def draw_world(env: gym.Env, state=None, pixels_per_metre: float = 12.0) -> np.ndarray:
    """Top-down map of the town: buildings (their photo-textured faces in each photo's mean
    colour), the town wall, closed streets (red bars), open streets (thin lines), places
    (numbered), the goal place (green) and, given a state, the agent (blue arrow).

    Returns:
        (H, W, 3) uint8 RGB image, north up.
    """
    nav = _navigation(env, "draw_world")
    world, scene = nav.world, nav.scene
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


def view_sheet(env: gym.Env, state, n: int = 8, gap: int = 2) -> np.ndarray:
    """A row of ``n`` jittered views of one state (place, heading): its bank's first views,
    rendered afresh (jitter seeds 0..n-1) beyond the bank's size.

    Returns:
        (H, n * W + (n - 1) * gap, 3) uint8 RGB image, white between the views.
    """
    nav = _navigation(env, "view_sheet")
    n = _check_int("n", n, 1)
    gap = _check_int("gap", gap, 0)
    states = nav.world.check_states(state, "state")
    if len(states) != 1:
        raise ValueError(f"view_sheet shows one state, got {states.tolist()}")
    if n <= nav.views_per_state:
        views = nav.views[nav.world.index(states)[0], :n]
    else:
        views = nav.scene.render(states, range(n))[0]
    size = nav.scene.image_size
    sheet = np.full((size, n * size + (n - 1) * gap, 3), 255, np.uint8)
    for k, view in enumerate(views):
        sheet[:, k * (size + gap) : k * (size + gap) + size] = view
    return sheet
