"""The visual car on the hill of the paper's section 2.5.1 (Figs. 6-7), as a Gymnasium environment.

The dynamics are the car on the hill of Moore & Atkeson (1995) as specified by Ernst, Geurts &
Wehenkel (2005, appendix): a point car of mass 1 on the hill

    Hill(p) = p^2 + p             for p < 0,
    Hill(p) = p / sqrt(1 + 5 p^2)  for p >= 0,

pushed with a force u in {-4, +4}. The state is (p, s), position and speed. One control step
lasts 0.1 s, integrated by explicit Euler in 100 steps of 0.001 s. The episode ends with reward
+1 when the car leaves the hill on the right (p > 1) at a speed |s| <= 3, and with reward -1
when it leaves on the left (p < -1) or exceeds the speed limit (|s| > 3); every other step gives
0. The discount factor is 0.95.

The agent never sees (p, s): its percept is one image, a window of a road (a long strip of
photographs) that slides with p, beside an analog velocity gauge whose needle shows s (paper
Fig. 6). The needle is short: its tip runs on a small circle around the hub, far inside the
ring of numerals, farther from them than the SIFT descriptor windows of the tip and the hub
reach. So no local feature of the gauge changes with the speed (the tip and the hub look the
same at every needle angle once SIFT has turned them upright, and a numeral never sees the
needle): the speed shows only in where the tip lies relative to the numerals, which only a
compound feature (a pair of local features at a given displacement) can read.
"""

from __future__ import annotations

import math
from functools import cache
from typing import ClassVar

import cv2
import gymnasium as gym
import numpy as np
from gymnasium import spaces

from vistask.checks import check_at_least, check_canvas, check_options, check_positive, checked
from vistask.envs.batched import BatchedCopies
from vistask.envs.tapestry import PHOTOS, make_tapestry

MASS = 1.0
GRAVITY = 9.81
CAR_ACTION_NAMES: tuple[str, ...] = ("push left", "push right")
FORCES = np.array([-4.0, 4.0])  # u of each action
TIME_STEP = 0.1  # seconds per control step
SUBSTEPS = 100  # Euler steps per control step (0.001 s each)
MAX_POSITION = 1.0  # the hill spans p in [-1, 1]
MAX_SPEED = 3.0  # |s| > 3 ends the episode with reward -1
GAMMA = 0.95

# Below this batch size ``hill_step`` integrates row by row with Python floats: for one car,
# 100 Euler steps of a dozen numpy calls each would cost ~1.5 ms per control step, against
# ~0.03 ms in plain Python. Both paths do the same operations in the same order (IEEE results
# are bit-identical), so a batch of cars and the same cars one by one agree exactly.
_SCALAR_BATCH = 4


# -- physics --------------------------------------------------------------------------------
def hill(p: np.ndarray) -> np.ndarray:
    """Height of the hill at positions ``p`` (any shape)."""
    p = np.asarray(p, dtype=np.float64)
    return np.where(p < 0, p * p + p, p / np.sqrt(1.0 + 5.0 * p * p))


def hill_slope(p: np.ndarray) -> np.ndarray:
    """Hill'(p): 2p + 1 for p < 0, (1 + 5 p^2)^(-3/2) for p >= 0 (any shape)."""
    p = np.asarray(p, dtype=np.float64)
    r = 1.0 / np.sqrt(1.0 + 5.0 * p * p)
    return np.where(p < 0, 2.0 * p + 1.0, r * r * r)


def hill_curvature(p: np.ndarray) -> np.ndarray:
    """Hill''(p): 2 for p < 0, -15 p (1 + 5 p^2)^(-5/2) for p >= 0 (any shape)."""
    p = np.asarray(p, dtype=np.float64)
    r = 1.0 / np.sqrt(1.0 + 5.0 * p * p)
    return np.where(p < 0, 2.0, -15.0 * p * r * r * r * r * r)


def acceleration(states: np.ndarray, forces: np.ndarray) -> np.ndarray:
    """(N,) s' = u / (m (1 + H'^2)) - g H' / (1 + H'^2) - s^2 H' H'' / (1 + H'^2).

    Args:
        states: (N, 2) rows (p, s).
        forces: (N,) forces u.
    """
    states = np.asarray(states, dtype=np.float64).reshape(-1, 2)
    p, s = states[:, 0], states[:, 1]
    d1, d2 = hill_slope(p), hill_curvature(p)
    q = 1.0 + d1 * d1
    return np.asarray(forces) / (MASS * q) - GRAVITY * d1 / q - s * s * d1 * d2 / q


def outcome(states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rewards (N,) and terminal flags (N,) of arriving in states (N, 2): +1 for p > 1 at
    |s| <= 3, -1 for p < -1 or |s| > 3, 0 (not terminal) inside the box."""
    states = np.asarray(states, dtype=np.float64).reshape(-1, 2)
    p, s = states[:, 0], states[:, 1]
    lost = (p < -MAX_POSITION) | (np.abs(s) > MAX_SPEED)
    won = (p > MAX_POSITION) & ~lost
    return np.where(lost, -1.0, np.where(won, 1.0, 0.0)), lost | won


@checked
def hill_step(
    states: np.ndarray,
    forces: np.ndarray,
    dt: float = TIME_STEP,
    substeps: int = SUBSTEPS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One control step of a batch of cars: ``substeps`` explicit Euler steps of ``dt /
    substeps`` seconds, then the reward and end of episode of the arrival state.

    Example:
        >>> next_states, rewards, terminal = hill_step(np.array([[0.0, 0.0]]), np.array([4.0]))

    Args:
        states: (N, 2) rows (p, s).
        forces: (N,) forces u (``FORCES[actions]``).
        dt: seconds of one control step.
        substeps: Euler steps within it.

    Returns:
        next states (N, 2), rewards (N,) and terminal flags (N,) (see ``outcome``).
    """
    states = np.asarray(states, dtype=np.float64)
    if states.ndim != 2 or states.shape[1] != 2:
        raise ValueError(f"states must be an (N, 2) array of (p, s), got shape {states.shape}")
    forces = np.asarray(forces, dtype=np.float64).reshape(-1)
    if forces.shape != (len(states),):
        raise ValueError(f"need one force per state: {len(states)}, got {forces.shape}")
    if not (np.isfinite(states).all() and np.isfinite(forces).all()):
        raise ValueError("states and forces must be finite")
    check_positive(dt=dt)
    check_at_least(1, substeps=substeps)
    h = dt / substeps
    pushes = forces / MASS
    if len(states) <= _SCALAR_BATCH:
        rows = [
            _euler(float(p), float(s), float(f), h, substeps)
            for (p, s), f in zip(states, pushes, strict=True)
        ]
        new = np.array(rows, dtype=np.float64).reshape(-1, 2)
    else:
        p, s = states[:, 0].copy(), states[:, 1].copy()
        for _ in range(substeps):
            r = 1.0 / np.sqrt(1.0 + 5.0 * p * p)
            right = r * r * r
            neg = p < 0
            d1 = np.where(neg, 2.0 * p + 1.0, right)
            d2 = np.where(neg, 2.0, -15.0 * p * right * r * r)
            a = (pushes - GRAVITY * d1 - s * s * d1 * d2) / (1.0 + d1 * d1)
            p, s = p + h * s, s + h * a
        new = np.stack([p, s], axis=1)
    rewards, terminal = outcome(new)
    return new, rewards, terminal


def _euler(p: float, s: float, push: float, h: float, substeps: int) -> tuple[float, float]:
    """``hill_step``'s integration for one car in Python floats (same operations, same order)."""
    for _ in range(substeps):
        if p < 0:
            d1, d2 = 2.0 * p + 1.0, 2.0
        else:
            r = 1.0 / math.sqrt(1.0 + 5.0 * p * p)
            right = r * r * r
            d1, d2 = right, -15.0 * p * right * r * r
        a = (push - GRAVITY * d1 - s * s * d1 * d2) / (1.0 + d1 * d1)
        p, s = p + h * s, s + h * a
    return p, s


def sample_states(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 2) states drawn uniformly in [-1, 1) x [-3, 3)."""
    return rng.uniform([-MAX_POSITION, -MAX_SPEED], [MAX_POSITION, MAX_SPEED], size=(n, 2))


def check_states(states, what: str = "states") -> np.ndarray:
    """(N, 2) float array of non-terminal states (p in [-1, 1], |s| <= 3), or a clear error."""
    array = np.asarray(states, dtype=np.float64)
    if array.ndim == 1:
        array = array.reshape(1, -1)
    if array.ndim != 2 or array.shape[1] != 2 or not np.isfinite(array).all():
        raise ValueError(f"{what} must be (p, s) pairs, got {states!r}")
    if np.any(np.abs(array[:, 0]) > MAX_POSITION) or np.any(np.abs(array[:, 1]) > MAX_SPEED):
        raise ValueError(
            f"{what} must lie on the hill, p in [-1, 1] and s in [-3, 3] (else they are "
            f"terminal), got {states!r}"
        )
    return array


# -- percepts -------------------------------------------------------------------------------
# The gauge hides the speed from every single local feature (paper Fig. 6: "the velocity is
# impossible to measure using local features only"). A SIFT descriptor sums gradients over a
# square of 4 x 4 cells of 3 sigma turned to the keypoint's orientation: pixels up to 3 sigma
# * 2.5 * sqrt(2) ~ 10.6 sigma away count. The old layout (tip circle 0.15 g, numerals at 0.29
# g, ticks at 0.38-0.46 g, tip disc 0.045 g; g = gauge size = 96 px) put numerals and ticks
# inside the tip's window (sigma 3, 32 px) at places that changed with the needle's angle, and
# the needle inside the numerals' windows: bands of speeds got words of their own. Now:
# - numerals -3..3 (black, 1 px strokes, font scale 0.0036 g) near the rim, centred at 0.40 g:
#   their ink starts 30 px from the centre. No ticks: the numerals are the numbered ticks;
# - the tip, a small dark disc (radius 0.023 g = 2.2 px; SIFT size 3.2, sigma 1.6, window
#   17 px), runs on a circle of 0.11 g = 10.6 px: 19.5 px from the nearest numeral ink;
# - the hub, a grey disc (radius 0.03 g; size 4.4, sigma 2.2, window 23 px) at the centre, 30
#   px from the ink. The needle is a 1 px radial segment hub -> tip: turned upright by SIFT,
#   the tip and the hub look the same at every angle (a 2 px needle or a larger tip disc
#   makes their DoG extrema come and go with the angle);
# - the strong numeral keypoints (size 1.9-2.6) reach 20-29 px from the centre, short of the
#   tip disc (12.8 px); the weak, large blobs where numerals meet the rim would reach it, but
#   are never among a percept's 24 strongest keypoints;
# - the needle goes on past -3 and +3 (``NEEDLE_STOP``): over the speed limit (terminal,
#   ~3% of random play's percepts) a needle pinned at +-3 drew pixel-identical gauges, which
#   the vocabulary gave words of their own (best word R^2 0.16 over collected percepts).
# Measured with the learner's pipeline (``SiftExtractor(max_keypoints=24)``, 8192 words fitted
# on the percepts of 6,000 uniform states), before -> after: keypoints on the gauge 13.3 ->
# 13.5, on the road 11.0 -> 10.8 (never fewer than 6); tip disc among them in 95.9% -> 98.7%
# of percepts, hub 99.9%; numerals found 4.3 -> 5.9 of 7 (3 or more in 97.2% -> 98.0%). The
# share of the speed's variance that the best single word explains (``feature_r2``): 0.27 ->
# 0.027 over uniform states (the best words now: the hub in narrow bands of extreme speeds,
# ~60 percepts each), 0.42 -> 0.033 over 6,000 percepts of random play (``collect``; there the
# best words are road words). For the position, words still explain up to 0.27. The tip moves
# 7.4 px per unit of speed (0.11 g x 40 degrees) and lies 22-30 px from the nearest numeral
# keypoint: 7-9.5 tip sizes. The road keeps only the most textured photo tiles (``paint_road``).
DIAL_COLOUR = (255, 255, 255)
DIAL_BACKGROUND = (40, 40, 40)
NUMERAL_COLOUR = (0, 0, 0)
NEEDLE_COLOUR = (220, 50, 50)
TIP_COLOUR = (20, 20, 160)
HUB_COLOUR = (90, 90, 90)
DIAL_BLUR = 0.5  # std in pixels of the blur of the empty dial (softens the numerals)
NUMERAL_RADIUS = 0.40  # the numerals' centres, in gauge sizes g from the centre
NUMERAL_SCALE = 0.0036  # font scale per pixel of g (Hershey simplex, 1 px strokes)
TIP_RADIUS = 0.11  # the tip's circle, in g
TIP_DISC = 0.023  # radius of the tip disc, in g
HUB_DISC = 0.03  # radius of the hub disc, in g
NEEDLE_STOP = 4.4  # the needle goes on past -3 and +3 to stops at s = -+4.4 (see the notes)
ROAD_CLAHE = 2.0  # clip limit of the road's contrast equalization, per photo tile (0: none)
TEXTURE_RESPONSE = 0.06  # a road tile's texture: its SIFT keypoints of at least this response


@cache
def paint_road(height: int, width: int, tile: int, seed: int, blur: float = 0.0) -> np.ndarray:
    """(height, width, 3) read-only strip of photo tiles: the most textured of all the
    photographs' tiles (``make_tapestry`` with every photo region once, each contrast-equalized),
    in their seeded order. Most bundled photographs are smooth at this scale (a colour
    gradient, a lemon, bread): a window on them would give SIFT nothing to tell positions
    apart by. Cached: copies of an env share one strip.

    Args:
        height, width: strip size in pixels.
        tile: side of a photo tile in pixels.
        seed: seed of the montage (``make_tapestry``).
        blur: std in pixels of a final Gaussian blur (0: none).
    """
    needed = -(-width // tile)
    pool_size = max(needed, 4 * len(PHOTOS))  # make_tapestry cuts each photo in 4 regions
    pool = make_tapestry(height, pool_size * tile, tile=tile, seed=seed)
    if ROAD_CLAHE:
        lab = cv2.cvtColor(pool, cv2.COLOR_RGB2LAB)
        grid = (pool_size, -(-height // tile))  # one per photo tile
        lab[..., 0] = cv2.createCLAHE(ROAD_CLAHE, grid).apply(lab[..., 0])
        pool = cv2.cvtColor(lab, cv2.COLOR_LAB2RGB)
    columns = [pool[:, k * tile : (k + 1) * tile] for k in range(pool_size)]
    detector = cv2.SIFT_create(contrastThreshold=0.02)
    scores = [
        sum(k.response > TEXTURE_RESPONSE for k in detector.detect(_grey(c))) for c in columns
    ]
    kept = np.sort(np.argsort(scores, kind="stable")[::-1][:needed])
    road = np.concatenate([columns[k] for k in kept], axis=1)[:, :width]
    if blur > 0:
        road = cv2.GaussianBlur(road, (0, 0), blur)
    road = np.ascontiguousarray(road)
    road.setflags(write=False)
    return road


class CarPercepts:
    """Renders percepts: a window of the road strip beside the velocity gauge.

    The road strip and the empty gauge (dial, numerals) are drawn once; a percept copies the
    road window and the dial and draws the needle (antialiased, at 1/16 pixel precision, so
    that the needle moves smoothly with s): about 10 µs per (96, 192) image.

    Gauge (a height x height square): numerals -3..3 near the rim over an arc of 240 degrees
    (-3 lower left, 0 up, +3 lower right); a short red needle from a grey hub at the
    centre, whose tip, a small dark blue disc, runs on a small circle (``tip_radius``) far
    inside the numerals: no numeral lies within the SIFT descriptor window of the tip or the
    hub, and no numeral's window reaches the needle (see the notes above ``DIAL_COLOUR``).

    Args:
        height: percept height in pixels (the gauge is a height x height square).
        road_width: width of the road window in pixels.
        pixels_per_unit: road pixels per unit of p (the window's left edge moves by
            ``2 * pixels_per_unit`` pixels from p = -1 to p = 1).
        road_blur: std in pixels of a Gaussian blur of the road (0: none); blurring the road
            leaves more of SIFT's strongest keypoints to the gauge.
        tile: side of the road's photo tiles in pixels (default ``height``).
        seed: seed of the road montage (``paint_road``).
    """

    def __init__(
        self,
        height: int = 96,
        road_width: int = 96,
        pixels_per_unit: float = 320.0,
        road_blur: float = 0.0,
        tile: int | None = None,
        seed: int = 0,
    ) -> None:
        if not isinstance(height, int | np.integer) or height < 48:
            raise ValueError(f"height must be an integer >= 48 pixels, got {height!r}")
        if not isinstance(road_width, int | np.integer) or road_width < 8:
            raise ValueError(f"road_width must be an integer >= 8 pixels, got {road_width!r}")
        if not pixels_per_unit > 0:
            raise ValueError(f"pixels_per_unit must be positive, got {pixels_per_unit}")
        if road_blur < 0:
            raise ValueError(f"road_blur must be >= 0, got {road_blur}")
        self.height, self.road_width = int(height), int(road_width)
        self.gauge_size = self.height
        self.width = self.road_width + self.gauge_size
        self.pixels_per_unit = float(pixels_per_unit)
        self.span = round(2 * MAX_POSITION * self.pixels_per_unit)
        width = self.span + self.road_width
        check_canvas(self.height, width, "pixels_per_unit and road_width")
        self.road = paint_road(self.height, width, tile or self.height, seed, float(road_blur))
        g = self.gauge_size  # gauge geometry, in pixels of the gauge square
        self.centre = (g / 2, g / 2)
        self.dial_radius = g / 2 - 2
        self.numeral_radius = NUMERAL_RADIUS * g
        self.tip_radius = TIP_RADIUS * g
        self.tip_disc = max(1.5, TIP_DISC * g)
        self.hub_disc = max(1.5, HUB_DISC * g)
        self.dial = self._draw_dial()
        self.dial.setflags(write=False)

    @staticmethod
    def angle(speed: np.ndarray | float) -> np.ndarray:
        """Needle angle in radians (counter-clockwise from the right) of speed s: -3 at 210
        degrees (lower left), 0 straight up, +3 at -30 (lower right), 40 degrees per unit, on
        past the numerals down to the stops at s = -+``NEEDLE_STOP`` (near straight down)."""
        s = np.clip(np.asarray(speed, dtype=np.float64), -NEEDLE_STOP, NEEDLE_STOP)
        return np.deg2rad(90.0 - 120.0 * s / MAX_SPEED)

    def point(self, angle: float, radius: float) -> tuple[float, float]:
        """(x, y) pixel in the gauge square at ``angle`` (radians) and ``radius`` (pixels)."""
        cx, cy = self.centre
        return cx + radius * math.cos(angle), cy - radius * math.sin(angle)

    def tip(self, speed: float) -> tuple[float, float]:
        """(x, y) pixel of the needle's tip in the gauge square for speed s."""
        return self.point(float(self.angle(speed)), self.tip_radius)

    def numeral_centre(self, value: int) -> tuple[float, float]:
        """(x, y) pixel of the centre of numeral ``value`` (-3..3) in the gauge square."""
        return self.point(float(self.angle(value)), self.numeral_radius)

    def _draw_dial(self) -> np.ndarray:
        g = self.gauge_size
        dial = np.full((g, g, 3), DIAL_BACKGROUND, np.uint8)
        centre = _fixed(self.centre)
        cv2.circle(dial, centre, _fixed_len(self.dial_radius), DIAL_COLOUR, -1, cv2.LINE_AA, _SHIFT)
        font, scale, thick = cv2.FONT_HERSHEY_SIMPLEX, NUMERAL_SCALE * g, 1
        for value in range(-int(MAX_SPEED), int(MAX_SPEED) + 1):
            text = str(value)
            (w, h), _ = cv2.getTextSize(text, font, scale, thick)
            x, y = self.numeral_centre(value)
            origin = (round(x - w / 2), round(y + h / 2))
            cv2.putText(dial, text, origin, font, scale, NUMERAL_COLOUR, thick, cv2.LINE_AA)
        if DIAL_BLUR:
            dial = cv2.GaussianBlur(dial, (0, 0), DIAL_BLUR)
        return dial

    def draw_needle(self, gauge: np.ndarray, speed: float) -> None:
        """Draw the needle for speed s into ``gauge`` (a copy of ``dial``), in place."""
        tip, centre = _fixed(self.tip(speed)), _fixed(self.centre)
        cv2.line(gauge, centre, tip, NEEDLE_COLOUR, 1, cv2.LINE_AA, _SHIFT)
        cv2.circle(gauge, tip, _fixed_len(self.tip_disc), TIP_COLOUR, -1, cv2.LINE_AA, _SHIFT)
        cv2.circle(gauge, centre, _fixed_len(self.hub_disc), HUB_COLOUR, -1, cv2.LINE_AA, _SHIFT)

    def window_left(self, position: float) -> int:
        """Left edge of the road window (pixels of ``road``) at position p, clipped to the
        hill: a car that has left it sees the road's end."""
        p = min(max(float(position), -MAX_POSITION), MAX_POSITION)
        return round((p + MAX_POSITION) / (2 * MAX_POSITION) * self.span)

    def render_into(self, out: np.ndarray, state: np.ndarray) -> np.ndarray:
        """Render the percept of ``state`` (p, s) into ``out`` (height, width, 3) uint8."""
        x0 = self.window_left(state[0])
        out[:, : self.road_width] = self.road[:, x0 : x0 + self.road_width]
        gauge = out[:, self.road_width :]
        gauge[:] = self.dial
        self.draw_needle(gauge, float(state[1]))
        return out

    def __call__(self, states: np.ndarray) -> np.ndarray:
        """(N, height, width, 3) uint8 percepts of states (N, 2), or one (height, width, 3)
        percept of one state (2,)."""
        states = np.asarray(states, dtype=np.float64)
        if states.shape == (2,):
            return self.render_into(np.empty((self.height, self.width, 3), np.uint8), states)
        if states.ndim != 2 or states.shape[1] != 2:
            raise ValueError(f"states must be (N, 2) rows (p, s) or one (2,), got {states.shape}")
        out = np.empty((len(states), self.height, self.width, 3), np.uint8)
        for image, state in zip(out, states, strict=True):
            self.render_into(image, state)
        return out


_SHIFT = 4  # cv2 draws at 1/16 pixel precision


def _grey(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)


def _fixed(point: tuple[float, float]) -> tuple[int, int]:
    return round(point[0] * (1 << _SHIFT)), round(point[1] * (1 << _SHIFT))


def _fixed_len(length: float) -> int:
    return round(length * (1 << _SHIFT))


# -- environments ----------------------------------------------------------------------------
@checked
class VisualMountainCarEnv(gym.Env):
    """Drive a car up a hill, seeing only a window of the road and a velocity gauge.

    Observation: (height, road_width + height, 3) uint8 RGB image (default (96, 192, 3)): the
    road window (left), which slides with the position p, and the gauge (right), whose needle
    shows the speed s. Actions: ``Discrete(2)``: push left (u = -4) or right (u = +4)
    (``CAR_ACTION_NAMES``). Reward +1 at the top (p > 1 with ``|s| <= 3``), -1 off the left edge
    (p < -1) or over the speed limit (``|s| > 3``), both terminal; 0 otherwise. ``gamma`` = 0.95.
    ``info["position"]`` holds the true state (p, s) (for oracles and plots only; agents must
    not use it). Starts are uniform in [-1, 1) x [-3, 3), or ``options={"state": (p, s)}``.
    ``panel_widths`` (road_width, height) tells feature extractors where the two views meet.

    Example:
        >>> import gymnasium as gym, vistask.envs
        >>> env = gym.make("vistask/VisualMountainCar-v0")
        >>> obs, info = env.reset(seed=0, options={"state": (-0.5, 0.0)})
        >>> obs.shape, info["position"]
        ((96, 192, 3), array([-0.5,  0. ]))
        >>> obs, reward, terminated, truncated, info = env.step(1)  # push right

    Args:
        height, road_width, pixels_per_unit, road_blur, tile: the percept (see ``CarPercepts``).
        road_seed: seed of the road montage (the world, not the episode's start).
        gamma: the task's discount factor.
        render_mode: ``None`` or ``"rgb_array"`` (the whole road, framed window, and gauge).
    """

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        height: int = 96,
        road_width: int = 96,
        pixels_per_unit: float = 320.0,
        road_blur: float = 0.0,
        tile: int | None = None,
        road_seed: int = 0,
        gamma: float = GAMMA,
        render_mode: str | None = None,
    ) -> None:
        if not 0 <= gamma < 1:
            raise ValueError(f"gamma must be in [0, 1), got {gamma}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        check_at_least(0, road_seed=road_seed)
        if tile is not None:
            check_at_least(1, tile=tile)
        self.percepts = CarPercepts(height, road_width, pixels_per_unit, road_blur, tile, road_seed)
        self.gamma = float(gamma)
        self.render_mode = render_mode
        shape = (self.percepts.height, self.percepts.width, 3)
        self.observation_space = spaces.Box(0, 255, shape, np.uint8)
        self.action_space = spaces.Discrete(len(CAR_ACTION_NAMES))
        # The percept's two views, left to right: feature extractors run on each alone.
        self.panel_widths = (self.percepts.road_width, self.percepts.gauge_size)
        self.state: np.ndarray | None = None  # set by reset

    def percept_at(self, state: np.ndarray) -> np.ndarray:
        """(height, width, 3) uint8 percept of the state (p, s) (a fresh array)."""
        return self.percepts(np.asarray(state, dtype=np.float64).reshape(2))

    # -- gymnasium API -----------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode: (observation, info), ``info["position"]`` the true state."""
        super().reset(seed=seed)
        options = check_options(options, ("state",))
        if "state" in options:
            state = check_states(options["state"], "start state")
            if state.shape != (1, 2):
                raise ValueError(f"start state must be one (p, s) pair, got {options['state']!r}")
            self.state = state[0].copy()
        else:
            self.state = sample_states(self.np_random, 1)[0]
        return self.percept_at(self.state), {"position": self.state.copy()}

    def step(self, action):
        """Take ``action``: (observation, reward, terminated, truncated, info)."""
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        if isinstance(action, bool | np.bool_) or not self.action_space.contains(action):
            raise ValueError(
                f"invalid action {action!r}: expected an int in 0..{self.action_space.n - 1}"
                f" ({', '.join(CAR_ACTION_NAMES)})"
            )
        new, rewards, terminal = hill_step(self.state[None], FORCES[[int(action)]])
        self.state = new[0]
        obs = self.percept_at(self.state)
        return obs, float(rewards[0]), bool(terminal[0]), False, {"position": self.state.copy()}

    def render(self) -> np.ndarray | None:
        """The picture of ``render_mode="rgb_array"`` (None without a render mode)."""
        if self.render_mode != "rgb_array":
            return None
        return draw_road(self, self.state)

    def vector_copies(
        self, num_envs: int, max_episode_steps: int | None = None
    ) -> VisualMountainCarVectorEnv:
        """``num_envs`` copies of this car (same road) stepped as one batch."""
        return VisualMountainCarVectorEnv.like(self, num_envs, max_episode_steps)


@checked
class VisualMountainCarVectorEnv(BatchedCopies):
    """``num_envs`` visual cars stepped as one batch: one ``hill_step`` for all.

    Each copy draws its starts from its own generator, exactly as a ``VisualMountainCarEnv``
    reset with the same seed would (the dynamics have no noise), so the batch gives the same
    episodes as ``num_envs`` separate envs. Autoreset is off: reset ended copies with
    ``reset(options={"reset_mask": mask})``; ``options={"states": (num_envs, 2)}`` starts the
    reset copies at given states instead. ``infos["position"]`` holds the true states.

    Example:
        >>> envs = gym.make_vec("vistask/VisualMountainCar-v0", num_envs=64,
        ...                     vectorization_mode="vector_entry_point")
        >>> obs, infos = envs.reset(seed=0)       # obs (64, 96, 192, 3); copy i seeded 0 + i
        >>> obs, rewards, terminated, truncated, infos = envs.step(envs.action_space.sample())

    Args:
        num_envs: number of copies.
        max_episode_steps: truncate episodes after this many steps (None: never).
        **kwargs: ``VisualMountainCarEnv`` arguments.
    """

    def __init__(self, num_envs: int = 1, max_episode_steps: int | None = None, **kwargs) -> None:
        self._attach(VisualMountainCarEnv(**kwargs), num_envs, max_episode_steps)

    @classmethod
    def like(
        cls, car: VisualMountainCarEnv, num_envs: int, max_episode_steps: int | None = None
    ) -> VisualMountainCarVectorEnv:
        """Copies of an existing car env, sharing its (read-only) road and dial."""
        envs = cls.__new__(cls)
        envs._attach(car, num_envs, max_episode_steps)
        return envs

    def _attach(
        self, car: VisualMountainCarEnv, num_envs: int, max_episode_steps: int | None
    ) -> None:
        super()._attach(car, num_envs, max_episode_steps)
        self.car = car
        self.states = np.zeros((num_envs, 2))

    @property
    def gamma(self) -> float:
        """The env's discount."""
        return self.car.gamma

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """Reset the copies (those of ``options["reset_mask"]`` only, if given): (observations,
        infos)."""
        options = options or {}
        starts = None
        if "states" in options:
            starts = check_states(options["states"], "start states")
            if starts.shape != (self.num_envs, 2):
                raise ValueError(
                    f"options['states'] must be ({self.num_envs}, 2), got {starts.shape}"
                )
        mask = self._reset_copies(seed, options)
        for i in np.flatnonzero(mask):
            self.states[i] = sample_states(self.rngs[i], 1)[0] if starts is None else starts[i]
        infos = {"position": self.states.copy(), "_position": mask.copy()}
        return self.car.percepts(self.states), infos

    def step(self, actions):
        """Step every copy with ``actions`` (N,): (observations, rewards, terminated, truncated,
        infos)."""
        actions = self._check_actions(actions)
        self.states, rewards, terminated = hill_step(self.states, FORCES[actions])
        truncated = self._count_step()
        every = np.ones(self.num_envs, dtype=bool)
        infos = {"position": self.states.copy(), "_position": every}
        return self.car.percepts(self.states), rewards, terminated, truncated, infos


def draw_road(env: VisualMountainCarEnv, state: np.ndarray | None = None) -> np.ndarray:
    """Picture of the whole road strip with the percept's window framed in white, and the
    percept's gauge beside it (paper Fig. 6 top): (height, road strip width + gap + height, 3).
    """
    view = env.percepts
    road = np.ascontiguousarray(view.road[:, : view.span + view.road_width])
    gap = np.full((view.height, 8, 3), 255, np.uint8)
    gauge = view.dial.copy()
    if state is not None:
        state = np.asarray(state, dtype=np.float64).reshape(2)
        road = road.copy()
        x0 = view.window_left(state[0])
        corners = (x0, 0), (x0 + view.road_width - 1, view.height - 1)
        cv2.rectangle(road, *corners, (0, 0, 0), 5)  # a dark rim keeps the frame visible
        cv2.rectangle(road, *corners, (255, 255, 255), 2)
        view.draw_needle(gauge, float(state[1]))
    return np.concatenate([road, gap, gauge], axis=1)
