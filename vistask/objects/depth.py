"""Pose hypotheses checked against depth images: what the scene's surfaces allow.

NBP's hypotheses explain observed patches; the depth images also say where nothing is. A
model point predicted in front of the observed surface lies in space the camera sees through
(free space), and a point below the supporting table is inside it: both rule the pose out.
Points behind the observed surface are hidden (by the object itself or by others) and count
neither way.

``DepthCheck(views).refine(poses, points)`` pulls hypotheses onto the observed surfaces
(projective ICP: each model point facing a camera is matched to the nearest back-projected
pixel in a small window around its projection, then a rigid fit); ``weights`` scores them by
the share of their model points that the depth explains, less what it rules out;
``colour_agreement`` by how well the colours of the model's surface match the pixels under
the points the depth explains.
"""

from __future__ import annotations

from collections.abc import Sequence

import roma
import torch
import torch.nn.functional as F
from torch import Tensor

from vistask.checks import check_at_least, check_positive, checked
from vistask.se3 import apply, rigid_refit
from vistask.vision import RGBDView
from vistask.vision.camera import pixel_grid

REFINE_SCALES_M = (0.02, 0.01, 0.006, 0.004)
"""Match distances of the refinement, coarse to fine (metres)."""
MIN_MATCHES = 6
"""A pose stays where fewer model points than this find an observed surface."""
REFINE_POINTS = 400
"""The refinement fits at most this many model points (evenly spaced in the model's order)."""
MIN_IN_SIGHT = 0.3
"""A pose's explained share counts its model points in sight, and at least this share of
those in view: the target hidden behind other objects is not scored down for what it hides,
and a pose buried behind the surfaces, with a few points explained, is not scored up. On the
pose benchmark's 60 clutter scenes (one camera, at most half of the target visible), NBP
counting hidden points as unexplained was right in 36, with this rule in 41; with the votes
of patch pairs as well, in 42 and 47 (46 without a minimum share, 45 with 0.5)."""
CHROMA_OFFSET = 0.05
"""Chromaticity is rgb / (r + g + b + this). A face's shading by the light's angle scales its
colour, which moves its chromaticity much less than the colour itself (on the pose
benchmark's clutter scenes, plain colours scored the milk carton's true pose below wrong
ones); the offset keeps dark pixels, whose hue is mostly noise, from counting as saturated
colours. With 0.1 the dark blue box lying on a side, its faces shaded unlike in its learning
views, was found in 32 of 40 scenes instead of 40 without colours; with 0.05 in 36."""
SCREEN_POINTS = 200
"""Model points that screen many poses at once (``NBP``'s draws from the object belief)."""


def chromaticity(rgb: Tensor) -> Tensor:
    """(..., 3) RGB in [0, 1] -> (..., 3) rgb / (r + g + b + ``CHROMA_OFFSET``).

    >>> chromaticity(torch.tensor([[0.6, 0.3, 0.0], [0.3, 0.15, 0.0]]))  # one colour, shaded
    tensor([[0.6316, 0.3158, 0.0000],
            [0.6000, 0.3000, 0.0000]])
    """
    return rgb / (rgb.sum(dim=-1, keepdim=True) + CHROMA_OFFSET)


def _pixels(camera, points: Tensor, H: int, W: int) -> tuple[Tensor, ...]:
    """(..., 3) world points -> the column and row (...) of the pixel each projects to (not
    clamped), its depth (...), and whether it lies in front of the camera inside the
    (H, W) image (...)."""
    uv, z = camera.project(points)
    u, v = uv[..., 0].round().long(), uv[..., 1].round().long()
    return u, v, z, (u >= 0) & (u < W) & (v >= 0) & (v < H) & (z > 0)


def _facing(camera, world: Tensor, normals: Tensor) -> Tensor:
    """(..., 3) world points and their (..., 3) outward world normals -> (...) whether each
    faces the camera (the camera lies in front of the point's tangent plane)."""
    return ((camera.position.to(world) - world) * normals).sum(-1) > 0


def evenly_spaced(points: Tensor, k: int) -> Tensor:
    """At most ``k`` of (N, ...) ``points`` (or patch frames), evenly spaced in their order."""
    if len(points) <= k:
        return points
    return points[torch.linspace(0, len(points) - 1, k).long()]


@checked
class DepthCheck:
    """Depth images against which object poses are refined and checked.

    Example:
        >>> check = DepthCheck(scene.views.values(), floor_z=TABLE_TOP_Z)
        >>> patches = model.patches
        >>> poses = check.refine(poses, patches.positions, normals=patches.normals)  # (H, 7)
        >>> check.weights(poses, patches.positions)  # (H,) in [0, 1]

    Args:
        views: V RGB-D views of the scene (pixels without valid depth are ignored).
        floor_z: world height of the supporting plane; model points more than
            ``tolerance`` below it rule a pose out. None: no floor.
        tolerance: metres; a model point within this of an observed surface is explained,
            one this far in front of every surface around its pixel is in free space.
        window: a model point is matched within (2 window + 1)^2 pixels around its
            projection, so that points on an object's outline, a pixel off, still find it.

    Raises:
        ValueError: no view, tolerance not positive, or window negative.
    """

    def __init__(
        self,
        views: Sequence[RGBDView],
        floor_z: float | None = None,
        tolerance: float = 0.01,
        window: int = 2,
    ) -> None:
        views = list(views)
        if not views:
            raise ValueError("DepthCheck needs at least one view")
        check_positive(tolerance=tolerance)
        check_at_least(0, window=window)
        self.floor_z = floor_z
        self.tolerance = tolerance
        self.window = window
        self._maps = [self._surface_maps(view, window) for view in views]
        self._chroma = [chromaticity(view.rgb.float() / 255.0) for view in views]

    @staticmethod
    def _surface_maps(view: RGBDView, window: int) -> tuple:
        """The view's camera; its back-projected world points as (3, P) coordinate planes
        over the image padded by ``window`` pixels on every side, row by row (NaN where depth
        is invalid or outside the image); the (K,) offsets of a pixel's window in that flat
        order; and the depth's minimum over the window (H, W) (inf where none is valid)."""
        depth = view.depth.float()
        H, W = depth.shape
        valid = torch.isfinite(depth) & (depth > 0)
        points = torch.full((H + 2 * window, W + 2 * window, 3), float("nan"))
        pixels = pixel_grid(H, W)[valid]
        inner = points[window : window + H, window : window + W]
        inner[valid] = view.camera.backproject(pixels, depth[valid]).float()
        side = torch.arange(-window, window + 1, dtype=torch.int32)
        offsets = (side[:, None] * (W + 2 * window) + side[None, :]).flatten()
        far = torch.where(valid, depth, torch.full_like(depth, float("inf")))
        nearest = -F.max_pool2d(-far[None, None], 2 * window + 1, 1, window)[0, 0]
        return view.camera, points.flatten(0, 1).T.contiguous(), offsets, nearest

    def _flat(self, u: Tensor, v: Tensor, W: int) -> Tensor:
        """(...) pixel columns and rows inside a W pixels wide image -> (...) their indices
        into the view's padded surface planes."""
        return ((v + self.window) * (W + 2 * self.window) + (u + self.window)).int()

    def match(self, points: Tensor) -> list[tuple[Tensor, ...]]:
        """Per view, for (..., 3) world points: the nearest observed point in each one's
        window (..., 3), its distance (...) (inf when none or outside the image), whether
        the point projects into the image (...), whether it lies in free space (...), and
        whether it is hidden: farther than ``tolerance`` behind the nearest surface around
        its pixel and not explained (...)."""
        out = []
        for camera, surface, offsets, nearest in self._maps:
            H, W = nearest.shape
            u, v, z, inside = _pixels(camera, points, H, W)
            u, v = u.clamp(0, W - 1), v.clamp(0, H - 1)
            around = self._flat(u, v, W)[..., None] + offsets  # (..., K)
            # Coordinate by coordinate: a gather of scalars is faster than of 3-vectors.
            dist = 0
            for plane, coordinate in zip(surface, points.unbind(-1), strict=True):
                seen = plane.index_select(0, around.flatten()).view(around.shape)
                dist = dist + (seen - coordinate[..., None]).square_()
            dist, k = dist.nan_to_num_(torch.inf).min(dim=-1)
            closest = surface[:, around.gather(-1, k[..., None])[..., 0]]
            front = nearest[v, u]
            free = inside & torch.isfinite(front) & (z < front - self.tolerance)
            dist = torch.where(inside, dist.sqrt_(), torch.inf)
            hidden = inside & (dist >= self.tolerance) & (z > front + self.tolerance)
            out.append((closest.movedim(0, -1), dist, inside, free, hidden))
        return out

    def refine(
        self, poses: Tensor, points: Tensor, iters: int = 3, normals: Tensor | None = None
    ) -> Tensor:
        """Pull poses onto the observed surfaces: at each scale of ``REFINE_SCALES_M``,
        ``iters`` times, the model points within that distance of their nearest observed
        point (in any view) are fitted rigidly onto them (weighted Kabsch).

        Args:
            poses: (H, 7) object poses (world).
            points: (N, 3) model points in the object frame (at most ``REFINE_POINTS`` of
                them are used).
            iters: fits at each scale.
            normals: (N, 3) the points' outward unit normals in the object frame; when
                given, a point is matched in a view only where it faces that camera (a
                point on the far side of a round object would otherwise be matched to the
                near side's pixels). None: every point is matched.

        Returns:
            (H, 7) the refined poses; a pose stays where fewer than ``MIN_MATCHES`` points
            match.
        """
        poses, points = poses.float(), evenly_spaced(points.float(), REFINE_POINTS)
        if normals is not None:
            normals = evenly_spaced(normals.float(), REFINE_POINTS)
        source = points.expand(len(poses), len(self._maps), *points.shape).flatten(1, 2)
        for scale in REFINE_SCALES_M:
            for _ in range(iters):
                world = apply(poses[:, None], points)
                matches = self.match(world)
                target = torch.cat([closest for closest, *_ in matches], dim=1)  # (H, VN, 3)
                near = [dist < scale for _, dist, *_ in matches]
                if normals is not None:
                    turned = normals @ roma.unitquat_to_rotmat(poses[:, 3:]).mT  # (H, N, 3)
                    near = [
                        n & _facing(camera, world, turned)
                        for n, (camera, *_) in zip(near, self._maps, strict=True)
                    ]
                near = torch.cat(near, dim=1)
                poses, moved = rigid_refit(poses, source, target, near.float(), MIN_MATCHES)
                if not moved:
                    return poses
        return poses

    def weights(self, poses: Tensor, points: Tensor) -> Tensor:
        """(H, 7) poses, (N, 3) object-frame model points -> (H,) weights in [0, 1]: the
        share of the model points in sight (one count per view) within ``tolerance`` of an
        observed surface, times max(0, 1 - 2 v), v the share in free space plus the share
        below the floor. In sight: projecting into the view and not hidden behind an observed
        surface, at least ``MIN_IN_SIGHT`` of those projecting into it."""
        return self.explain(poses, points)[0]

    def colour_agreement(self, poses: Tensor, surface: Tensor, sigma: float) -> Tensor:
        """How well a model's surface colours match the scene under each pose.

        Args:
            poses: (H, 7) object poses (world).
            surface: (S, 6) object-frame surface points and their RGB colours in [0, 1]
                (``ObjectModel.surface``).
            sigma: scale of the chromaticity difference.

        Returns:
            (H,) over the surface points within ``tolerance`` of the observed point of the
            pixel they project to (one count per view), the mean of exp(-d^2 / 2 sigma^2), d
            the distance between the chromaticities (``chromaticity``) of the point's colour
            and of that pixel; 0 where no point is explained.
        """
        world = apply(poses.float()[:, None], surface[:, :3].float())
        model = chromaticity(surface[:, 3:].float())
        total = count = 0
        for (camera, observed, _, _), chroma in zip(self._maps, self._chroma, strict=True):
            H, W = chroma.shape[:2]
            u, v, _, inside = _pixels(camera, world, H, W)
            u, v = u.clamp(0, W - 1), v.clamp(0, H - 1)
            # The pixel's own observed point, not the nearest in a window as ``match``
            # finds: its colour is the one compared, and one pixel is 25 times cheaper.
            seen = observed[:, self._flat(u, v, W)].movedim(0, -1)
            near = (seen - world).norm(dim=-1) < self.tolerance  # NaN: False
            explained = inside & near
            similar = torch.exp(-0.5 * (chroma[v, u] - model).square().sum(-1) / sigma**2)
            total = total + (similar * explained).sum(-1)
            count = count + explained.sum(-1)
        return total / count.clamp_min(1)

    def explain(self, poses: Tensor, points: Tensor) -> tuple[Tensor, Tensor]:
        """(H, 7) poses, (N, 3) object-frame model points -> (H,) ``weights`` and (H,) the
        number of model points (one count per view) within ``tolerance`` of an observed
        surface."""
        world = apply(poses.float()[:, None], points.float())
        matches = self.match(world)
        in_view = sum(inside.sum(dim=-1) for _, _, inside, _, _ in matches)
        hidden = sum(hidden.sum(dim=-1) for *_, hidden in matches)
        explained = sum((dist < self.tolerance).sum(dim=-1) for _, dist, *_ in matches)
        in_sight = torch.maximum(in_view - hidden, (MIN_IN_SIGHT * in_view).ceil()).clamp_min(1)
        violated = sum(free.sum(dim=-1) for *_, free, _ in matches) / in_view.clamp_min(1)
        if self.floor_z is not None:
            violated = violated + (world[..., 2] < self.floor_z - self.tolerance).float().mean(-1)
        return explained / in_sight * (1.0 - 2.0 * violated).clamp_min(0.0), explained
