# The two commands of the README: `make quickstart` (set up + run the main job) and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
# torch is pinned to the CPU build that lies on this kind of machine's disk; an unpinned torch pulls CUDA.
TORCH ?= torch==2.13.0

.PHONY: quickstart test install install-dev browser clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q "$(TORCH)" -e ".[onnx]"
	touch $@

$(VENV)/.installed-dev: $(VENV)/.installed
	$(PY) -m pip install -q "$(TORCH)" -e ".[onnx,sweeps,sketch,dev,docs]"
	touch $@

# The browser tests drive Debian's chromium through Playwright (Playwright's own browser download is not
# reachable from CI); installed here when missing and apt-get is usable (root).
browser:
	@command -v chromium >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) \
	  || echo "chromium not installed: the browser tests will skip (install Debian's chromium package)"; }

install: $(VENV)/.installed
install-dev: $(VENV)/.installed-dev

quickstart: install
	$(PY) -m spade.train +experiment=quickstart

test: install-dev browser
	$(PY) -m pytest --durations=15

clean:
	rm -rf $(VENV) outputs logs multirun .pytest_cache
