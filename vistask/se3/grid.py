"""Uniform-grid neighbour search over particle positions, for kernels with a spatial cut-off.

Particles are sorted by the linear index (ix * ny + iy) * nz + iz of their grid cell, so for a
fixed (ix, iy) a run of z-cells is one contiguous slice of the sorted particles. A group of
queries (spatially close, sorted together) gathers every run whose cells lie within the cut-off
radius of the group's bounding box, and is evaluated densely against that gather: the pair work
stays in fused matmul blocks, and the per-group bookkeeping costs a few small tensor ops.
"""

from __future__ import annotations

import math

import torch


class CellIndex:
    """Particles sorted by grid cell, for range queries of a fixed radius.

    Args:
        positions: (N, 3) particle positions.
        radius: search radius (the kernel cut-off distance).
        subdivisions: grid cells per radius; finer cells gather fewer far pairs but more runs.
    """

    def __init__(self, positions: torch.Tensor, radius: float, subdivisions: int = 2) -> None:
        if radius <= 0:
            raise ValueError(f"radius must be positive, got {radius}")
        self.radius = float(radius)
        self.h = self.radius / subdivisions
        self.origin = positions.min(dim=0).values
        self._origin = self.origin.tolist()
        cells = torch.floor((positions - self.origin) / self.h).long()
        dims = (cells.max(dim=0).values + 1).tolist()
        if math.prod(dims) >= 2**62:
            raise ValueError("particle spread is too large for the cut-off grid; use cutoff=None")
        self.dims = dims
        keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
        self.perm = torch.argsort(keys, stable=True)
        self.keys = keys[self.perm]

    def neighbours(self, box_min: list[float], box_max: list[float]) -> torch.Tensor:
        """Sorted-order indices of the particles in cells within ``radius`` of a box.

        Args:
            box_min, box_max: corners of the query group's bounding box (3 floats each).

        Returns:
            (M,) indices into the cell-sorted particle order (apply ``perm`` for original ones).
        """
        device, r, h = self.keys.device, self.radius, self.h
        origin = self._origin
        lo = [math.floor((box_min[a] - r - origin[a]) / h) for a in range(3)]
        hi = [math.floor((box_max[a] + r - origin[a]) / h) for a in range(3)]
        if any(hi[a] < 0 or lo[a] >= self.dims[a] for a in range(3)):
            return torch.empty(0, dtype=torch.long, device=device)
        lo = [max(lo[a], 0) for a in range(3)]
        hi = [min(hi[a], self.dims[a] - 1) for a in range(3)]

        def gaps(axis: int) -> tuple[torch.Tensor, torch.Tensor]:
            j = torch.arange(lo[axis], hi[axis] + 1, device=device)
            start = origin[axis] + j * h
            gap = torch.maximum(start - box_max[axis], box_min[axis] - (start + h)).clamp(min=0)
            return j, gap

        jx, gx = gaps(0)
        jy, gy = gaps(1)
        g2 = gx[:, None] ** 2 + gy[None, :] ** 2
        reach = torch.sqrt((r * r - g2).clamp(min=0))
        z_lo = torch.floor((box_min[2] - reach - origin[2]) / h).long().clamp(lo[2], hi[2])
        z_hi = torch.floor((box_max[2] + reach - origin[2]) / h).long().clamp(lo[2], hi[2])
        base = (jx[:, None] * self.dims[1] + jy[None, :]) * self.dims[2]
        valid = (g2 <= r * r).flatten()
        start = torch.searchsorted(self.keys, (base + z_lo).flatten()[valid])
        end = torch.searchsorted(self.keys, (base + z_hi).flatten()[valid], right=True)
        lengths = end - start
        keep = lengths > 0
        start, lengths = start[keep], lengths[keep]
        total = int(lengths.sum())
        # Concatenate the runs [start, start + length) without a Python loop.
        offsets = torch.cumsum(lengths, 0) - lengths
        shift = (start - offsets).repeat_interleave(lengths, output_size=total)
        return torch.arange(total, device=device) + shift
