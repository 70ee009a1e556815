"""Pictures of the visual car on the hill: the road and a percept (paper Fig. 6), and greedy
policies over the true state plane (p, s) (paper Fig. 7)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import ListedColormap

from vistask.envs.mountain_car import (
    CAR_ACTION_NAMES,
    MAX_POSITION,
    MAX_SPEED,
    VisualMountainCarEnv,
    draw_road,
)

ACTION_COLOURS = ("tab:blue", "tab:orange")  # push left, push right


def state_grid(grid: int) -> np.ndarray:
    """(grid*grid, 2) cell centres (p, s) of a grid x grid partition of [-1, 1] x [-3, 3],
    row-major with rows along s (increasing) and columns along p: reshape any per-state
    result to (grid, grid) to get the [s index, p index] arrays ``plot_car_policy`` draws.

    Example:
        >>> states = state_grid(50)
        >>> actions = oracle.act(states).reshape(50, 50)
    """
    if grid < 1:
        raise ValueError(f"grid must be >= 1, got {grid}")
    p = ((np.arange(grid) + 0.5) / grid * 2 - 1) * MAX_POSITION
    s = ((np.arange(grid) + 0.5) / grid * 2 - 1) * MAX_SPEED
    pp, ss = np.meshgrid(p, s)
    return np.stack([pp.ravel(), ss.ravel()], axis=1)


def percepts_at(env: VisualMountainCarEnv, states: np.ndarray) -> np.ndarray:
    """(N, H, W, 3) uint8 percepts of states (N, 2), e.g. ``state_grid``'s, for a classifier
    (``env`` may be wrapped)."""
    car = env.unwrapped
    if not isinstance(car, VisualMountainCarEnv):
        raise TypeError(f"percepts_at needs a VisualMountainCarEnv, got {type(car).__name__}")
    return car.percepts(np.asarray(states, dtype=np.float64).reshape(-1, 2))


def plot_road(env: VisualMountainCarEnv, state: np.ndarray, path: str | Path) -> Path:
    """The whole road strip with the window of the percept at ``state`` (p, s) framed in white,
    and the percept's gauge beside it (paper Fig. 6 top)."""
    car = env.unwrapped
    state = np.asarray(state, dtype=np.float64).reshape(2)
    picture = draw_road(car, state)
    height, width = picture.shape[:2]
    fig, ax = plt.subplots(figsize=(width / 80, height / 80 + 0.5))
    ax.imshow(picture, interpolation="nearest")
    ax.set_title(f"road and percept at p = {state[0]:+.2f}, s = {state[1]:+.2f}")
    ax.set_axis_off()
    path = Path(path)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_car_policy(
    actions_by_name: dict[str, np.ndarray], path: str | Path, title: str = ""
) -> Path:
    """Greedy actions over the (p, s) plane, one panel per entry, side by side (paper Fig. 7:
    RLVC's actions next to the oracle's).

    Args:
        actions_by_name: panel title -> (G, G) action ids indexed [s index, p index] over
            ``state_grid(G)`` (G may differ between panels); NaN cells are left blank.
        path: where to save the figure (PNG).
        title: title over the panels ("": none).
    """
    if not actions_by_name:
        raise ValueError("plot_car_policy needs at least one (name, actions) panel")
    cmap = ListedColormap(ACTION_COLOURS)
    fig, axes = plt.subplots(
        1, len(actions_by_name), figsize=(4 * len(actions_by_name), 3.6), squeeze=False
    )
    for ax, (name, actions) in zip(axes[0], actions_by_name.items(), strict=True):
        actions = np.asarray(actions, dtype=np.float64)
        if actions.ndim != 2 or actions.shape[0] != actions.shape[1]:
            raise ValueError(f"{name}: actions must be a (G, G) array, got {actions.shape}")
        ax.imshow(
            actions,
            cmap=cmap,
            vmin=-0.5,
            vmax=len(ACTION_COLOURS) - 0.5,
            origin="lower",
            extent=(-MAX_POSITION, MAX_POSITION, -MAX_SPEED, MAX_SPEED),
            aspect="auto",
            interpolation="nearest",
        )
        ax.set_title(name)
        ax.set_xlabel("position p")
        ax.set_ylabel("speed s")
    handles = [plt.Rectangle((0, 0), 1, 1, color=colour) for colour in ACTION_COLOURS]
    fig.legend(handles, CAR_ACTION_NAMES, loc="lower center", ncol=2, frameon=False)
    if title:
        fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    path = Path(path)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path
