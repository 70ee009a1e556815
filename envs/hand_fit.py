"""Whether an object resting on the table in a given orientation has a part that a parallel
hand can close across: the test behind the objects and poses ``bench_grasp_objects.py`` keeps.

The object's collision geoms are probed with vertical rays on a grid (``column_heights``), which
gives its solid cross-section at every height. Fingers come down from above and close
horizontally (a finger under the object would be under the table), their tips ``clearance``
above the table or higher. A cross-section part fits when, in some horizontal direction:

- it is narrower than the opening;
- the fingers reach it: nothing of the object lies above the closing height just beyond the
  part on either side (a ball's lower half is under its widest circle);
- its sides face the fingers: above the closing height the part narrows by at most ``SLOPE``
  times the height climbed on each side (the rim of a ball's cap slopes away, and the closing
  fingers squeeze it out).

A part also fits when it is a wall around a hole that a finger fits into (a nut's rim, a tube's
wall) and the wall is thinner than the opening. It is a geometric test, not a simulation: the
fingers' length, the object's weight and how the hand approaches are left out.

Example:
    >>> from vistask.envs.objects import object_spec, rest_rotation
    >>> spec = object_spec("BoxObject")  # 111 x 82 x 63 mm, resting on its largest face
    >>> pose_misfit(spec.make("probe"), rest_rotation(spec))
    'narrowest part 82 mm across, above 10 mm: wider than the 80 mm opening'
"""

from __future__ import annotations

import math
import warnings

import mujoco
import numpy as np
from scipy import ndimage
from torch import Tensor

from vistask.envs.object_shape import compile_alone
from vistask.envs.objects import box_corners
from vistask.envs.scene import body_bounds, subtree_geoms

CELL = 0.002  # metres between the probing rays
CLEARANCE = 0.01  # metres from the table up to the lowest height the fingertips close at
RISE = 0.004  # metres above the closing height over which a side's lean is measured
FINGER = 0.012  # metres: a hole this wide takes a fingertip
SLOPE = 0.7  # most a side may lean away from the fingers, metres per metre (35 degrees):
# inside the 45 degrees that robosuite objects' friction of 1 holds, with room for the weight
DIRECTIONS = np.linspace(0.0, math.pi, 36, endpoint=False)  # horizontal closing directions


def column_heights(obj, rot: Tensor, cell: float = CELL) -> tuple[np.ndarray, np.ndarray]:
    """Bottom and top (H, W) of the robosuite object ``obj``'s collision geoms along vertical
    rays on a ``cell`` grid, the object turned by ``rot`` (3, 3) and resting on z = 0 (NaN where
    a ray misses it); rows run along y, columns along x, in metres.

    Raises:
        ValueError: no ray meets a collision geom of the object.
    """
    model, data, root = compile_alone(obj)
    # Rested frame -> the compiled world: undo the turn, then the root body's placement.
    to_world = data.xmat[root].reshape(3, 3) @ rot.numpy().T
    centre = data.xpos[root]
    corners = box_corners(body_bounds(model, data, root, subtree_geoms(model, root)), rot).numpy()
    lo, hi = corners.min(0) - cell, corners.max(0) + cell
    # Rays half a cell off the grid of the bounds: none grazes a box geom's face.
    xs, ys = np.arange(lo[0] + cell / 2, hi[0], cell), np.arange(lo[1] + cell / 2, hi[1], cell)
    groups = np.array([1, 0, 0, 0, 0, 0], np.uint8)  # robosuite's collision geoms
    hit = np.zeros(1, np.int32)

    def ray(x: float, y: float, z: float, direction: list[float]) -> float:
        """Distance from (x, y, z) along ``direction``, both in the rested frame, to the
        object (-1: it misses)."""
        start = centre + to_world @ [x, y, z]
        return mujoco.mj_ray(model, data, start, to_world @ direction, groups, 1, -1, hit)

    bottom = np.full((len(ys), len(xs)), np.nan)
    top = np.full_like(bottom, np.nan)
    for i, y in enumerate(ys):
        for j, x in enumerate(xs):
            down, up = ray(x, y, hi[2], [0.0, 0.0, -1.0]), ray(x, y, lo[2], [0.0, 0.0, 1.0])
            if down >= 0 and up >= 0:
                top[i, j], bottom[i, j] = hi[2] - down, lo[2] + up
    if np.isnan(top).all():
        raise ValueError(f"object {obj.name!r}: no vertical ray meets its collision geoms")
    floor = np.nanmin(bottom)
    return bottom - floor, top - floor


def pose_misfit(obj, rot: Tensor, opening: float | None = None, cell: float = CELL) -> str | None:
    """Why the object ``obj``, resting turned by ``rot`` (3, 3), has no part a hand opening
    ``opening`` metres wide (default: the Panda's) can close across; None when it has one."""
    from vistask.envs.grasp_trial import PANDA_MAX_OPENING

    opening = PANDA_MAX_OPENING if opening is None else opening
    bottom, top = column_heights(obj, rot, cell)
    if np.nanmax(top) <= CLEARANCE:
        return f"lower than {1000 * CLEARANCE:.0f} mm: nothing above the fingertips to close across"
    narrowest, fitting = math.inf, False
    for h in np.arange(CLEARANCE, np.nanmax(top), cell):
        solid = (bottom <= h) & (top >= h)
        open_above = np.isnan(top) | (top < h)
        parts, n = ndimage.label(solid, structure=np.ones((3, 3)))
        for k in range(1, n + 1):
            part = parts == k
            here = _projections(part)
            widths = (np.ptp(here, axis=0) + 1) * cell
            closable = widths < opening
            narrowest = min(narrowest, widths.min())
            fitting |= bool(closable.any())
            if _closes_across(part, here, top - h, open_above, closable, cell):
                return None
            if _wall_fits(part, open_above, opening, cell):
                return None
    if fitting:
        return (
            f"no part narrower than the {1000 * opening:.0f} mm opening that fingers from above "
            f"reach with its sides facing them (a rounded top or underside)"
        )
    return (
        f"narrowest part {1000 * narrowest:.0f} mm across, above {1000 * CLEARANCE:.0f} mm: "
        f"wider than the {1000 * opening:.0f} mm opening"
    )


def pose_misfits(spec, conditions: tuple[str, ...] = ("upright", "lying")) -> dict[str, str]:
    """Why the object of ``ObjectSpec`` ``spec`` cannot be grasped, per condition of
    ``conditions``: ``"upright"``, standing as built (``pose_misfit`` of its rest pose), or
    ``"lying"``, on at least one of the four sides ``lying_rotations`` lays it on (objects
    round about their upright axis, which would roll away, do not lie). Empty when all fit."""
    from vistask.envs.objects import lying_rotations, rest_rotation

    misfits, obj = {}, spec.make("probe")
    if "upright" in conditions:
        upright = pose_misfit(obj, rest_rotation(spec))
        if upright is not None:
            misfits["upright"] = upright
    if "lying" not in conditions:
        return misfits
    if not spec.can_tip:
        misfits["lying"] = "round about its upright axis, it would roll away on a side"
        return misfits
    turns = (
        "-90 degrees about x",
        "+90 degrees about x",
        "-90 degrees about y",
        "+90 degrees about y",
    )
    for turn, rot in zip(turns, lying_rotations(spec), strict=True):
        reason = pose_misfit(obj, rot)
        if reason is not None:
            misfits["lying"] = f"turned {turn}: {reason}"
            break
    return misfits


def warn_misfits(spec, tip_probability: float) -> None:
    """Warn when trials will place the object of ``spec`` in a pose no grasp can close across
    (``pose_misfits``): standing as built, or (with ``tip_probability`` > 0) on some side; the
    warning says which resting pose fits, if any."""
    misfits = pose_misfits(spec)
    used = ("upright",) * (tip_probability < 1) + ("lying",) * (tip_probability > 0)
    wrong = [c for c in used if c in misfits and (c == "upright" or spec.can_tip)]
    if not wrong:
        return
    where = {"upright": "standing as built", "lying": "on some sides"}
    why = "; ".join(f"{where[c]}, {misfits[c]}" for c in wrong)
    if "upright" not in misfits:
        advice = "stand it upright (tip_probability=0, --tip-probability 0)"
    elif "lying" not in misfits:  # pose_misfits gives one that cannot tip a "lying" misfit
        advice = "lay it on a side (tip_probability=1, --tip-probability 1)"
    else:
        advice = "no resting pose fits: make it smaller, or it will not be grasped"
    warnings.warn(f"{spec.name}: no part fits the hand ({why}): {advice}", stacklevel=2)


def _projections(cells: np.ndarray) -> np.ndarray:
    """(N, D) positions, in cells, of the N true cells of (H, W) ``cells`` along each of the
    ``DIRECTIONS``."""
    rows, cols = np.nonzero(cells)
    return np.outer(cols, np.cos(DIRECTIONS)) + np.outer(rows, np.sin(DIRECTIONS))


def _closes_across(
    part: np.ndarray,
    here: np.ndarray,
    rise: np.ndarray,
    open_above: np.ndarray,
    closable: np.ndarray,
    cell: float,
) -> bool:
    """Whether fingers from above close across a (H, W) cross-section part (its cells along
    the ``DIRECTIONS``: ``here`` = ``_projections(part)``) along one of the ``closable`` (D,)
    directions: the cells just beyond it on both sides are ``open_above`` ((H, W) bool), and
    where the part climbs ``RISE`` higher (or to its top, if nearer; ``rise`` is the (H, W)
    height of each column's top above the cross-section, metres) it is narrower on each side
    by at most ``SLOPE`` times the climb. A part climbing less than a cell has no side to
    hold."""
    climb = min(RISE, float(rise[part].max()))
    if not closable.any() or climb < cell:
        return False
    ring = ndimage.binary_dilation(part, np.ones((5, 5))) & ~part
    beyond = _projections(ring)
    up = _projections(part & (rise >= climb))
    blocked = ~open_above[ring]
    lean = SLOPE * climb / cell  # cells
    for d in np.flatnonzero(closable):
        lo, hi = here[:, d].min(), here[:, d].max()
        if blocked[beyond[:, d] < lo].any() or blocked[beyond[:, d] > hi].any():
            continue
        if up[:, d].min() - lo <= lean and hi - up[:, d].max() <= lean:
            return True
    return False


def _wall_fits(part: np.ndarray, open_above: np.ndarray, opening: float, cell: float) -> bool:
    """Whether a (H, W) cross-section part is a wall around a fingertip-wide hole that is
    open above (``open_above``, (H, W) bool), thinner than the opening: one finger in the
    hole, one outside."""
    holes = ndimage.binary_fill_holes(part) & ~part & open_above
    if not holes.any():
        return False
    hole = 2 * cell * ndimage.distance_transform_edt(holes).max()
    wall = 2 * cell * ndimage.distance_transform_edt(part).max()
    return hole >= FINGER and wall < opening
