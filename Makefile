# Two commands set up everything on a fresh machine:
#   make demo   build the demo maps, localize the demo sequences with all four methods
#   make test   ruff check, then the test suite (what CI runs)
#   make test-fast   ruff check, then the unit tests only (tests/unit) on the core install, pytest and ruff: the quick
#                    loop while editing
# and one regenerates every figure the repository commits:
#   make docs   make demo, the benchmark into docs/benchmark/, the README's figures, the docs' printed
#               examples (tools/docs_outputs.py) and docs/*.png
# Each creates .venv with what it needs and the system libraries (open3d: libusb; headless
# screenshots: Mesa's Vulkan driver): the demo runs only simulated parts, so `make demo` installs
# the core alone (no torch: PyPI's Linux torch carries ~15 CUDA libraries, GPU or not); `make test`,
# `make bench` and `make docs` add the models extra (torch, open_clip, ultralytics) and pytest.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
SUDO   := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
CORE   := $(VENV)/.installed-core
STAMP  := $(VENV)/.installed
# the cluster extra (dask): make test installs it on top of make install; make demo does without
CLUSTER_STAMP := $(VENV)/.cluster
DEV_STAMP := $(VENV)/.installed-dev
APT_PACKAGES := libusb-1.0-0 libgomp1 mesa-vulkan-drivers

export YOLO_OFFLINE ?= 1
export YOLO_AUTOINSTALL ?= false
export HF_HUB_OFFLINE ?= 1

.PHONY: install sysdeps demo test test-fast bench docs clean

install: $(STAMP)

sysdeps:
	@missing=""; for p in $(APT_PACKAGES); do \
	  dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  if command -v apt-get >/dev/null; then \
	    echo "installing system packages:$$missing"; \
	    $(SUDO) apt-get update -qq && $(SUDO) apt-get install -y -qq $$missing >/dev/null; \
	  else echo "warning: install these system packages yourself:$$missing"; fi; \
	fi

$(CORE): pyproject.toml
	$(MAKE) sysdeps
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e .
	touch $(CORE)

$(STAMP): $(CORE)
	# torch first, pinned to a build whose torchvision imports beside it
	$(PY) -m pip install -q torch==2.14.1 torchvision==0.29.1
	$(PY) -m pip install -q -e '.[models,dev]'
	touch $(STAMP)

demo: $(CORE)
	$(PY) tools/demo.py

$(CLUSTER_STAMP): $(STAMP)
	$(PY) -m pip install -q -e '.[cluster]'
	touch $(CLUSTER_STAMP)

test: $(CLUSTER_STAMP)
	$(PY) -m ruff check .
	$(PY) -m pytest -q -n auto --maxprocesses 4 --dist loadscope --durations=15

# the core, pytest and ruff only: no torch, so a fresh clone is testing in a minute or two
$(DEV_STAMP): $(CORE)
	$(PY) -m pip install -q -e '.[dev]'
	touch $(DEV_STAMP)

test-fast: $(DEV_STAMP)
	$(PY) -m ruff check .
	$(PY) -m pytest -q tests/unit -m "not models" --durations=15

bench: $(STAMP)
	$(PY) tools/bench.py

docs: $(STAMP) demo
	$(PY) tools/bench.py --docs
	$(PY) tools/scene_stats.py demo_apartment demo_desk demo_clutter --readme docs/scenes.md
	$(PY) tools/docs_outputs.py --write
	$(PY) tools/screenshot.py outputs/maps/demo.map.rrd docs/map_recording.png
	$(PY) tools/screenshot.py outputs/loc/demo/clipclique/recording.rrd docs/localization_recording.png --frame 102

clean:
	rm -rf $(VENV) outputs
