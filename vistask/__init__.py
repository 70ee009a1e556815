"""vistask: task-specific visual representations learned inside perception-action loops.

Importing ``vistask.envs`` registers the Gymnasium environments (``vistask/VisualMaze-v0``,
``vistask/GraspTrial-v0``). ``import vistask`` alone loads nothing else, so that the numeric
cores (``vistask.se3`` and the other algorithm packages) import without Gymnasium or OpenCV.
"""

__version__ = "0.1.0"
