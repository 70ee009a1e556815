"""One progress bar over a whole ``learn`` call of a visual agent."""

from __future__ import annotations

from typing import Any

from tqdm.auto import tqdm


class LearnProgress:
    """A tqdm bar that counts the interactions of a ``learn`` call up to ``total_timesteps``.

    The bar moves while interactions are collected; its description names the phase
    (``collecting``, ``SIFT``, ``vocabulary``, ``stages``, ...) and its postfix the database,
    the percepts whose keypoints are extracted so far, the stage, the classes and the mean
    return of the episodes ended in the latest database.

    Args:
        total: interactions of the call (``total_timesteps``).
        databases: databases the call collects.
        enabled: False makes every method a no-op.

    Example:
        >>> with LearnProgress(40_000, 4, enabled=True) as progress:
        ...     progress.phase("collecting", database=1)
        ...     progress.update(128)
        ...     progress.show(classes=12)
    """

    def __init__(self, total: int, databases: int, enabled: bool = True) -> None:
        self.databases = databases
        self.bar = tqdm(total=total, unit="step", disable=not enabled, dynamic_ncols=True)
        self.postfix: dict[str, Any] = {}

    def phase(self, name: str, database: int | None = None) -> None:
        """Name the phase; with ``database`` (1-based), show which database it works on."""
        self.bar.set_description(name)
        if database is not None:
            self.postfix.pop("sift", None)
            self.show(db=f"{database}/{self.databases}")

    def update(self, n: int) -> None:
        """Count ``n`` more interactions collected."""
        self.bar.update(n)

    def show(self, **values: Any) -> None:
        """Set entries of the postfix (floats with three significant digits)."""
        for key, value in values.items():
            self.postfix[key] = f"{value:.3g}" if isinstance(value, float) else value
        self.bar.set_postfix(self.postfix, refresh=True)

    def close(self) -> None:
        """Close the bar."""
        self.bar.close()

    def __enter__(self) -> LearnProgress:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
