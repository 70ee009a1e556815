"""An object's shape from its MuJoCo model: points on the surface of its geoms (meshes and
primitives, every body of it), and the rotational symmetry they show.

Example:
    >>> points = surface_points(object_spec("can").make("probe"))  # (N, 3) metres, body frame
    >>> estimate_symmetry(points, shape_tolerance(points)).axis
    tensor([0., 0., 1.])
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import torch
from torch import Tensor

from vistask.envs.scene import geom_to_body, subtree_geoms

# A turned point may lie this share of the object's largest extent from its surface (at least
# SHAPE_TOLERANCE_MIN): a lemon's 40 x 43 mm section turned about its long axis moves its
# outline 1.5 mm at most, the bottle's six-sided body 3.4 mm over its 160 mm.
SHAPE_TOLERANCE = 0.025
SHAPE_TOLERANCE_MIN = 0.0005  # metres: the surface samples lie about 0.2 mm apart on a 1 cm cube
POINTS = 20_000  # surface points an object's shape is sampled with
MAX_EXTENT = 0.5  # metres: larger objects do not fit on the table beside others
ORIGIN_MARGIN = 0.01  # metres the body's origin may lie outside its geoms' box


def compile_alone(obj) -> tuple[mujoco.MjModel, mujoco.MjData, int]:
    """The robosuite object ``obj`` compiled in an empty world: model, data after
    ``mj_forward``, and its root body's id."""
    from robosuite.models.world import MujocoWorldBase

    world = MujocoWorldBase()
    world.merge_assets(obj)
    world.worldbody.append(obj.get_obj())
    model = world.get_model(mode="mujoco")
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data, model.body(obj.root_body).id


def surface_points(obj, n: int = POINTS, seed: int = 0) -> Tensor:
    """(n, 3) float64 points on the surface of the robosuite object ``obj``'s geoms (its
    visual geoms, else its collision geoms; every body below its root), in its root body's
    frame, spread by area."""
    return _surface_points(obj, *compile_alone(obj), n, seed)


def table_object_shape(obj, label: str) -> tuple[Tensor, Tensor]:
    """``surface_points`` of an object that can stand on the table, and (3 G, 3) float64 the
    axes of its G geoms' frames in its root body's frame (a box's or cylinder's axes are
    those of its symmetries, where the shape's principal axes may be any, as a cube's).

    Raises:
        ValueError: naming ``label`` and why not: MuJoCo cannot compile it, none of its geoms
            collides (it would fall through the table), it is larger than ``MAX_EXTENT``
            (lengths in millimetres, say), or its body's origin, by which it is placed, lies
            outside its geoms.
    """
    try:
        model, data, root = compile_alone(obj)
    except Exception as error:  # MuJoCo's compile errors name robosuite's copy, not the file
        raise ValueError(f"{label}: MuJoCo cannot compile it ({error})") from None
    own = subtree_geoms(model, root)
    if not ((model.geom_contype[own] | model.geom_conaffinity[own]) != 0).any():
        raise ValueError(
            f"{label}: none of its geoms collides (contype and conaffinity 0): it would fall "
            "through the table"
        )
    points = _surface_points(obj, model, data, root)
    low, high = points.min(0).values, points.max(0).values
    if float((high - low).max()) > MAX_EXTENT:
        raise ValueError(
            f"{label} is {float((high - low).max()):.2f} m across, more than the table takes "
            f"({MAX_EXTENT} m): MJCF lengths are metres (a mesh drawn in millimetres needs "
            'scale="0.001 0.001 0.001")'
        )
    if bool((low[:2] > ORIGIN_MARGIN).any() or (high[:2] < -ORIGIN_MARGIN).any()):
        middle = ((low + high) / 2).tolist()
        raise ValueError(
            f"{label}: its body's origin lies outside its geoms (their middle is at "
            f"{[round(v, 3) for v in middle]} m from it), and robosuite places an object by "
            "that origin: move the geoms (their pos) so that it lies within them"
        )
    rotations = [data.xmat[root].reshape(3, 3).T @ data.geom_xmat[g].reshape(3, 3) for g in own]
    return points, torch.from_numpy(np.concatenate([r.T for r in rotations]))


def _surface_points(obj, model, data, root: int, n: int = POINTS, seed: int = 0) -> Tensor:
    own = subtree_geoms(model, root)
    # robosuite's visual geoms (group 1) show the shape; collision geoms (group 0) are often
    # coarse hulls (the bottle's is six-sided).
    visual = own[model.geom_group[own] == 1]
    geoms = visual if len(visual) else own[model.geom_group[own] == 0]
    if not len(geoms):
        raise ValueError(f"object {obj.name!r} has no geoms")
    rng = np.random.default_rng(seed)
    areas = np.array([_area(model, g) for g in geoms])
    counts = rng.multinomial(n, areas / areas.sum())
    parts = [
        geom_to_body(data, g, root, _sample(model, g, count, rng))
        for g, count in zip(geoms, counts, strict=True)
    ]
    return torch.from_numpy(np.concatenate(parts))


def shape_tolerance(points: Tensor) -> float:
    """How far a turned point may lie from the shape ``points`` (N, 3) and still count as on
    it: ``SHAPE_TOLERANCE`` of its largest extent, at least ``SHAPE_TOLERANCE_MIN``."""
    extent = float((points.max(0).values - points.min(0).values).max())
    return max(SHAPE_TOLERANCE * extent, SHAPE_TOLERANCE_MIN)


def _triangles(model: mujoco.MjModel, geom: int) -> tuple[np.ndarray, ...]:
    """The corners a, b, c (T, 3) of a mesh geom's triangles in the geom's frame, and the
    triangles' areas (T,)."""
    mesh = model.geom_dataid[geom]
    start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
    first, faces = model.mesh_faceadr[mesh], model.mesh_facenum[mesh]
    vertices = model.mesh_vert[start : start + count]
    a, b, c = (vertices[model.mesh_face[first : first + faces, i]] for i in range(3))
    return a, b, c, np.linalg.norm(np.cross(b - a, c - a), axis=1) / 2


def _radii(model: mujoco.MjModel, geom: int) -> np.ndarray:
    """(3,) semi-axes of a sphere or ellipsoid geom."""
    size = model.geom_size[geom]
    return np.repeat(size[0], 3) if model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_SPHERE else size


def _box_faces(model: mujoco.MjModel, geom: int) -> np.ndarray:
    """(3,) areas of the quarter faces of a geom's bounding box, across x, y and z."""
    half = model.geom_aabb[geom, 3:]
    return np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]])


ROUND = (mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_ELLIPSOID)
TUBES = (mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_CAPSULE)


def _area(model: mujoco.MjModel, geom: int) -> float:
    """Surface area of a geom (ellipsoids as spheres of their mean semi-axis; any shape not
    handled here by its bounding box)."""
    kind, size = model.geom_type[geom], model.geom_size[geom]
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        return float(_triangles(model, geom)[3].sum())
    if kind in ROUND:
        return 4 * math.pi * float(_radii(model, geom).mean()) ** 2
    if kind in TUBES:
        r, h = size[0], size[1]
        return float(2 * math.pi * r * 2 * h + 4 * math.pi * r * r)
    return float(8 * _box_faces(model, geom).sum())


def _sample(model: mujoco.MjModel, geom: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) points on a geom's surface in its frame (meshes by area; spheres, ellipsoids,
    cylinders and capsules by their parametrisation; other shapes on their bounding box)."""
    kind, size = model.geom_type[geom], model.geom_size[geom]
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        a, b, c, area = _triangles(model, geom)
        pick = rng.choice(len(area), n, p=area / area.sum())
        u, v = rng.uniform(size=(2, n, 1))
        flip = (u + v) > 1
        u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
        return a[pick] + u * (b[pick] - a[pick]) + v * (c[pick] - a[pick])
    if kind in ROUND:
        d = rng.normal(size=(n, 3))
        return d / np.linalg.norm(d, axis=1, keepdims=True) * _radii(model, geom)
    if kind in TUBES:
        r, h = size[0], size[1]
        side = rng.uniform(size=n) < (2 * h) / (2 * h + 2 * r)  # the rest on caps or domes
        theta = rng.uniform(0, 2 * math.pi, n)
        z = np.where(side, rng.uniform(-h, h, n), np.where(rng.uniform(size=n) < 0.5, -h, h))
        if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
            d = rng.normal(size=(n, 3))
            dome = d / np.linalg.norm(d, axis=1, keepdims=True) * r
            dome[:, 2] = np.abs(dome[:, 2]) * np.sign(z) + z
            ring = np.stack([r * np.cos(theta), r * np.sin(theta), z], 1)
            return np.where(side[:, None], ring, dome)
        rho = np.where(side, r, r * np.sqrt(rng.uniform(size=n)))
        return np.stack([rho * np.cos(theta), rho * np.sin(theta), z], 1)
    half, centre = model.geom_aabb[geom, 3:], model.geom_aabb[geom, :3]
    faces = _box_faces(model, geom)
    face = rng.choice(6, n, p=np.tile(faces, 2) / (2 * faces.sum()))
    points = rng.uniform(-half, half, (n, 3))
    axis, sign = face % 3, np.where(face < 3, -1.0, 1.0)
    points[np.arange(n), axis] = sign * half[axis]
    return points + centre
