"""3-D oriented appearance patches ("ECV-like") from one RGB-D image.

A patch sits on an image contour (an intensity edge found by Canny, or an occluding
contour found as a depth step), lifted to 3-D with the depth map:

- ``positions`` (N, 3): the contour point in 3-D.
- ``directions`` (N, 3): unit 3-D direction of the contour. Physically axial (v == -v); its
  sign is fixed by appearance for convenience: seen from the camera, the brighter side
  (``colors[:, 1]``) lies to the left of the direction. The sign is only meaningful when
  the two colours differ, so treat directions as axial unless that holds.
- ``colors`` (N, 2, 3): RGB in [0, 1] a few pixels either side of the contour, darker side
  (lower luminance) first.
- ``normals`` (N, 3) or None: unit surface normal of the surface the patch lies on,
  pointing towards the camera that saw it.
- ``pixels`` (N, 2) or None: (u, v) where the patch was found in its source image; dropped
  when patches from different images are concatenated.

All coordinates are in one frame (world, or an object frame after ``to_frame``). Poses are
(7,) ``[tx, ty, tz, qx, qy, qz, qw]`` (roma XYZW), mapping frame coordinates to world.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import roma
import torch
import torch.nn.functional as F
from torch import Tensor

from vistask.checks import check_at_least, check_device, check_positive, checked
from vistask.saving import load_state, save_state
from vistask.se3.poses import check_poses
from vistask.vision.camera import Camera, backproject

_LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)


def _pose_rt(pose: Tensor) -> tuple[Tensor, Tensor]:
    """(7,) pose -> rotation (3, 3), translation (3,)."""
    if pose.shape != (7,):
        raise ValueError(f"pose must have shape (7,), got {tuple(pose.shape)}")
    pose = check_poses(pose.float(), "pose")
    return roma.unitquat_to_rotmat(pose[3:]), pose[:3]


@checked
@dataclass
class Patches:
    """A set of N 3-D oriented appearance patches (see the module docstring for fields)."""

    positions: Tensor
    directions: Tensor
    colors: Tensor
    normals: Tensor | None = None
    pixels: Tensor | None = None

    def __post_init__(self) -> None:
        n = self.positions.shape[0]
        expected = {
            "positions": (self.positions, (n, 3)),
            "directions": (self.directions, (n, 3)),
            "colors": (self.colors, (n, 2, 3)),
            "normals": (self.normals, (n, 3)),
            "pixels": (self.pixels, (n, 2)),
        }
        for name, (value, shape) in expected.items():
            if value is not None and tuple(value.shape) != shape:
                raise ValueError(f"{name} must have shape {shape}, got {tuple(value.shape)}")

    def __len__(self) -> int:
        return self.positions.shape[0]

    @property
    def device(self) -> torch.device:
        """The device of the patch tensors."""
        return self.positions.device

    def _map(self, fn) -> Patches:
        return Patches(
            fn(self.positions),
            fn(self.directions),
            fn(self.colors),
            None if self.normals is None else fn(self.normals),
            None if self.pixels is None else fn(self.pixels),
        )

    def to(self, device: torch.device | str) -> Patches:
        """Copy to ``device``."""
        device = check_device(device)
        return self._map(lambda x: x.to(device))

    def select(self, index: Tensor) -> Patches:
        """Subset by a (N,) bool mask or a (K,) index tensor."""
        return self._map(lambda x: x[index])

    def in_mask(self, mask: Tensor) -> Patches:
        """Keep the patches whose source pixel lies inside ``mask`` (H, W) bool.

        Raises:
            ValueError: if the patches carry no pixels (e.g. after ``cat``).
        """
        if self.pixels is None:
            raise ValueError("these patches have no source pixels (merged from several images?)")
        if mask.dim() != 2:
            raise ValueError(f"mask must have shape (H, W), got {tuple(mask.shape)}")
        H, W = mask.shape
        u = self.pixels[:, 0].round().long().clamp(0, W - 1)
        v = self.pixels[:, 1].round().long().clamp(0, H - 1)
        return self.select(mask.to(self.device).bool()[v, u])

    def in_box(self, lo: Tensor, hi: Tensor) -> Patches:
        """Keep the patches whose position lies in the axis-aligned box [lo, hi], both (3,)."""
        lo, hi = torch.as_tensor(lo).to(self.positions), torch.as_tensor(hi).to(self.positions)
        return self.select(((self.positions >= lo) & (self.positions <= hi)).all(-1))

    def transform(self, pose: Tensor) -> Patches:
        """Apply a rigid transform: x -> R x + t.

        Args:
            pose: (7,) pose whose frame the current coordinates are expressed in.

        Returns:
            Patches in the outer frame (world coordinates when ``pose`` is a world pose).
        """
        R, t = _pose_rt(pose.to(self.device))
        return Patches(
            self.positions @ R.T + t,
            self.directions @ R.T,
            self.colors,
            None if self.normals is None else self.normals @ R.T,
            self.pixels,
        )

    def to_frame(self, pose: Tensor) -> Patches:
        """Express world-frame patches in the frame whose world pose is ``pose`` (7,)."""
        R, t = _pose_rt(pose.to(self.device))
        return Patches(
            (self.positions - t) @ R,
            self.directions @ R,
            self.colors,
            None if self.normals is None else self.normals @ R,
            self.pixels,
        )

    def frames(self) -> Tensor:
        """(N, 7) full pose of each patch: x = direction (made orthogonal to the normal),
        z = normal, y = z x x; translation = position.

        Raises:
            ValueError: if the patches have no normals.
        """
        if self.normals is None:
            raise ValueError("patch frames need normals")
        z = self.normals
        x = F.normalize(self.directions - (self.directions * z).sum(-1, keepdim=True) * z, dim=-1)
        y = torch.linalg.cross(z, x, dim=-1)
        q = roma.rotmat_to_unitquat(torch.stack([x, y, z], dim=-1))
        return torch.cat([self.positions, q], dim=-1)

    def voxel_downsample(self, voxel: float) -> Patches:
        """Keep one patch (the first) per cubic voxel of side ``voxel`` metres."""
        if voxel <= 0:
            raise ValueError(f"voxel must be positive, got {voxel}")
        if len(self) == 0:
            return self
        keys = torch.floor(self.positions / voxel).long()
        _, inverse = torch.unique(keys, dim=0, return_inverse=True)
        first = torch.full(
            (int(inverse.max()) + 1,), len(self), dtype=torch.long, device=self.device
        )
        first.scatter_reduce_(0, inverse, torch.arange(len(self), device=self.device), "amin")
        return self.select(first.sort().values)

    @staticmethod
    def cat(parts: list[Patches]) -> Patches:
        """Concatenate patch sets (same frame). Pixels are dropped unless there is one part;
        normals are kept only if every part has them."""
        if not parts:
            raise ValueError("nothing to concatenate")
        if len(parts) == 1:
            return parts[0]
        normals = (
            torch.cat([p.normals for p in parts])
            if all(p.normals is not None for p in parts)
            else None
        )
        return Patches(
            torch.cat([p.positions for p in parts]),
            torch.cat([p.directions for p in parts]),
            torch.cat([p.colors for p in parts]),
            normals,
            None,
        )

    def save(self, path: str | Path) -> None:
        """Save as a plain dict of CPU tensors (``vistask.saving``: atomic, checked on load)."""
        save_state(path, "Patches", dict(self.to("cpu").__dict__))

    @classmethod
    def load(cls, path: str | Path, device: torch.device | str = "cpu") -> Patches:
        """Load what ``save`` wrote."""
        return cls(**load_state(path, "Patches")).to(device)


def _gather(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """image[v, u] with rounding; out-of-image samples read NaN. u, v: same shape (...)."""
    H, W = image.shape[:2]
    ui, vi = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
    inside = (ui >= 0) & (ui < W) & (vi >= 0) & (vi < H)
    out = image[vi.clip(0, H - 1), ui.clip(0, W - 1)].astype(np.float32)
    out[~inside] = np.nan
    return out


def _window_offsets(radius: int) -> tuple[np.ndarray, np.ndarray]:
    r = np.arange(-radius, radius + 1)
    dv, du = np.meshgrid(r, r, indexing="ij")
    return du.ravel(), dv.ravel()


# 3x3 window offsets, nearest first: the centre, its 4-neighbours, then the diagonals.
_NEAREST_FIRST = (
    np.array([0, 1, -1, 0, 0, 1, 1, -1, -1]),
    np.array([0, 0, 0, 1, -1, 1, -1, 1, -1]),
)


def _surface_pixel(
    depth: np.ndarray, u: np.ndarray, v: np.ndarray, ref: np.ndarray, tol: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pixel nearest to (u, v) within one pixel whose depth lies within ``tol`` of ``ref``.

    At occluding contours a sample may fall on the far side; stepping to the nearest pixel
    of the patch's own surface, and back-projecting *that* pixel, keeps the 3-D point exact.

    Args:
        depth: (H, W) NaN where invalid.
        u, v, ref: (...) sample coordinates and reference depth; ``tol`` broadcasts with them.

    Returns:
        u', v', depth' (...) of the chosen pixels, and a (...) bool "found" flag.
    """
    du, dv = _NEAREST_FIRST
    uu = np.rint(u)[..., None] + du
    vv = np.rint(v)[..., None] + dv
    d = _gather(depth, uu, vv)  # (..., 9)
    ok = np.abs(d - np.asarray(ref)[..., None]) < np.asarray(tol)[..., None]  # NaN -> False
    first = ok.argmax(-1)[..., None]
    pick = lambda a: np.take_along_axis(a, first, -1)[..., 0]  # noqa: E731
    return pick(uu), pick(vv), np.nan_to_num(pick(d), nan=1.0), ok.any(-1)


def _depth_edges(depth: np.ndarray, jump: float) -> np.ndarray:
    """Foreground side of occluding contours: valid pixels with a 4-neighbour farther by more
    than ``jump`` (invalid counts as far) where the step is also ``jump`` larger than the
    step on the opposite side, so that a steep but smooth surface is no edge."""
    far = np.where(np.isnan(depth), 1e6, depth)
    # Odd reflection continues the surface linearly past the image border.
    padded = np.pad(far, 1, mode="reflect", reflect_type="odd")
    H, W = depth.shape
    centre = padded[1 : H + 1, 1 : W + 1]
    edge = np.zeros((H, W), dtype=bool)
    for (av, au), (bv, bu) in (((0, 1), (2, 1)), ((1, 0), (1, 2))):
        a = padded[av : av + H, au : au + W] - centre  # step to one neighbour
        b = padded[bv : bv + H, bu : bu + W] - centre  # and to the opposite one
        edge |= ((a > jump) & (a + b > jump)) | ((b > jump) & (a + b > jump))
    return edge & ~np.isnan(depth)


@checked
class PatchExtractor:
    """Extracts 3-D oriented appearance patches from one RGB-D image.

    Call it on an image: ``PatchExtractor()(rgb, depth, camera)``. Pixel sizes assume images
    of a few hundred pixels. The arguments are kept as attributes of the same names.

    Args:
        spacing: at most one patch per ``spacing`` x ``spacing`` pixel cell.
        canny_low, canny_high: Canny hysteresis thresholds (on 0-255 grey levels).
        blur_sigma: Gaussian blur (pixels) before edge detection and gradients.
        depth_jump: metres; a larger step between neighbours is an occluding contour, and
            samples farther than this from the patch depth lie on another surface.
        tangent_radius: pixels; the 3-D direction is fitted to points up to this far along
            the 2-D edge tangent.
        min_tangent_points: fewer valid tangent samples than this drop the patch.
        color_offset: pixels; side colours are read this far from the edge along its normal.
        normal_radius: half window (pixels) of the surface-normal fit; 0 disables normals.
        max_depth: metres; farther pixels (background, far plane) count as invalid.

    Raises:
        ValueError: spacing or tangent_radius below 1, normal_radius below 0, or color_offset,
            depth_jump or max_depth not positive.
    """

    def __init__(
        self,
        spacing: int = 4,
        canny_low: float = 20.0,
        canny_high: float = 50.0,
        blur_sigma: float = 1.0,
        depth_jump: float = 0.01,
        tangent_radius: int = 3,
        min_tangent_points: int = 4,
        color_offset: float = 2.5,
        normal_radius: int = 3,
        max_depth: float = 5.0,
    ) -> None:
        check_at_least(1, spacing=spacing, tangent_radius=tangent_radius)  # pixels
        check_at_least(2, min_tangent_points=min_tangent_points)  # a line needs two
        if normal_radius < 0:
            raise ValueError(f"normal_radius must be >= 0 (0: no normals), got {normal_radius}")
        check_positive(color_offset=color_offset, depth_jump=depth_jump, max_depth=max_depth)
        check_at_least(0, canny_low=canny_low, canny_high=canny_high, blur_sigma=blur_sigma)
        self.spacing = spacing
        self.canny_low = canny_low
        self.canny_high = canny_high
        self.blur_sigma = blur_sigma
        self.depth_jump = depth_jump
        self.tangent_radius = tangent_radius
        self.min_tangent_points = min_tangent_points
        self.color_offset = color_offset
        self.normal_radius = normal_radius
        self.max_depth = max_depth

    def __call__(
        self,
        rgb: Tensor,
        depth: Tensor,
        camera: Camera,
        mask: Tensor | None = None,
        device: torch.device | str | None = None,
    ) -> Patches:
        """Extract 3-D oriented appearance patches from one RGB-D image.

        Args:
            rgb: (H, W, 3) uint8 image, OpenCV orientation (row 0 at the top).
            depth: (H, W) z-depth in metres (non-finite or <= 0 where invalid).
            camera: the camera (intrinsics, camera-to-world) of the image.
            mask: (H, W) bool; only contours on these pixels are used, and depth is read
                only from them (object isolation with a segmentation mask).
            device: device of the returned tensors (default CPU).

        Returns:
            Patches in world coordinates, with ``pixels`` set.

        Raises:
            ValueError: bad shapes, an empty mask, no valid depth, or no patch found.
        """
        H, W = camera.height, camera.width
        for name, image in (("rgb", rgb), ("depth", depth)):
            if not isinstance(image, torch.Tensor):
                raise TypeError(f"{name} must be a torch.Tensor, got {type(image).__name__}")
        if tuple(rgb.shape) != (H, W, 3) or rgb.dtype != torch.uint8:
            raise ValueError(f"rgb must be uint8 ({H}, {W}, 3), got {rgb.dtype} {tuple(rgb.shape)}")
        if tuple(depth.shape) != (H, W):
            raise ValueError(f"depth must have shape ({H}, {W}), got {tuple(depth.shape)}")
        image = np.ascontiguousarray(rgb.cpu().numpy())
        z = depth.detach().cpu().numpy().astype(np.float32)
        valid = np.isfinite(z) & (z > 0) & (z < self.max_depth)
        if mask is not None:
            if tuple(mask.shape) != (H, W):
                raise ValueError(f"mask must have shape ({H}, {W}), got {tuple(mask.shape)}")
            mask_np = mask.cpu().numpy().astype(bool)
            if not mask_np.any():
                raise ValueError("empty mask: the object is not visible in this image")
            valid &= mask_np
        if not valid.any():
            raise ValueError(
                "empty point cloud: no pixel with valid depth"
                + (" in the mask" if mask is not None else "")
            )
        z = np.where(valid, z, np.nan)

        # Contours: intensity edges (Canny) plus occluding contours (depth steps), which catch
        # object outlines that have the background's colour.
        grey = cv2.GaussianBlur(
            cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32), (0, 0), self.blur_sigma
        )
        canny = (
            cv2.Canny(
                grey.clip(0, 255).astype(np.uint8), self.canny_low, self.canny_high, L2gradient=True
            )
            > 0
        )
        depth_edge = _depth_edges(z, self.depth_jump)
        candidates = (canny | depth_edge) & valid

        # 2-D edge normal: the intensity gradient, or across the depth step for depth-only edges.
        gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
        filled = np.where(valid, z, np.nanmax(z) + 10 * self.depth_jump).astype(np.float32)
        dx = cv2.Sobel(filled, cv2.CV_32F, 1, 0, ksize=3)
        dy = cv2.Sobel(filled, cv2.CV_32F, 0, 1, ksize=3)
        vs, us = np.nonzero(candidates)
        g = np.stack([gx[vs, us], gy[vs, us]], -1)
        dg = np.stack([dx[vs, us], dy[vs, us]], -1)
        use_grey = canny[vs, us] & (np.linalg.norm(g, axis=-1) > 1e-3)
        n2 = np.where(use_grey[:, None], g, dg)
        strength = np.linalg.norm(g, axis=-1) + 1e3 * depth_edge[vs, us]
        keep = np.linalg.norm(n2, axis=-1) > 1e-6
        vs, us, n2, strength = vs[keep], us[keep], n2[keep], strength[keep]

        # One patch per spacing x spacing cell: the strongest edge pixel in it.
        s = self.spacing
        cell = (vs // s) * (W // s + 1) + us // s
        order = np.lexsort((-strength, cell))
        first = np.ones(len(order), dtype=bool)
        first[1:] = cell[order][1:] != cell[order][:-1]
        sel = order[first]
        vs, us = vs[sel], us[sel]
        n2 = n2[sel] / np.linalg.norm(n2[sel], axis=-1, keepdims=True)

        # Depth of the patch: its own, unless it lies just outside an occluding contour (a
        # neighbour is the near side of a depth edge); then that of the nearest occluder pixel.
        du, dv = _window_offsets(1)
        win_u, win_v = us[:, None] + du, vs[:, None] + dv
        win_d = _gather(z, win_u, win_v)
        own = z[vs, us]
        occluder = (_gather(depth_edge, win_u, win_v) == 1) & (
            own[:, None] - win_d > self.depth_jump
        )
        ref = np.where(occluder.any(-1), np.where(occluder, win_d, np.inf).min(-1), own)
        cu, cv, d0, _ = _surface_pixel(z, us, vs, ref, self.depth_jump)
        uf, vf = us.astype(np.float32), vs.astype(np.float32)

        # Side colours; orient n2 towards the brighter side.
        smooth = cv2.blur(image.astype(np.float32) / 255.0, (3, 3))
        off = self.color_offset * n2
        plus = _gather(smooth, uf + off[:, 0], vf + off[:, 1])
        minus = _gather(smooth, uf - off[:, 0], vf - off[:, 1])
        plus = np.where(np.isnan(plus), smooth[vs, us], plus)
        minus = np.where(np.isnan(minus), smooth[vs, us], minus)
        flip = plus @ _LUMA < minus @ _LUMA
        n2 = np.where(flip[:, None], -n2, n2)
        colors = np.stack(
            [np.where(flip[:, None], plus, minus), np.where(flip[:, None], minus, plus)], 1
        )
        # Tangent with the bright side on its left as seen in the image (rows grow downwards).
        t2 = np.stack([-n2[:, 1], n2[:, 0]], -1)

        # 3-D direction: least-squares line through back-projected samples along the tangent,
        # parametrised by the signed step k, so its sign follows t2.
        k = np.arange(-self.tangent_radius, self.tangent_radius + 1, dtype=np.float32)
        tu = uf[:, None] + k * t2[:, :1]
        tv = vf[:, None] + k * t2[:, 1:]
        tol = self.depth_jump * np.maximum(1.0, np.abs(k))
        su, sv, sd, found = _surface_pixel(z, tu, tv, d0[:, None], tol)
        tw = found.astype(np.float64)
        K_, T_ = camera.K.double(), camera.cam_to_world.double()
        pts = _backproject_np(su, sv, sd, K_, T_)  # (N, K, 3)
        wsum = tw.sum(-1, keepdims=True)
        kbar = (tw * k).sum(-1, keepdims=True) / wsum.clip(1e-9)
        xbar = (tw[..., None] * pts).sum(1) / wsum.clip(1e-9)
        kc = (k - kbar) * tw
        direction = (kc[..., None] * (pts - xbar[:, None])).sum(1)
        ok = (wsum[:, 0] >= self.min_tangent_points) & (np.linalg.norm(direction, axis=-1) > 1e-9)

        positions = _backproject_np(cu, cv, d0, K_, T_)
        normals = None
        if self.normal_radius > 0:
            normals, normal_ok = _fit_normals(
                z, cu, cv, d0, n2, self.normal_radius, self.depth_jump, K_, T_, positions
            )
            ok &= normal_ok
        if not ok.any():
            raise ValueError("no patches found: no contour with valid depth")

        def out(x: np.ndarray) -> Tensor:
            return torch.from_numpy(np.ascontiguousarray(x[ok])).float().to(device or "cpu")

        return Patches(
            positions=out(positions),
            directions=F.normalize(out(direction), dim=-1),
            colors=out(colors),
            normals=None if normals is None else out(normals),
            pixels=out(np.stack([cu, cv], -1)),
        )


def _backproject_np(
    u: np.ndarray, v: np.ndarray, d: np.ndarray, K: Tensor, T: Tensor
) -> np.ndarray:
    """:func:`vistask.vision.camera.backproject` on NumPy arrays (float64)."""
    pix = torch.from_numpy(np.stack([u, v], -1).astype(np.float64))
    return backproject(pix, torch.from_numpy(np.asarray(d, dtype=np.float64)), K, T).numpy()


def _fit_normals(
    z: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    d0: np.ndarray,
    n2: np.ndarray,
    normal_radius: int,
    depth_jump: float,
    K: Tensor,
    T: Tensor,
    positions: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Surface normal of each patch, pointing towards the camera, and a (N,) "valid" flag.

    A plane is fitted to the window's pixels on the patch's surface (depth within tolerance)
    on each side of the edge separately, and the flatter fit wins: at a crease (box edge)
    a single fit would average two faces into a normal that belongs to neither.

    Args:
        z: (H, W) depth image in metres, NaN where invalid.
        u, v: (N,) patch pixels.
        d0: (N,) their depth.
        n2: (N, 2) unit 2-D edge normals.
        normal_radius: half side of the window of pixels fitted, in pixels.
        depth_jump: depth difference that separates two surfaces, in metres.
        K: (3, 3) camera intrinsics.
        T: (4, 4) camera-to-world transform.
        positions: (N, 3) patch positions (to orient the normals).
    """
    du, dv = _window_offsets(normal_radius)
    wu, wv = u[:, None] + du, v[:, None] + dv
    wd = _gather(z, wu, wv)
    ring = np.maximum(np.abs(du), np.abs(dv)).clip(1)
    on_surface = np.abs(wd - d0[:, None]) < depth_jump * ring
    side = du * n2[:, :1] + dv * n2[:, 1:]  # (N, K) signed pixel offset across the edge
    w = np.stack([on_surface & (side >= -0.5), on_surface & (side <= 0.5)], 1).astype(np.float64)
    pts = torch.from_numpy(_backproject_np(wu, wv, np.nan_to_num(wd, nan=1.0), K, T))[:, None]
    wt = torch.from_numpy(w)  # (N, 2, K)
    count = wt.sum(-1)
    mean = (wt[..., None] * pts).sum(2) / count[..., None].clamp_min(1e-9)
    c = (pts - mean[:, :, None]) * wt[..., None].sqrt()
    vals, vecs = torch.linalg.eigh(c.transpose(-1, -2) @ c)  # (N, 2, 3), (N, 2, 3, 3)
    flatness = vals[..., 0] / vals[..., 1].clamp_min(1e-18)
    flatness = torch.where(count >= 5, flatness, torch.inf)
    best = flatness.argmin(-1)
    n = vecs[torch.arange(len(best)), best, :, 0]
    to_cam = T[:3, 3] - torch.from_numpy(positions)
    n = torch.where(((n * to_cam).sum(-1) < 0)[:, None], -n, n)
    return n.numpy(), torch.isfinite(flatness.min(-1).values).numpy()
