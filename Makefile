# Two entry points for a fresh machine with Python 3.11 and pip: `make demo`, `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
STAMP := $(VENV)/.installed
SYSTEM_PACKAGES := libegl1 libosmesa6 libgl1 libusb-1.0-0
export MUJOCO_GL ?= egl
export PYOPENGL_PLATFORM ?= egl

.PHONY: demo test test-all lint docs bench clean system-packages

$(STAMP): pyproject.toml constraints.txt
	$(MAKE) system-packages
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip
	# torch first: this pin resolves to the local CPU wheel; a bare range would pull CUDA builds.
	$(PIP) install --no-compile torch==2.13.0
	$(PIP) install --no-compile -c constraints.txt -e ".[dev]"
	# robosuite depends on opencv-python; keep exactly one OpenCV (the headless one) importable.
	$(PIP) uninstall -y opencv-python
	$(PIP) install --no-compile -c constraints.txt --force-reinstall --no-deps opencv-python-headless
	# Byte-compile on every core rather than in pip's single process (about half the time).
	# Some packages ship files that do not compile (pip skips them too), hence the || true.
	$(PY) -m compileall -q -j 0 $$($(PY) -c "import sysconfig; print(sysconfig.get_paths()['purelib'])") >/dev/null || true
	$(PY) -c "import cv2, torch, torchrl, gymnasium, stable_baselines3, robosuite, mujoco, roma, dd, minigrid, ray, rliable.library"
	touch $(STAMP)

# Debian libraries for offscreen MuJoCo rendering (EGL / OSMesa) and Open3D.
system-packages:
	@missing=""; for p in $(SYSTEM_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
		echo "installing Debian packages:$$missing"; \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		$$SUDO apt-get update && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y --no-install-recommends $$missing; \
	fi

demo: $(STAMP)
	$(PY) scripts/train_rlvc.py

# The tests marked slow repeat in processes, on Ray or after a signal what other tests check in
# one process; with them `make test` would pass 15 minutes on a 2-core machine. The others run
# a file a worker, a worker a core, each on one thread (tests/conftest.py).
test: $(STAMP)
	$(VENV)/bin/lint-imports
	$(PY) -m pytest -q -m "not slow" -n auto --dist loadfile

test-all: $(STAMP)
	$(VENV)/bin/lint-imports
	$(PY) -m pytest -q

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

# The documentation site, warnings as errors (tests/test_docs.py builds it in `make test` too).
docs: $(STAMP)
	$(PY) -m sphinx -W --keep-going -q -b html docs docs/_build/html
	@echo "open docs/_build/html/index.html"

bench: $(STAMP)
	$(PY) scripts/bench_features.py

clean:
	rm -rf $(VENV) build *.egg-info docs/_build
