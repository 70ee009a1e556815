"""Settings shared by every test module."""

import os


def pytest_configure(config):
    # Under pytest-xdist (`make test`: a worker a core) each worker keeps to one thread, as the
    # library's own workers do: more threads only contend with the other workers for the cores
    # (the suite on 2 cores: 441 s so, 706 s with each worker's default threads, 570 s in one
    # process).
    if os.environ.get("PYTEST_XDIST_WORKER"):
        from vistask.parallel import one_thread

        one_thread()
