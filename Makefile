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

.PHONY: demo test lint bench setup clean

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
	$(BIN)/pip install -q -e ".[test,nets,batch]"
	$(BIN)/pip install -q --no-deps mediapipe==0.10.21
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

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports

bench: $(STAMP)
	$(BIN)/semslam bench --presets f2kf,orb --variant "orb-noloop:orb:slam.loop_closing=false" --json out/bench/results.json

clean:
	rm -rf $(VENV) out
