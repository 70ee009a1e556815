"""Hierarchical object models: a Markov tree of features over SE(3) (paper Sect. 3.3).

- A *primitive feature* is an appearance class of patches (k-means on descriptors of the
  two side colours).
  Its instances in the object are the object-frame frames of the patches of that class.
- A *meta-feature* pairs two features. Its frame sits at the centroid of the primitive
  instances below it, with the object's orientation; it has one instance in the object.
  Learning pairs, greedily, the two features whose instances are jointly most compact: the
  child poses in the new parent's frame are then most concentrated (most strongly correlated).
- Each edge parent -> child holds a compatibility potential psi: an ``SE3KDE`` of the child's
  instance poses in the parent's frame (one particle for a meta-feature child).
- The root's world pose X_root gives the object pose X_root ∘ inverse(root frame).

Poses are (..., 7) ``[t, qx, qy, qz, qw]`` (roma XYZW); see ``vistask.se3``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy.cluster.vq import kmeans2
from torch import Tensor

from vistask.checks import check_at_least, checked
from vistask.objects.depth import evenly_spaced
from vistask.objects.pair_votes import PairTable
from vistask.saving import load_state, save_state
from vistask.se3 import SE3KDE, identity_poses, relative
from vistask.se3.kernels import check_bandwidth
from vistask.vision import Patches

MIN_PATCHES_PER_CLASS = 3
"""An appearance class needs at least this many instances to become a primitive feature."""

SURFACE_POINTS = 2000
"""Surface points a model keeps (evenly spaced in their order) for the colour check of pose
hypotheses (``DepthCheck.colour_agreement``)."""

PAIR_TABLE_PATCHES = 512
"""Patches of a model's pair table (``ObjectModel.pair_table``): the table grows with their
square, 0.07 s to build for 500 patches and 0.8 s for 1339 (the cereal box)."""


@checked
@dataclass
class Feature:
    """One node of the model's Markov tree.

    Attributes:
        children: indices of child features (empty for a primitive feature).
        parent: index of the parent, None for the root.
        appearance: the appearance class of a primitive feature, None for a meta-feature.
        frame: (7,) pose of the feature's (single) instance in the object frame, for a
            meta-feature; None for a primitive feature (it has many instances).
        potential: psi(parent, self): density of this feature's pose in the parent's frame;
            None for the root.
    """

    children: tuple[int, ...] = ()
    parent: int | None = None
    appearance: int | None = None
    frame: Tensor | None = None
    potential: SE3KDE | None = None

    @property
    def is_primitive(self) -> bool:
        """Whether the feature is an appearance class of patches (else a meta-feature)."""
        return self.appearance is not None


APPEARANCE = "side shares and relative brightness"
"""The appearance descriptor a model is learned with (saved models are checked against it)."""


@checked
def appearance_descriptors(colors: Tensor) -> Tensor:
    """(N, 2, 3) side colours (darker first) -> (N, 6) appearance descriptors that other light
    changes little.

    A brighter or tinted lamp multiplies each channel of both sides by about the same gain:

    - (N, 3) per channel, the darker side's share of the pair: unchanged by any gain per
      channel;
    - (N, 3) the brighter side's colour over the pair's mean brightness: unchanged by one gain
      for all channels, and it keeps the colour that tells lookalikes apart.

    Both parts span about [0, 1], so that k-means and the class radii weigh them alike
    (``docs/results.md``, "Pose estimation", measures them against raw colours).

    Example:
        >>> side = torch.tensor([[[0.4, 0.2, 0.2], [0.8, 0.6, 0.4]]])
        >>> appearance_descriptors(side).round(decimals=2)
        tensor([[0.3300, 0.2400, 0.3200, 0.8300, 0.6200, 0.4100]])
        >>> dimmer = side * torch.tensor([0.5, 0.6, 0.55])  # a dimmer, tinted lamp
        >>> appearance_descriptors(dimmer).round(decimals=2)
        tensor([[0.3200, 0.2400, 0.3100, 0.7000, 0.6300, 0.3900]])
    """
    if colors.dim() != 3 or colors.shape[1:] != (2, 3):
        raise ValueError(f"colors must have shape (N, 2, 3), got {tuple(colors.shape)}")
    colors = colors.float()
    # The small constants keep black and near-black patches from dividing noise by zero.
    shares = colors[:, 0] / (colors.sum(dim=1) + 0.02)
    brighter = colors[:, 1] * 0.5 / (colors.mean(dim=(1, 2))[:, None] + 0.05)
    return torch.cat([shares, brighter], dim=1)


@checked
@dataclass
class ObjectModel:
    """A learned hierarchical object model (see the module docstring).

    Attributes:
        name: object name.
        centres: (K, 6) appearance-class centres (``appearance_descriptors``).
        radii: (K,) accept radius of each class in descriptor space.
        features: the Markov tree; primitives first (feature k has appearance class k),
            the root last.
        patches: (N) the object-frame patches it was learned from (for drawing, baselines).
        labels: (N,) appearance class of each patch.
        grasp_density: optional ``SE3KDE`` of gripper poses in the object frame (psi_og).
        params: the keyword arguments ``learn`` was given (n_classes, sigma_t, sigma_r,
            meta_sigma_t, meta_sigma_r, class_radius, seed) and the ``APPEARANCE``
            descriptor's name.
        surface: (S, 6) object-frame surface points and their RGB colours in [0, 1]
            (``vistask.vision.object_surface``), against which NBP checks the colours under
            its hypotheses; None: no colour check.
    """

    name: str
    centres: Tensor
    radii: Tensor
    features: list[Feature]
    patches: Patches
    labels: Tensor
    grasp_density: SE3KDE | None = None
    params: dict[str, Any] = field(default_factory=dict)
    surface: Tensor | None = None
    _instances: dict[int, Tensor] = field(default_factory=dict, init=False, repr=False)
    _pair_table: PairTable | None = field(default=None, init=False, repr=False, compare=False)

    def __getstate__(self) -> dict:
        # The pair table is large (N^2 pairs) and quick to rebuild: workers make their own.
        return {**self.__dict__, "_pair_table": None}

    # --- learning --------------------------------------------------------------------------
    @classmethod
    def learn(
        cls,
        patches: Patches,
        name: str = "object",
        n_classes: int = 8,
        sigma_t: float = 0.004,
        sigma_r: float = 0.25,
        meta_sigma_t: float = 0.002,
        meta_sigma_r: float = 0.05,
        class_radius: float = 2.5,
        seed: int = 0,
        surface: Tensor | None = None,
    ) -> ObjectModel:
        """Learn a model from an object-frame patch set.

        Args:
            patches: (N) patches with normals, in the object frame.
            name: object name.
            n_classes: number of appearance classes (k-means clusters) before dropping small
                ones.
            sigma_t: position bandwidth (metres) of the primitive potentials.
            sigma_r: orientation bandwidth (radians) of the primitive potentials.
            meta_sigma_t, meta_sigma_r: bandwidth of meta-feature potentials (one exact
                particle).
            class_radius: an observed colour pair farther than this factor times the class's
                RMS radius from every centre belongs to no class (clutter of another appearance).
            seed: k-means seed.
            surface: (S, 6) object-frame surface points and colours from the same views
                (``vistask.vision.object_surface``); the model keeps ``SURFACE_POINTS`` of
                them. None: NBP does not check colours.

        Raises:
            ValueError: a bad parameter, patches without normals, too few patches, or a
                surface not of shape (S, 6).
        """
        if n_classes < 1:
            raise ValueError(f"n_classes must be >= 1, got {n_classes}")
        for arg, value in (
            ("sigma_t", sigma_t),
            ("sigma_r", sigma_r),
            ("meta_sigma_t", meta_sigma_t),
            ("meta_sigma_r", meta_sigma_r),
            ("class_radius", class_radius),
        ):
            if not value > 0:
                raise ValueError(f"{arg} must be positive, got {value}")
        check_bandwidth(sigma_t, sigma_r)
        check_bandwidth(meta_sigma_t, meta_sigma_r, names=("meta_sigma_t", "meta_sigma_r"))
        check_at_least(0, seed=seed)
        if patches.normals is None:
            raise ValueError("learning needs patches with normals (full patch frames)")
        need = 2 * MIN_PATCHES_PER_CLASS
        if len(patches) < need:
            raise ValueError(
                f"too few patches to learn a model: {len(patches)} (need at least {need})"
            )
        if surface is not None and (surface.dim() != 2 or surface.shape[1] != 6):
            raise ValueError(f"surface must have shape (S, 6), got {tuple(surface.shape)}")
        patches = patches.to("cpu")
        desc = appearance_descriptors(patches.colors)
        centres, labels = _kmeans(desc, n_classes, seed)
        # Small classes are noise: merge their patches into the nearest big class (until
        # every class is big; reassignment can leave a class short).
        while True:
            counts = torch.bincount(labels, minlength=len(centres))
            big = counts >= MIN_PATCHES_PER_CLASS
            if big.all():
                break
            if not big.any():
                raise ValueError("no appearance class has enough patches")
            centres = centres[big]
            labels = torch.cdist(desc, centres).argmin(dim=1)
        sq = ((desc - centres[labels]) ** 2).sum(dim=1)
        rms = torch.stack([sq[labels == k].mean().sqrt() for k in range(len(centres))])
        radii = class_radius * rms.clamp_min(0.02)
        features = _build_tree(
            patches.frames(), labels, len(centres), sigma_t, sigma_r, meta_sigma_t, meta_sigma_r
        )
        params = {
            "n_classes": n_classes,
            "sigma_t": sigma_t,
            "sigma_r": sigma_r,
            "meta_sigma_t": meta_sigma_t,
            "meta_sigma_r": meta_sigma_r,
            "class_radius": class_radius,
            "seed": seed,
            "appearance": APPEARANCE,
        }
        if surface is not None:
            surface = evenly_spaced(surface.float().cpu(), SURFACE_POINTS)
        return cls(name, centres, radii, features, patches, labels, None, params, surface)

    # --- structure ---------------------------------------------------------------------------
    @property
    def n_classes(self) -> int:
        """Number of appearance classes (primitive features)."""
        return self.centres.shape[0]

    @property
    def root(self) -> int:
        """Index of the root feature (the object's frame)."""
        return len(self.features) - 1

    def leaves(self) -> list[int]:
        """Indices of the primitive features (= their appearance classes)."""
        return [i for i, f in enumerate(self.features) if f.is_primitive]

    def structure(self) -> tuple:
        """The tree as nested tuples of appearance classes, e.g. ((0, 2), 1)."""

        def nest(i: int):
            f = self.features[i]
            return f.appearance if f.is_primitive else tuple(nest(c) for c in f.children)

        return nest(self.root)

    def depth(self) -> int:
        """Number of edges on the longest root-to-leaf path."""

        def d(i: int) -> int:
            kids = self.features[i].children
            return 0 if not kids else 1 + max(d(c) for c in kids)

        return d(self.root)

    def bottom_up_order(self) -> list[int]:
        """Meta-feature indices, children before parents."""
        return [i for i, f in enumerate(self.features) if not f.is_primitive]

    def instances(self, k: int) -> Tensor:
        """(N_k, 7) object-frame frames of the patches of appearance class ``k``."""
        if k not in self._instances:
            self._instances[k] = self.patches.select(self.labels == k).frames()
        return self._instances[k]

    def pair_table(self) -> PairTable:
        """Every pair of at most ``PAIR_TABLE_PATCHES`` of the model's patches (evenly spaced
        in their order) filed by pair feature (``PairTable``), built on first use and kept."""
        if self._pair_table is None:
            frames = evenly_spaced(self.patches.frames(), PAIR_TABLE_PATCHES)
            self._pair_table = PairTable(frames)
        return self._pair_table

    def instance_colors(self, k: int) -> Tensor:
        """(N_k, 6) appearance descriptors of the patches of appearance class ``k``."""
        return appearance_descriptors(self.patches.colors[self.labels == k])

    # --- appearance --------------------------------------------------------------------------
    def classify(self, colors: Tensor, radius_scale: float = 1.0) -> Tensor:
        """Appearance class of observed patches: (N, 2, 3) colours -> (N,) class or -1 (farther
        than ``radius_scale`` times its radius from the nearest class's centre)."""
        desc = appearance_descriptors(colors).to(self.centres.device)
        if len(desc) == 0:
            return torch.zeros(0, dtype=torch.long, device=desc.device)
        dist = torch.cdist(desc, self.centres)
        best, k = dist.min(dim=1)
        return torch.where(best <= radius_scale * self.radii[k], k, torch.full_like(k, -1))

    # --- persistence -------------------------------------------------------------------------
    def state_dict(self) -> dict:
        """Its settings and learned values as plain values and tensors (for ``save``)."""
        grasp = None if self.grasp_density is None else self.grasp_density.state_dict()
        feats = [
            {
                "children": list(f.children),
                "parent": f.parent,
                "appearance": f.appearance,
                "frame": f.frame,
                "potential": None if f.potential is None else f.potential.state_dict(),
            }
            for f in self.features
        ]
        return {
            "name": self.name,
            "centres": self.centres.cpu(),
            "radii": self.radii.cpu(),
            "features": feats,
            "patches": {k: v for k, v in self.patches.to("cpu").__dict__.items()},
            "labels": self.labels.cpu(),
            "grasp_density": grasp,
            "params": self.params,
            "surface": None if self.surface is None else self.surface.cpu(),
        }

    def save(self, path: str | Path) -> None:
        """Save the model (``vistask.saving``: atomic, checked on load)."""
        save_state(path, "ObjectModel", self.state_dict())

    @classmethod
    def load(cls, path: str | Path) -> ObjectModel:
        """Load a model written by ``save``."""
        state = load_state(path, "ObjectModel")
        if state["params"].get("appearance") != APPEARANCE:
            raise ValueError(
                f"{path} holds a model learned with other appearance descriptors than this "
                "vistask's: learn it again (ObjectModel.learn)"
            )
        features = [
            Feature(
                tuple(f["children"]),
                f["parent"],
                f["appearance"],
                f["frame"],
                None if f["potential"] is None else SE3KDE.from_state_dict(f["potential"]),
            )
            for f in state["features"]
        ]
        grasp = state["grasp_density"]
        return cls(
            state["name"],
            state["centres"],
            state["radii"],
            features,
            Patches(**state["patches"]),
            state["labels"],
            None if grasp is None else SE3KDE.from_state_dict(grasp),
            state["params"],
            state.get("surface"),  # models saved without one check no colours
        )


def _build_tree(
    frames: Tensor,
    labels: Tensor,
    n_classes: int,
    sigma_t: float,
    sigma_r: float,
    meta_sigma_t: float,
    meta_sigma_r: float,
) -> list[Feature]:
    """Agglomerate appearance classes into a binary Markov tree.

    Args:
        frames: (N, 7) object-frame patch frames.
        labels: (N,) appearance class per patch.
        n_classes: K classes; features 0..K-1 are the primitives.
        sigma_t, sigma_r: bandwidth of the primitive potentials.
        meta_sigma_t, meta_sigma_r: bandwidth of the meta-feature potentials.

    Returns:
        the features, root last, with their potentials.
    """
    features = [Feature(appearance=k) for k in range(n_classes)]
    members: dict[int, Tensor] = {k: frames[labels == k, :3] for k in range(n_classes)}
    active = list(range(n_classes))
    while len(active) > 1:
        # The merge whose instances are most compact gives the most concentrated potentials.
        best: tuple[float, int, int] | None = None
        for a_pos, a in enumerate(active):
            for b in active[a_pos + 1 :]:
                pts = torch.cat([members[a], members[b]])
                spread = float(((pts - pts.mean(dim=0)) ** 2).sum(dim=1).mean())
                if best is None or spread < best[0]:
                    best = (spread, a, b)
        assert best is not None
        _, a, b = best
        new = len(features)
        members[new] = torch.cat([members[a], members[b]])
        features.append(Feature(children=(a, b)))
        features[a].parent = features[b].parent = new
        active = [i for i in active if i not in (a, b)] + [new]
    if n_classes == 1:  # a lone class still gets a meta-feature root, so the object has a frame
        members[1] = members[0]
        features.append(Feature(children=(0,)))
        features[0].parent = 1
    for i, f in enumerate(features):
        if not f.is_primitive:
            f.frame = identity_poses(1)[0]
            f.frame[:3] = members[i].mean(dim=0)
    for f in features:
        if f.parent is None:
            continue
        parent_frame = features[f.parent].frame
        if f.is_primitive:
            poses = relative(parent_frame, frames[labels == f.appearance])
            f.potential = SE3KDE(poses, sigma_t=sigma_t, sigma_r=sigma_r)
        else:
            poses = relative(parent_frame, f.frame)[None]
            f.potential = SE3KDE(poses, sigma_t=meta_sigma_t, sigma_r=meta_sigma_r)
    return features


def _kmeans(desc: Tensor, k: int, seed: int) -> tuple[Tensor, Tensor]:
    """(N, D) descriptors -> (k, D) centres and (N,) labels, by scipy's k-means++.

    Colour classes are a few separated clusters: k-means from random seeds (as the visual
    vocabulary fits) lost 7 of 180 pose estimates (``scripts/bench_pose.py``, model seeds 0-2).
    """
    data = desc.double().numpy()
    # Duplicate descriptors can make k-means++ pick fewer distinct seeds than k.
    k = min(k, len(np.unique(data.round(4), axis=0)))
    centres, labels = kmeans2(data, k, minit="++", seed=np.random.default_rng(seed))
    return torch.from_numpy(centres).float(), torch.from_numpy(labels).long()
