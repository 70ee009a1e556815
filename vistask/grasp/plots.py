"""Pictures of grasp densities over an object (after the paper's Figs. 16-17)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import roma
import torch

from vistask.se3 import SE3KDE


def draw_density(
    ax,
    density: SE3KDE,
    points: torch.Tensor | None = None,
    colors: torch.Tensor | None = None,
    n: int = 60,
    stem: float = 0.03,
    finger: float = 0.02,
    color: str = "tab:green",
) -> None:
    """Draw ``n`` resampled particles as grippers: an approach stem and a finger bar.

    Args:
        ax: a matplotlib 3-D axis.
        density: object-frame grasp density.
        points: (M, 3) object points to show (e.g. patch positions), or None.
        colors: (M, 3) RGB in [0, 1] for the points.
        n: particles drawn (systematic resampling by weight, so heavy particles repeat).
        stem: length of the approach stem behind the gripper origin (metres).
        finger: half-length of the bar along the closing axis (metres).
        color: line colour.
    """
    if points is not None:
        c = "0.5" if colors is None else colors.clamp(0, 1).numpy()
        ax.scatter(*points.T.numpy(), s=2, c=c, depthshade=False)
    idx = torch.unique(torch.multinomial(density.weights, n, replacement=True))
    g = density.points[idx].cpu()
    R = roma.unitquat_to_rotmat(g[:, 3:])
    t, x, z = g[:, :3], R[:, :, 0], R[:, :, 2]  # origin, closing axis, approach
    for ti, zi, xi in zip(t, z, x, strict=True):
        back = ti - stem * zi
        ax.plot(*torch.stack([back, ti]).T.numpy(), color=color, lw=1.2)
        ends = torch.stack([ti - finger * xi, ti + finger * xi])
        ax.plot(*ends.T.numpy(), color=color, lw=0.8, alpha=0.7)


def density_figure(
    densities: Sequence[tuple[str, SE3KDE | None]],
    points: torch.Tensor | None,
    colors: torch.Tensor | None,
    path: str | Path,
    title: str = "",
    n: int = 60,
) -> None:
    """Save side-by-side 3-D pictures of several densities over the same object points."""
    fig = plt.figure(figsize=(5 * len(densities), 5))
    for k, (name, density) in enumerate(densities):
        ax = fig.add_subplot(1, len(densities), k + 1, projection="3d")
        if density is not None:
            draw_density(ax, density, points, colors, n=n)
        elif points is not None:
            ax.scatter(*points.T.numpy(), s=2, c="0.5")
        ax.set_title(f"{title} {name}".strip())
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_zlabel("z")
        lim = 0.1
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_zlim(-lim, lim)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
