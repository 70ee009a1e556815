"""Independent runs spread over cores or a cluster with Ray, or run one after another.

``map_runs(fn, items)`` calls ``fn(item)`` for every item and hands each outcome to a callback
as soon as it is known, in the order the runs finish. With ``workers=1`` (and no cluster
address) it runs in this process, which is what a debugger wants; otherwise every call is a
Ray task on one CPU. A run that raises does not stop the others: its outcome carries the
error text instead of a result.

Ray: a local Ray is started with ``workers`` CPUs (default: all cores) and shut down at the
end; ``address`` (or the ``RAY_ADDRESS`` environment variable) connects to a running cluster
instead, whose nodes must have vistask installed. Inside a task Ray sets one thread per
CPU, so runs side by side do not fight over cores.
"""

from __future__ import annotations

import os
import re
import traceback
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

_ANSI = re.compile(r"\x1b\[[0-9;]*m")


@dataclass
class Outcome:
    """One run: its ``item``, and either its ``result`` or its ``error`` (traceback text)."""

    item: Any
    result: Any = None
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


def cluster_address(address: str | None = None) -> str | None:
    """``address`` if given, else ``RAY_ADDRESS`` from the environment (None: no cluster)."""
    return address or os.environ.get("RAY_ADDRESS") or None


def in_process(workers: int | None, address: str | None = None) -> bool:
    """True when runs go one after another in this process: one worker and no cluster."""
    return workers == 1 and cluster_address(address) is None


@contextmanager
def ray_session(workers: int | None = None, address: str | None = None) -> Iterator[Any]:
    """The ``ray`` module, initialised: connected to the cluster at ``address`` (or
    ``RAY_ADDRESS``), or a local Ray with ``workers`` CPUs (default: all cores). A Ray started
    here is shut down on exit; one already running is left as it is."""
    import ray

    if ray.is_initialized():
        yield ray
        return
    address = cluster_address(address)
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if address is None:
        ray.init(
            num_cpus=workers or os.cpu_count(),
            include_dashboard=False,
            configure_logging=False,
        )
    else:
        ray.init(address=address, configure_logging=False)
    try:
        yield ray
    finally:
        ray.shutdown()


def map_runs(
    fn: Callable[[Any], Any],
    items: Iterable[Any],
    workers: int | None = None,
    address: str | None = None,
    on_outcome: Callable[[Outcome], None] | None = None,
) -> list[Outcome]:
    """``fn(item)`` for every item, in this process or as Ray tasks.

    Example:
        >>> outcomes = map_runs(train_one, [("rlvc", 0), ("dqn", 0)], workers=2)
        >>> [o.result for o in outcomes if o.ok]

    Args:
        fn: a picklable top-level function of one argument.
        items: its arguments, one run each.
        workers: CPUs of the local Ray (default: all cores); 1 runs in this process.
        address: Ray cluster to run on (default ``RAY_ADDRESS``; None: local).
        on_outcome: called with each outcome as soon as its run ends.

    Returns:
        The outcomes in the order the runs ended.
    """
    items = list(items)
    outcomes: list[Outcome] = []

    def done(outcome: Outcome) -> None:
        outcomes.append(outcome)
        if on_outcome is not None:
            on_outcome(outcome)

    if in_process(workers, address):
        for item in items:
            try:
                done(Outcome(item, result=fn(item)))
            except Exception:
                done(Outcome(item, error=traceback.format_exc()))
        return outcomes

    with ray_session(workers, address) as ray:
        remote = ray.remote(num_cpus=1, max_retries=0)(fn)
        pending = {remote.remote(item): item for item in items}
        while pending:
            (ref,), _ = ray.wait(list(pending), num_returns=1)
            item = pending.pop(ref)
            try:
                done(Outcome(item, result=ray.get(ref)))
            except Exception as error:  # RayTaskError wraps the run's own exception
                done(Outcome(item, error=_ANSI.sub("", str(error))))
    return outcomes
