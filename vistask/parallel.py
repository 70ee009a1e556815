"""Independent runs spread over this machine's cores or a Ray cluster, or run one after another.

``map_runs(fn, items)`` calls ``fn(item)`` for every item and hands each outcome to a callback
as soon as it is known, in the order the runs finish. A run that raises does not stop the
others: its outcome carries the error text instead of a result. Where the runs go:

- ``workers=1`` and no cluster: one after another in this process, which is what a debugger
  wants;
- no cluster (the default): ``workers`` side by side on this machine (default: one per core),
  this process and ``workers - 1`` processes forked from a server process that has imported
  ``fn``'s module once. This process starts at once and the others in seconds, where a local
  Ray took 5 s to start its workers and import the modules in them. Each worker process
  imports the main script, so a script keeps its work under ``if __name__ == "__main__":``
  (a worker that would run it again stops with that advice);
- ``address`` (or the ``RAY_ADDRESS`` environment variable): Ray tasks on the running cluster
  there, whose nodes must have vistask installed; ``address="local"`` starts a Ray on this
  machine with ``workers`` CPUs instead, and shuts it down at the end.

Each worker, process or Ray task, runs torch, OpenCV and SIFT on one thread, so that runs side
by side do not fight over cores and give the results of one run in one thread.
"""

from __future__ import annotations

import multiprocessing
import os
import queue
import re
import signal
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

_ANSI = re.compile(r"\x1b\[[0-9;]*m")
# "ValueError: ...", "RayTaskError(ValueError): ..." at a line's start
_EXCEPTION = re.compile(r"[A-Za-z_][\w.]*(Error|Exception|Exit|Interrupt|Failed)(\([\w.]+\))?: ")
# Imported once by the process server, not by every worker: torch imports its compiler
# (1.6 s) at the first optimizer a process makes.
PRELOAD = ("torch._dynamo",)


@dataclass
class Outcome:
    """One run: its ``item``, and either its ``result`` or its ``error`` (traceback text)."""

    item: Any
    result: Any = None
    error: str | None = None

    @property
    def ok(self) -> bool:
        """Whether the run ended without an error."""
        return self.error is None


class RunsFailed(RuntimeError):
    """Runs of a script failed: its message gives each one's last error line."""

    @classmethod
    def of(cls, lines: list[str], every: bool = False) -> RunsFailed:
        """The error for failed runs, a line each (``every``: no run finished)."""
        head = "every run failed" if every else f"{len(lines)} of the runs failed"
        return cls(f"{head}: " + "; ".join(lines))


def last_line(error: str) -> str:
    """The line of a traceback text that names the exception (``ValueError: ...``; the first
    of a message of several lines), else its last non-empty line."""
    lines = [line for line in error.strip().splitlines() if line.strip()]
    named = [line for line in lines if _EXCEPTION.match(line)]
    return named[-1] if named else lines[-1] if lines else error


def cluster_address(address: str | None = None) -> str | None:
    """``address`` if given, else ``RAY_ADDRESS`` from the environment (None: no cluster;
    ``"local"``: a Ray started on this machine)."""
    return address or os.environ.get("RAY_ADDRESS") or None


def check_not_importing_main(user: str) -> None:
    """Raise where this process is a worker process still importing the main script of the
    process that started it: a script that starts worker processes runs again, whole, in each
    of them unless its work is under ``if __name__ == "__main__":``.

    Args:
        user: what would start the processes, for the message.
    """
    # multiprocessing sets _inheriting while a new process takes in its parent's main module;
    # its own check raises only when a process starts, inside the pool's thread, after the
    # script has run as far as it goes.
    if getattr(multiprocessing.current_process(), "_inheriting", False):
        raise RuntimeError(
            f"{user} starts worker processes, and each imports the main script again: put "
            'the script\'s work under `if __name__ == "__main__":`'
        )


def one_thread() -> None:
    """Run torch, OpenCV and SIFT's batches on one thread in this process (a worker's setting;
    SIFT's batches follow ``OMP_NUM_THREADS``, which Ray sets in its tasks)."""
    use_threads(1)


def use_threads(n: int) -> None:
    """Run torch, OpenCV and SIFT's batches on ``n`` threads in this process."""
    import cv2
    import torch

    os.environ["OMP_NUM_THREADS"] = str(n)
    torch.set_num_threads(n)
    cv2.setNumThreads(n)


def _start_worker(parent: int) -> None:
    """A worker process's start: one thread (``one_thread``), and an end of its own when the
    process ``parent`` that hands it runs has died (a ``kill -9`` leaves its workers running
    otherwise, as children of the process server)."""
    import psutil

    one_thread()
    try:
        watched = psutil.Process(parent)
    except psutil.NoSuchProcess:
        os._exit(1)

    def watch() -> None:
        while watched.is_running():  # False too for a new process with the same pid
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, name="watch-parent", daemon=True).start()


@contextmanager
def worker_threads(n: int = 1) -> Iterator[None]:
    """This process on ``n`` threads (``use_threads``; 1: as a worker), inside the block."""
    import cv2
    import torch

    saved = torch.get_num_threads(), cv2.getNumThreads(), os.environ.get("OMP_NUM_THREADS")
    use_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(saved[0])
        cv2.setNumThreads(saved[1])
        if saved[2] is None:
            os.environ.pop("OMP_NUM_THREADS", None)
        else:
            os.environ["OMP_NUM_THREADS"] = saved[2]


def unreachable(address: str) -> str | None:
    """Why the Ray cluster at ``[ray://]host:port`` ``address`` cannot be reached (no answer
    within 5 s), or None when it answers or ``address`` is not host:port."""
    import socket

    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        return None
    try:
        socket.create_connection((host, int(port)), timeout=5).close()
    except OSError as error:
        return f"cannot reach {address} ({error})"
    return None


@contextmanager
def ray_session(workers: int | None = None, address: str | None = None) -> Iterator[Any]:
    """The ``ray`` module, initialised: connected to the cluster at ``address`` (or
    ``RAY_ADDRESS``), or with None or ``"local"`` a local Ray with ``workers`` CPUs (default:
    all cores). A Ray started here is shut down on exit; one already running is left as it
    is."""
    import ray

    if ray.is_initialized():
        yield ray
        return
    address = cluster_address(address)
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    # ray.init puts its own SIGTERM handler in place, which exits at once: a script's
    # (``cli.run_main``: a stop that says how to go on) is set again after it.
    on_sigterm = signal.getsignal(signal.SIGTERM)
    if address in (None, "local"):
        ray.init(
            num_cpus=workers or os.cpu_count(),
            include_dashboard=False,
            configure_logging=False,
        )
    else:
        # Ray retries an address that does not answer for minutes (RAY_ADDRESS is not
        # checked as --address is): refuse it at once.
        why = unreachable(address)
        if why is None:
            try:
                ray.init(address=address, configure_logging=False)
            except ConnectionError as error:  # "auto" with no cluster running here
                why = str(error).splitlines()[0]
        if why is not None:
            raise ValueError(f"Ray cluster (--address or RAY_ADDRESS): {why}")
    if callable(on_sigterm) and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, on_sigterm)
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
    """``fn(item)`` for every item: in this process, in worker processes, or as Ray tasks.

    Example:
        >>> outcomes = map_runs(train_one, [("rlvc", 0), ("dqn", 0)], workers=2)
        >>> [o.result for o in outcomes if o.ok]

    Args:
        fn: a picklable top-level function of one argument.
        items: its arguments, one run each.
        workers: runs side by side on this machine (default: one per core); 1 runs them in
            this process.
        address: Ray cluster to run on (default ``RAY_ADDRESS``; None: this machine;
            ``"local"``: a Ray started here).
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

    if workers is not None and workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    side_by_side = min(workers or os.cpu_count() or 1, len(items))
    if cluster_address(address) is not None:
        _map_ray(fn, items, workers, address, done)
    elif side_by_side > 1:
        _map_processes(fn, items, side_by_side, done)
    else:
        for item in items:
            done(_run_here(fn, item))
    return outcomes


def _run_here(fn: Callable[[Any], Any], item: Any) -> Outcome:
    try:
        return Outcome(item, result=fn(item))
    except Exception:
        return Outcome(item, error=traceback.format_exc())


def _run_in_worker(fn: Callable[[Any], Any], item: Any) -> tuple[Any, str | None]:
    # The outcome without the item, which the caller has: a result, or the traceback text
    # whatever the run raised (an exception need not survive pickling).
    outcome = _run_here(fn, item)
    return outcome.result, outcome.error


def _map_processes(fn, items: list, workers: int, done: Callable[[Outcome], None]) -> None:
    # This process runs runs too, beside workers - 1 processes: it has imported everything,
    # where a new process takes seconds to import torch and the rest. Each takes the next run
    # in the list when it ends its last.
    # forkserver, not fork: a process forked from one whose torch or OpenCV thread pools ran
    # hangs at its first parallel call.
    check_not_importing_main("map_runs")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload([*PRELOAD, fn.__module__])
    pool = ProcessPoolExecutor(
        workers - 1, mp_context=context, initializer=_start_worker, initargs=(os.getpid(),)
    )
    todo, lock, stopping = deque(items), threading.Lock(), threading.Event()
    # The processes' outcomes as their runs end; None: a run handed back to this process.
    ended: queue.SimpleQueue[Outcome | None] = queue.SimpleQueue()

    def take() -> tuple[bool, Any]:
        with lock:
            return (True, todo.popleft()) if todo else (False, None)

    def submit(item: Any) -> None:
        try:
            future = pool.submit(_run_in_worker, fn, item)
        except Exception:  # the pool is broken or shut down: this process runs the item
            with lock:
                todo.appendleft(item)
            ended.put(None)
            return
        future.add_done_callback(lambda f: finished(item, f))

    def finished(item: Any, future: Future) -> None:  # in the pool's thread
        try:
            ended.put(Outcome(item, *future.result()))
        except BaseException:  # the run exited its process or killed it, or was cancelled
            ended.put(Outcome(item, error=traceback.format_exc()))
        found, item = take()
        if found:
            submit(item)

    def drained() -> list[Outcome]:
        outcomes = []
        while not ended.empty():
            outcome = ended.get()
            if outcome is not None:
                outcomes.append(outcome)
        return outcomes

    def stop() -> None:
        stopping.set()
        with lock:
            todo.clear()
        for process in list((pool._processes or {}).values()):  # no public way before 3.14
            process.terminate()

    # The processes' first runs are the first in the list. Submitting them waits for the
    # process server to import the modules: this process runs runs meanwhile.
    first = [todo.popleft() for _ in range(workers - 1)]

    def start() -> None:
        for item in first:
            if stopping.is_set():
                return
            submit(item)

    starter = threading.Thread(target=start, daemon=True)
    try:
        with worker_threads():
            starter.start()
            remaining = len(items)
            while remaining:
                found, item = take()
                for outcome in [_run_here(fn, item) if found else ended.get(), *drained()]:
                    if outcome is not None:
                        done(outcome)
                        remaining -= 1
            starter.join()
    except BaseException as error:  # Ctrl-C or SIGTERM: stop the processes' runs too
        stop()
        starter.join()
        stop()  # the processes the starter made meanwhile
        if isinstance(error, KeyboardInterrupt):  # keep the runs that ended
            for outcome in drained():
                if outcome.ok:
                    done(outcome)
        raise
    finally:
        pool.shutdown(cancel_futures=True)


def _map_ray(fn, items: list, workers, address, done: Callable[[Outcome], None]) -> None:
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
