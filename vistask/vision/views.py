"""Patches of one object from several views, merged in the object's frame."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import torch
from torch import Tensor

from vistask.checks import checked
from vistask.se3 import apply, inverse
from vistask.vision.camera import RGBDView
from vistask.vision.patches import Patches, PatchExtractor


@checked
def view_patches(
    view: RGBDView,
    label: int | None = None,
    extractor: PatchExtractor | None = None,
    device: str | None = None,
) -> Patches:
    """World-frame patches of a view, restricted to object ``label`` when given.

    Args:
        view: an RGB-D view (with segmentation when ``label`` is given).
        label: segmentation label of the object to isolate, or None for the whole image.
        extractor: the patch extractor (default: ``PatchExtractor()``).
        device: device of the returned tensors.

    Raises:
        ValueError: the object is not visible, or no patch was found.
    """
    mask = None if label is None else view.mask(label)
    extract = extractor or PatchExtractor()
    return extract(view.rgb, view.depth, view.camera, mask=mask, device=device)


@checked
def object_patch_set(
    views: Sequence[RGBDView],
    object_poses: Tensor,
    label: int = 0,
    extractor: PatchExtractor | None = None,
    voxel: float | None = None,
    device: str | None = None,
) -> Patches:
    """Merge one object's patches from several views into its own frame.

    Each view may show the object at a different pose (object rotated between shots) or
    from a different camera; the simulator's ground-truth pose maps every patch into the
    object frame. Views where the object is not visible are skipped.

    Args:
        views: V views with segmentation.
        object_poses: (V, 7) world pose of the object in each view.
        label: the object's segmentation label.
        extractor: the patch extractor (default: ``PatchExtractor()``).
        voxel: if given, keep one patch per voxel of this side (metres) after merging.
        device: device of the returned tensors.

    Returns:
        Patches in the object frame (no ``pixels``).

    Raises:
        ValueError: mismatched inputs, or no patch in any view.
    """
    if object_poses.dim() != 2 or object_poses.shape != (len(views), 7):
        raise ValueError(
            f"object_poses must have shape ({len(views)}, 7), got {tuple(object_poses.shape)}"
        )
    parts: list[Patches] = []
    for view, pose in zip(views, object_poses, strict=True):
        try:
            patches = view_patches(view, label, extractor, device)
        except ValueError:
            continue  # object hidden in this view
        parts.append(patches.to_frame(pose))
    if not parts:
        raise ValueError(f"object {label} yields no patch in any of the {len(views)} views")
    merged = replace(Patches.cat(parts), pixels=None)
    return merged if voxel is None else merged.voxel_downsample(voxel)


@checked
def object_surface(
    views: Sequence[RGBDView], object_poses: Tensor, label: int = 0, voxel: float = 0.004
) -> Tensor:
    """One object's surface points and their colours, merged from several views into its own
    frame: per view, the object's pixels back-projected and averaged per cubic voxel.

    Example:
        >>> surface = object_surface(views, poses)  # as for ``object_patch_set``
        >>> points, colours = surface[:, :3], surface[:, 3:]

    Args:
        views: V views with segmentation and depth.
        object_poses: (V, 7) world pose of the object in each view.
        label: the object's segmentation label.
        voxel: side (metres) of the voxels whose pixels are averaged, per view.

    Returns:
        (S, 6) object-frame points and RGB colours in [0, 1].

    Raises:
        ValueError: mismatched inputs, or the object in none of the views.
    """
    if object_poses.shape != (len(views), 7):
        raise ValueError(
            f"object_poses must have shape ({len(views)}, 7), got {tuple(object_poses.shape)}"
        )
    parts = []
    for view, pose in zip(views, object_poses, strict=True):
        try:
            points, colours = view.point_cloud(view.mask(label))
        except ValueError:
            continue  # object hidden in this view
        local = apply(inverse(pose.float()), points)
        _, voxel_of = torch.unique(torch.floor(local / voxel).long(), dim=0, return_inverse=True)
        n = int(voxel_of.max()) + 1
        sums = torch.zeros(n, 6).index_add_(0, voxel_of, torch.cat([local, colours], dim=1))
        parts.append(sums / torch.bincount(voxel_of, minlength=n)[:, None])
    if not parts:
        raise ValueError(f"object {label} is in none of the {len(views)} views")
    return torch.cat(parts)
