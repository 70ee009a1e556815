"""Objects for the tabletop scenes and grasp trials, named by robosuite class or MJCF file.

``object_spec(name)`` resolves a name to an ``ObjectSpec``:

- a preset: a robosuite object with fixed sizes ("box", "cube", "hammer"; add your own with
  ``register_object``);
- a robosuite object class, as its class name or in snake case without ``Object``
  ("CanObject", "can", "bottle", "lemon", "round_nut", ...), at robosuite's own sizes; it is
  named in snake case, with ``_object`` where a preset has that name ("BoxObject" ->
  "box_object");
- a MuJoCo XML file in robosuite's object format (``*.xml``): a ``<body name="object">``
  holding the geoms, as in robosuite's ``models/assets/objects`` (whose sites ``bottom_site``,
  ``top_site`` and ``horizontal_radius_site`` are optional: objects are placed by the box
  around their geoms).

Objects that robosuite generates at random sizes (boxes, cylinders) are built with a fixed
generator, so every process builds the same object. An object's symmetry is estimated from its
model (``shape_symmetry``): the rotations that turn its surface onto itself.

Poses are (7,) ``[tx, ty, tz, qx, qy, qz, qw]`` (roma XYZW), object frame -> world.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import roma
import torch
from torch import Tensor

from vistask.vision import Symmetry, estimate_symmetry

# Distractors of tabletop scenes and grasp trials when none are named.
DEFAULT_DISTRACTORS = ("cereal", "milk", "bread", "hammer", "can", "box")


@dataclass(frozen=True)
class ObjectSpec:
    """An object kind.

    Attributes:
        name: its name in scenes, results and file names.
        make: builds the robosuite object, given the MuJoCo name of the instance.
        symmetry: rotational symmetry of its shape, in its body frame.
        rest: (4,) XYZW rotation that stands it in its natural rest pose on the table.
        can_tip: whether it may be laid on a side (not objects round about a vertical axis,
            which would roll away).
        shape_symmetry: the symmetry of its shape alone where its texture breaks it (bread
            turned by half a turn), or None when that is ``symmetry``.
    """

    name: str
    make: Callable[[str], object]
    symmetry: Symmetry
    rest: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    can_tip: bool = True
    shape_symmetry: Symmetry | None = None


def _robosuite_classes() -> dict[str, type]:
    import robosuite.models.objects as objects

    return {
        name: cls
        for name, cls in vars(objects).items()
        if name.endswith("Object") and isinstance(cls, type) and not inspect.isabstract(cls)
    }


def _fixed(cls: type, **kwargs) -> Callable[[str], object]:
    """A builder of ``cls`` that passes a seeded generator where robosuite samples sizes, so
    that every build of one kind, in any process, gives the same object."""
    seeded = "rng" in inspect.signature(cls.__init__).parameters

    def make(name: str):
        if seeded:
            return cls(name, **kwargs, rng=np.random.default_rng(0))
        # The others (a ball, a capsule) draw their sizes from a fresh, unseeded
        # np.random.default_rng(): seed it for the one call.
        unseeded = np.random.default_rng
        np.random.default_rng = lambda seed=0, *args: unseeded(seed, *args)
        try:
            return cls(name, **kwargs)
        finally:
            np.random.default_rng = unseeded

    return make


# Objects whose texture tells apart poses that their shape does not: only the crust tells a
# loaf of bread from the loaf turned by half a turn about its z. Their ``symmetry`` is none,
# their ``shape_symmetry`` the shape's.
_TEXTURED = ("BreadObject",)
_SHAPES: dict[str, Symmetry] = {}  # estimated shape symmetries, by class name or file


def shape_symmetry(label: str, make: Callable[[str], object]) -> Symmetry:
    """The rotational symmetry of the shape of the object ``make`` builds, estimated from its
    model (``estimate_symmetry`` on its surface points) once per process for each ``label``;
    textures are not seen.

    Raises:
        ValueError: the object cannot stand on the table (``_buildable``,
            ``table_object_shape``), named by ``label``.
    """
    if label not in _SHAPES:
        from vistask.envs.object_shape import shape_tolerance, table_object_shape

        points, axes = table_object_shape(_buildable(label, make), label)
        _SHAPES[label] = estimate_symmetry(points, shape_tolerance(points), axes)
    return _SHAPES[label]


_PRESETS: dict[str, ObjectSpec | Callable[[], ObjectSpec]] = {}  # a spec, or its maker


def _can_tip(symmetry: Symmetry) -> bool:
    """Cans and bottles, round about their upright axis, would roll away on a side."""
    return symmetry.axis is None or abs(float(symmetry.axis[2])) < 0.5


def register_object(spec: ObjectSpec) -> None:
    """Make ``spec`` known by its name to ``object_spec`` (in this process only: processes
    that run trials or scenes resolve names themselves, so give them files or classes)."""
    _PRESETS[spec.name] = spec


def _preset(name: str, cls_name: str, **kwargs) -> None:
    """Register a robosuite object of fixed sizes; its symmetry is estimated when first used
    (building it imports robosuite)."""

    def make(instance: str):
        return _fixed(_robosuite_classes()[cls_name], **kwargs)(instance)

    def spec() -> ObjectSpec:
        sym = shape_symmetry(name, make)
        return ObjectSpec(name, make, sym, can_tip=_can_tip(sym))

    _PRESETS[name] = spec


_preset("box", "BoxObject", size=(0.045, 0.03, 0.02), rgba=(0.15, 0.45, 0.8, 1.0))
_preset("cube", "BoxObject", size=(0.021, 0.021, 0.021), rgba=(0.8, 0.15, 0.1, 1.0))
# Fixed sizes: robosuite samples the hammer's geometry at random. robosuite builds it standing
# on its handle; ``rest`` lays it flat.
register_object(
    ObjectSpec(
        "hammer",
        lambda instance: _fixed(
            _robosuite_classes()["HammerObject"],
            handle_radius=0.016,
            handle_length=0.16,
            handle_density=150.0,
            handle_friction=4.0,
        )(instance),
        Symmetry.none(),
        rest=(0.5, -0.5, 0.5, -0.5),
        can_tip=False,
    )
)
# The built-in presets' names: a robosuite class of one of them is named apart from it, in
# every process, whatever a user registers.
_BUILT_IN = frozenset(_PRESETS)


def object_source(name: str | Path) -> str:
    """What builds the object ``name`` names: an MJCF file's resolved path, ``preset <name>``,
    or a robosuite class name. Names with one source name one object."""
    text = str(name)
    if text.lower().endswith(".xml"):
        return str(Path(text).resolve())
    return f"preset {text}" if text in _PRESETS else _class_name(text)


def check_same_object(folder: Path, name: str | Path) -> None:
    """Record in ``folder/object.json`` what builds the object ``name`` (``object_source``, and
    an MJCF file's SHA-256), or, where a stopped run left one, refuse another object: an
    edited file or another file of the same name."""
    source = {"source": object_source(name)}
    if source["source"].lower().endswith(".xml"):
        source["sha256"] = hashlib.sha256(Path(source["source"]).read_bytes()).hexdigest()
    path = Path(folder) / "object.json"
    if path.exists() and json.loads(path.read_text()) != source:
        raise ValueError(
            f"{folder} holds results of another object than {name} (another file, or the file "
            "was edited since): pick another output folder, or remove that one"
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(source, indent=1))


def _class_name(name: str) -> str:
    """The robosuite class name of an object name: "round_nut" -> "RoundNutObject",
    "box_object" -> "BoxObject"."""
    if name.endswith("Object"):
        return name
    name = name.removesuffix("_object")
    return "".join(part.capitalize() for part in re.split(r"[_\-\s]+", name)) + "Object"


def _mjcf_spec(path: Path) -> ObjectSpec:
    from robosuite.models.objects import MujocoXMLObject

    if not path.is_file():
        raise ValueError(f"no MJCF file at {path}")
    try:
        root = ElementTree.parse(path).getroot()
    except ElementTree.ParseError as error:
        raise ValueError(f"{path} is not valid XML ({error})") from None
    check_mjcf(path, root)
    fname = str(path.resolve())
    name = re.sub(r"\W", "_", path.stem)

    def make(instance: str):
        return MujocoXMLObject(
            fname, instance, joints=[{"type": "free", "damping": "0.0005"}], obj_type="all"
        )

    return ObjectSpec(name, make, shape_symmetry(fname, make))


def check_mjcf(path: Path, root: ElementTree.Element) -> None:
    """Raise ValueError naming ``path`` and the reason where robosuite's ``MujocoXMLObject``
    would misread the MJCF model ``root``: another layout than ``<worldbody><body><body
    name="object">``; a geom of no group or another than 0 (collision) and 1 (visual), the
    two robosuite keeps, or no geom of group 0; a free joint of the file's own (robosuite
    adds one); compiler settings and includes that robosuite does not follow (angles in
    degrees, ``meshdir``, ``texturedir``, ``assetdir``, ``<include>``)."""
    body = root.find("./worldbody/body/body[@name='object']")
    if root.tag != "mujoco" or body is None:
        raise ValueError(
            f"{path} must be an MJCF <mujoco> model laid out as <worldbody><body><body "
            'name="object"> holding the geoms (robosuite\'s MujocoXMLObject layout)'
        )
    groups = _geom_groups(root)
    for name, group in groups:
        if group not in ("0", "1"):
            raise ValueError(
                f'{path}: geom {name!r} has group {group!r}: robosuite keeps group "0" '
                '(collision) and "1" (visual) geoms; give each geom one of them'
            )
    if "0" not in {group for _, group in groups}:
        raise ValueError(f'{path}: no geom of group "0", robosuite\'s collision geoms')
    if body.find(".//freejoint") is not None or any(
        joint.get("type") == "free" for joint in body.iter("joint")
    ):
        raise ValueError(
            f"{path}: robosuite gives the object its free joint: remove the file's own "
            "(<freejoint/> or a joint of type free)"
        )
    for compiler in root.iter("compiler"):
        if compiler.get("angle", "radian") != "radian":
            raise ValueError(
                f"{path}: <compiler angle={compiler.get('angle')!r}>: robosuite merges objects "
                "into a model whose angles are radians; give euler and axisangle in radians"
            )
        for folder in ("meshdir", "texturedir", "assetdir"):
            if compiler.get(folder) is not None:
                raise ValueError(
                    f"{path}: <compiler {folder}=...> is not followed by robosuite: give each "
                    "file's path relative to the XML file's folder"
                )
    if root.find(".//include") is not None:
        raise ValueError(f"{path}: robosuite does not follow <include>: copy the file in")


def _geom_groups(root: ElementTree.Element) -> list[tuple[str, str | None]]:
    """(name, group) of each geom of an MJCF model, its group given or taken from its default
    class (the geom's ``class``, else the nearest body's ``childclass``, else ``main``)."""
    defaults: dict[str, str | None] = {}

    def read(default: ElementTree.Element, inherited: str | None) -> None:
        geom = default.find("geom")
        group = inherited if geom is None else geom.get("group", inherited)
        defaults[default.get("class", "main")] = group
        for child in default.findall("default"):
            read(child, group)

    for default in root.findall("default"):
        read(default, None)
    found = []

    def walk(element: ElementTree.Element, childclass: str) -> None:
        for child in element:
            if child.tag == "geom":
                group = child.get("group", defaults.get(child.get("class", childclass)))
                found.append((child.get("name") or child.get("type") or "sphere", group))
            walk(child, child.get("childclass", childclass))

    walk(root.find("worldbody"), "main")
    return found


def _buildable(label: str, make: Callable[[str], object]) -> object:
    """The object ``make`` builds; raise ValueError naming ``label`` and why it cannot stand
    on the table: robosuite cannot build it from a name alone (a base class), it has no
    collision geoms (a visual-only twin) or no free joint (a fixture such as a door)."""
    try:
        obj = make("probe")
    except Exception as error:  # robosuite raises TypeError, AssertionError, ... alike
        reason = f"{type(error).__name__}: {error}"
        raise ValueError(f"{label}: robosuite cannot build it ({reason})") from None
    if obj.obj_type == "visual":
        raise ValueError(f"{label} has only visual geoms: nothing to collide with or grasp")
    if not any(joint.get("type") == "free" for joint in obj.get_obj().iter("joint")):
        raise ValueError(
            f"{label} has no free joint (a fixture, such as a door in its frame): it cannot "
            "be placed on the table"
        )
    return obj


def object_spec(name: str | Path | ObjectSpec) -> ObjectSpec:
    """The ``ObjectSpec`` of a preset, a robosuite object class or an MJCF file (see the
    module docstring).

    Raises:
        ValueError: nothing of that name, a missing file, an MJCF file robosuite cannot read
            (``check_mjcf``), or an object that cannot stand on the table (a base class, no
            colliding geom, a fixture without a free joint, too large, placed by an origin
            outside it).
    """
    if isinstance(name, ObjectSpec):
        return name
    text = str(name)
    if text.lower().endswith(".xml"):
        return _mjcf_spec(Path(text))
    if text in _PRESETS:
        if not isinstance(_PRESETS[text], ObjectSpec):
            _PRESETS[text] = _PRESETS[text]()
        return _PRESETS[text]
    classes = _robosuite_classes()
    cls_name = _class_name(text)
    if cls_name not in classes or cls_name in ("MujocoObject", "MujocoXMLObject"):
        raise ValueError(
            f"unknown object {text!r}: name a preset {sorted(_PRESETS)}, a robosuite object "
            "class (e.g. 'can', 'LemonObject') or an MJCF file ending in .xml"
        )
    make = _fixed(classes[cls_name])
    shape = shape_symmetry(cls_name, make)
    sym = Symmetry.none() if cls_name in _TEXTURED else shape
    snake = re.sub(r"(?<!^)(?=[A-Z])", "_", cls_name.removesuffix("Object")).lower()
    # A preset of fixed sizes may hold the short name ("box"): the class at robosuite's own
    # sizes is another object, so it gets another name ("box_object") in scenes and results.
    return ObjectSpec(
        f"{snake}_object" if snake in _BUILT_IN else snake,
        make,
        sym,
        can_tip=_can_tip(shape),
        shape_symmetry=shape if cls_name in _TEXTURED else None,
    )


def object_name(name: str | Path | ObjectSpec) -> str:
    """The name results and files use for an object (a file's stem for MJCF files)."""
    return object_spec(name).name


def rest_rotation(
    spec: ObjectSpec, rng: np.random.Generator | None = None, tip_probability: float = 0.0
) -> Tensor:
    """(3, 3) float64 rest orientation, laid on a random side (+-90 degrees about its x or y
    axis) with ``tip_probability`` when the object may tip. Physics then settles it where
    it rests."""
    rot = roma.unitquat_to_rotmat(torch.tensor(spec.rest, dtype=torch.float64))
    if rng is not None and spec.can_tip and rng.uniform() < tip_probability:
        rot = rot @ _side_turn(rng.integers(0, 2), rng.choice([-1.0, 1.0]))
    return rot


def lying_rotations(spec: ObjectSpec) -> list[Tensor]:
    """The four (3, 3) float64 orientations ``rest_rotation`` lays ``spec`` on a side in
    (before physics settles it): its rest pose turned by -90 and +90 degrees about its x, then
    by -90 and +90 degrees about its y."""
    rest = rest_rotation(spec)
    return [rest @ _side_turn(axis, sign) for axis in (0, 1) for sign in (-1.0, 1.0)]


def _side_turn(axis: int, sign: float) -> Tensor:
    """(3, 3) quarter turn of sign ``sign`` about the object's ``axis`` (0: x, 1: y)."""
    return roma.rotvec_to_rotmat(torch.from_numpy(np.eye(3)[axis] * sign * (math.pi / 2)))


def yaw_rotation(yaw: float) -> Tensor:
    """(3, 3) float64 rotation by ``yaw`` radians about the world's z."""
    return roma.rotvec_to_rotmat(torch.tensor([0.0, 0.0, yaw], dtype=torch.float64))


def box_corners(bounds: np.ndarray | Tensor, rot: Tensor) -> Tensor:
    """(8, 3) corners of the (2, 3) object-frame box ``bounds`` turned by ``rot`` (3, 3)."""
    lo, hi = torch.as_tensor(np.asarray(bounds), dtype=torch.float64)
    grid = torch.meshgrid(*torch.stack([lo, hi], dim=1), indexing="ij")
    return torch.stack(grid, -1).reshape(-1, 3) @ rot.T


def drop_pose(bounds, rot: Tensor, xy: Sequence[float], floor_z: float) -> Tensor:
    """(7,) float64 pose at ``xy`` turned by ``rot``, its lowest corner 3 mm above
    ``floor_z``."""
    corners = box_corners(bounds, rot)
    z = floor_z + 0.003 - float(corners[:, 2].min())
    t = torch.tensor([float(xy[0]), float(xy[1]), z], dtype=torch.float64)
    return torch.cat([t, roma.rotmat_to_unitquat(rot)])


def place_apart(
    rng: np.random.Generator,
    radii: Sequence[float],
    spans: Sequence[float],
    gap: float,
    placed: Sequence[tuple[np.ndarray, float]] = (),
) -> list[np.ndarray]:
    """Random (2,) positions, the i-th uniform in +-``spans[i]``, discs of ``radii`` at least
    ``gap`` apart from each other and from the ``placed`` (position, radius) discs.

    Raises:
        NoRoomError: no room found in 500 draws for one of them.
    """
    return _place(
        rng, radii, gap, placed, [lambda span=span: rng.uniform(-span, span, 2) for span in spans]
    )


def place_occluders(
    rng: np.random.Generator,
    radii: Sequence[float],
    gap: float,
    target: tuple[np.ndarray, float],
    towards: Sequence[float],
) -> list[np.ndarray]:
    """Random (2,) positions of discs of ``radii`` between the ``target`` (position,
    radius) disc and the point ``towards`` (a camera's x, y): just clear of the target (up to
    12 cm farther) and at most half a target-and-disc width sideways, ``gap`` apart.

    Raises:
        NoRoomError: no room found in 500 draws for one of them.
    """
    centre, r0 = target
    ahead = np.asarray(towards, dtype=float) - centre
    ahead /= max(float(np.linalg.norm(ahead)), 1e-9)
    side = np.array([-ahead[1], ahead[0]])

    def draw(r: float) -> np.ndarray:
        forward = r0 + r + gap + rng.uniform(0.0, 0.12)
        return centre + ahead * forward + side * rng.uniform(-0.5, 0.5) * (r0 + r)

    return _place(rng, radii, gap, [target], [lambda r=r: draw(r) for r in radii])


class NoRoomError(ValueError):
    """The objects of a scene find no room apart on the table."""


def _place(rng, radii, gap, placed, draws) -> list[np.ndarray]:
    taken = list(placed)
    out = []
    for radius, draw in zip(radii, draws, strict=True):
        for _ in range(500):
            xy = draw()
            if all(np.linalg.norm(xy - c) > radius + r + gap for c, r in taken):
                break
        else:
            raise NoRoomError(
                f"no room for an object {2 * radius:.2f} m across, {gap} m from the "
                f"{len(taken)} placed: the objects are too large for the table, or too many"
            )
        taken.append((xy, radius))
        out.append(xy)
    return out


def footprint_radius(bounds, rot: Tensor) -> float:
    """Radius of the table area the box ``bounds`` turned by ``rot`` may cover."""
    return float(box_corners(bounds, rot)[:, :2].norm(dim=-1).max())


MAX_DISTRACTORS = 4  # other objects on the grasp trials' table at most


def distinct_object_specs(argument: str, kinds: Sequence[str | Path]) -> dict[str, ObjectSpec]:
    """The specs of ``kinds`` by name, a kind named twice once; ValueError naming
    ``argument`` where two sources (files, classes, presets) give objects of one name."""
    specs: dict[str, ObjectSpec] = {}
    sources: dict[str, str] = {}
    for kind in dict.fromkeys(kinds):
        spec, source = named_object_spec(argument, kind), object_source(kind)
        if sources.setdefault(spec.name, source) != source:
            raise ValueError(
                f"{argument}: {kind!r} and {sources[spec.name]!r} are other objects of one "
                f"name, {spec.name!r}: rename one"
            )
        specs.setdefault(spec.name, spec)
    return specs


def named_object_spec(argument: str, name: str):
    """``object_spec(name)``, its error naming the argument that gave the name."""
    try:
        return object_spec(name)
    except (ValueError, TypeError) as error:
        raise type(error)(f"{argument}: {error}") from None
