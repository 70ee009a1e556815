"""How the heavy parts of a run take memory from the kernel, and how much they take."""

from __future__ import annotations

import resource
import threading
from collections.abc import Iterator
from contextlib import contextmanager, suppress

import psutil

try:
    from numpy._core.multiarray import _set_madvise_hugepage
except ImportError:  # numpy < 2
    from numpy.core.multiarray import _set_madvise_hugepage


@contextmanager
def base_pages() -> Iterator[None]:
    """Numpy's new arrays on the kernel's base pages, not transparent huge pages, inside the
    block (also a decorator: ``@base_pages()``).

    numpy asks the kernel for huge pages for every array of 4 MB or more, and on some machines
    a huge page costs far more to fault in than the base pages it replaces. It shows where
    memory is taken afresh, step after step (a 2-core VM whose kernel gives huge pages on
    request):

    - collecting keeps every batch of percepts: a step of 128 car percepts took 33-61 ms
      instead of 7-8 ms, 10,000 random car interactions 7.7-9.4 s instead of 1.4-1.9 s;
    - a compound search makes arrays of millions of pairs of occurrences, in two threads:
      the car's first database's stages took 31-32 s of compound search instead of 25-26 s,
      a search of 8 classes at 101 classes 1.5 s instead of 1.15 s.

    Example:
        >>> with base_pages():
        ...     table = np.zeros((50_000, 640), np.float32)  # 128 MB on base pages
    """
    before = _set_madvise_hugepage(False)
    try:
        yield
    finally:
        _set_madvise_hugepage(before)


class PeakMemory:
    """Peak resident memory of this process and its children, in MB, inside the block.

    A thread sums the resident memory of the process tree every ``every`` seconds; the
    process's own peak (``ru_maxrss``, which the kernel keeps exactly) is a lower bound that
    catches a spike between two samples.

    Example:
        >>> with PeakMemory() as memory:
        ...     agent.learn(40_000)
        >>> memory.peak_mb

    Args:
        every: seconds between two samples (> 0, default 0.05).
    """

    def __init__(self, every: float = 0.05) -> None:
        self.every, self.peak_mb = every, 0.0
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _tree_mb(self) -> float:
        process = psutil.Process()
        total = 0
        for p in [process, *process.children(recursive=True)]:
            with suppress(psutil.Error):  # a child that ended meanwhile
                total += p.memory_info().rss
        return total / 2**20

    def _sample(self) -> None:
        while not self._done.wait(self.every):
            self.peak_mb = max(self.peak_mb, self._tree_mb())

    def __enter__(self) -> PeakMemory:
        self.peak_mb = self._tree_mb()
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._done.set()
        self._thread.join()
        own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KB on Linux
        self.peak_mb = max(self.peak_mb, self._tree_mb(), own)
