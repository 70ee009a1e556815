"""The small maze the agent tests learn on: one wall, two exits, 0.2 steps, 64-pixel views."""

import gymnasium as gym

import vistask.envs  # noqa: F401  (registers the vistask ids)

SMALL = dict(
    obstacles=((0.45, 0.0, 0.55, 0.6),),
    exits=((0.0, 0.0, 0.2, 0.2), (0.8, 0.0, 1.0, 0.2)),
    step=0.2,
    window=64,
    pixels_per_unit=240.0,
)


def small_maze() -> gym.Env:
    """``vistask/VisualMaze-v0`` with the ``SMALL`` layout."""
    return gym.make("vistask/VisualMaze-v0", **SMALL)
