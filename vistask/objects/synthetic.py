"""Synthetic patch sets (no rendering): an object of coloured edge segments, and scenes with
that object at a known pose among clutter. Used by the tests and for quick experiments."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from vistask.vision import Patches

# Segments (start, end, normal, dark colour, bright colour): an asymmetric "chair" of
# four appearance classes; distinct colours per segment group.
_SEGMENTS = [
    ((-0.05, -0.03, 0.0), (0.05, -0.03, 0.0), (0, 0, 1), (0.8, 0.1, 0.1), (0.9, 0.9, 0.9)),
    ((-0.05, 0.03, 0.0), (0.02, 0.03, 0.0), (0, 0, 1), (0.8, 0.1, 0.1), (0.9, 0.9, 0.9)),
    ((-0.05, -0.03, 0.0), (-0.05, 0.03, 0.0), (0, 0, 1), (0.1, 0.1, 0.8), (0.9, 0.9, 0.2)),
    ((0.05, -0.03, 0.0), (0.05, -0.03, 0.08), (1, 0, 0), (0.1, 0.6, 0.1), (0.9, 0.9, 0.9)),
    ((-0.05, 0.03, 0.0), (-0.05, 0.03, 0.05), (0, 1, 0), (0.3, 0.3, 0.3), (0.9, 0.5, 0.1)),
    ((0.05, -0.03, 0.08), (-0.02, -0.03, 0.08), (0, 1, 0), (0.1, 0.6, 0.1), (0.9, 0.9, 0.9)),
]


def synthetic_object(spacing: float = 0.004) -> Patches:
    """Object-frame patches, one every ``spacing`` metres along each segment (with normals)."""
    parts = []
    for start, end, normal, dark, bright in _SEGMENTS:
        a, b = torch.tensor(start), torch.tensor(end)
        n = max(2, math.ceil(float((b - a).norm()) / spacing))
        s = torch.linspace(0.0, 1.0, n)[:, None]
        direction = F.normalize(b - a, dim=0).expand(n, 3)
        colors = torch.tensor([dark, bright]).expand(n, 2, 3)
        parts.append(
            Patches(a + s * (b - a), direction, colors, torch.tensor(normal).float().expand(n, 3))
        )
    return Patches.cat([p._map(lambda x: x.contiguous().float()) for p in parts])


def synthetic_scene(
    pose: Tensor,
    n_clutter: int = 200,
    keep: float = 0.7,
    noise_t: float = 0.001,
    noise_r: float = 0.05,
    seed: int = 0,
) -> Patches:
    """World-frame scene patches: the synthetic object at ``pose`` (7,), with noise and
    occlusion, plus random clutter patches.

    Args:
        pose: (7,) object pose.
        n_clutter: clutter patches (random positions in a 0.4 m cube, directions, normals and
            colours).
        keep: fraction of the object's patches kept (the rest are "occluded").
        noise_t: position noise std (metres).
        noise_r: direction/normal noise std (radians, roughly).
        seed: random seed.
    """
    g = torch.Generator().manual_seed(seed)
    obj = synthetic_object()
    kept = obj.select(torch.randperm(len(obj), generator=g)[: max(1, int(keep * len(obj)))])
    jitter = lambda x: F.normalize(x + noise_r * torch.randn(x.shape, generator=g), dim=-1)  # noqa: E731
    noisy = Patches(
        kept.positions + noise_t * torch.randn(kept.positions.shape, generator=g),
        jitter(kept.directions),
        kept.colors,
        jitter(kept.normals),
    ).transform(pose)
    if n_clutter == 0:
        return noisy
    clutter = Patches(
        pose[:3] + 0.4 * (torch.rand(n_clutter, 3, generator=g) - 0.5),
        F.normalize(torch.randn(n_clutter, 3, generator=g), dim=-1),
        torch.rand(n_clutter, 2, 3, generator=g),
        F.normalize(torch.randn(n_clutter, 3, generator=g), dim=-1),
    )
    return Patches.cat([noisy, clutter])
