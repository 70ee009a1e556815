"""vistask: task-specific visual representations learned inside perception-action loops.

Importing vistask registers its Gymnasium environments (``vistask/VisualMaze-v0``,
``vistask/GraspTrial-v0``), so ``gymnasium.make`` finds them.
"""

__version__ = "0.1.0"

from vistask import envs as envs  # registers the environments
