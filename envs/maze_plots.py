"""Pictures of value functions and policies over the true maze positions (paper Figs. 3-4):
action ids (``plot_policy``) or move angles of the continuous-action maze (``plot_directions``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from vistask.envs.visual_maze import (
    ACTION_DIRECTIONS,
    VisualMazeEnv,
    angle_directions,
    draw_maze,
)


def grid_positions(env: VisualMazeEnv, grid: int) -> np.ndarray:
    """(grid*grid, 2) cell centres, row-major with rows along y (matches ``MazeOracle`` grids)."""
    centres = (np.arange(grid) + 0.5) / grid * env.geometry.size
    xx, yy = np.meshgrid(centres, centres)
    return np.stack([xx.ravel(), yy.ravel()], -1)


def percept_grid(
    env: VisualMazeEnv, fn: Callable[[list[np.ndarray]], np.ndarray], grid: int = 50
) -> np.ndarray:
    """Evaluate ``fn`` (a batch of percepts -> (n,) values, or (n, k)) at every grid cell:
    (grid, grid), or (grid, grid, k). Cells that are not free (obstacles, exits) are NaN."""
    points = grid_positions(env, grid)
    free = env.geometry.is_free(points)
    found = np.asarray(fn([env.percept_at(p) for p in points[free]]), dtype=np.float64)
    values = np.full((len(points), *found.shape[1:]), np.nan)
    values[free] = found
    return values.reshape(grid, grid, *found.shape[1:])


def _mask_blocked(env: VisualMazeEnv, values: np.ndarray) -> np.ndarray:
    free = env.geometry.is_free(grid_positions(env, values.shape[0])).reshape(values.shape)
    return np.where(free, values, np.nan)


def plot_values(
    env: VisualMazeEnv, panels: dict[str, np.ndarray], path: str | Path, title: str = ""
) -> Path:
    """Side-by-side value maps (brighter = greater, as in the paper's Fig. 4)."""
    finite = [v[np.isfinite(v)] for v in panels.values()]
    vmax = max((f.max() for f in finite if f.size), default=1.0)
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 4), squeeze=False)
    size = env.geometry.size
    for ax, (name, values) in zip(axes[0], panels.items(), strict=True):
        image = ax.imshow(
            _mask_blocked(env, values),
            cmap="gray",
            vmin=0,
            vmax=vmax,
            extent=(0, size, size, 0),
            interpolation="nearest",
        )
        for x0, y0, x1, y1 in env.geometry.obstacle_array:
            ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, color="tab:red", alpha=0.6))
        ax.set_title(name)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(image, ax=axes[0].tolist(), shrink=0.8, label="V")
    if title:
        fig.suptitle(title)
    path = Path(path)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_policy(env: VisualMazeEnv, actions: np.ndarray, path: str | Path, title: str = "") -> Path:
    """Greedy actions (grid, grid) as arrows over the maze picture (paper Fig. 3 right)."""
    directions = ACTION_DIRECTIONS[np.nan_to_num(actions.ravel()).astype(int)]
    return _plot_arrows(env, directions, actions.shape[0], path, title)


def plot_directions(
    env: VisualMazeEnv, angles: np.ndarray, path: str | Path, title: str = ""
) -> Path:
    """Move angles in radians (grid, grid) as arrows over the maze picture, for a policy of
    ``VisualMazeContinuousEnv`` (e.g. ``MazeOracle.policy_angles``); NaN cells get no arrow.

    Example:
        >>> oracle = MazeOracle.solve(env.geometry, n_directions=32)
        >>> plot_directions(env, oracle.policy_angles[::2, ::2], "policy.png")
    """
    angles = np.asarray(angles, dtype=np.float64)
    directions = angle_directions(angles)
    directions[~np.isfinite(angles.ravel())] = np.nan
    return _plot_arrows(env, directions, angles.shape[0], path, title)


def _plot_arrows(
    env: VisualMazeEnv, directions: np.ndarray, grid: int, path: str | Path, title: str
) -> Path:
    """Unit vectors (grid*grid, 2), row-major over ``grid_positions``, as arrows at the free
    cells (NaN vectors skipped)."""
    points = grid_positions(env, grid)
    free = env.geometry.is_free(points) & np.isfinite(directions).all(axis=1)
    pixels = points * env.pixels_per_unit
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.imshow(draw_maze(env))
    length = 0.75 * env.geometry.size / grid * env.pixels_per_unit
    ax.quiver(
        pixels[free, 0],
        pixels[free, 1],
        directions[free, 0] * length,
        directions[free, 1] * length,
        color="yellow",
        angles="xy",
        scale_units="xy",
        scale=1,
        width=0.004,
        headwidth=3,
        headlength=3,
        headaxislength=2.5,
        pivot="middle",
    )
    ax.set_axis_off()
    if title:
        ax.set_title(title)
    path = Path(path)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path
