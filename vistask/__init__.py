"""vistask: task-specific visual representations learned inside perception-action loops."""

__version__ = "0.1.0"
