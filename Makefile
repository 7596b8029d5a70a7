# The two commands of the README: `make quickstart` (set up + run the main job) and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
# torch is pinned to the CPU build that lies on this kind of machine's disk; an unpinned torch pulls CUDA.
TORCH ?= torch==2.13.0

.PHONY: quickstart test install install-dev clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q "$(TORCH)" -e ".[onnx]"
	touch $@

$(VENV)/.installed-dev: $(VENV)/.installed
	$(PY) -m pip install -q "$(TORCH)" -e ".[onnx,sweeps,dev]"
	touch $@

install: $(VENV)/.installed
install-dev: $(VENV)/.installed-dev

quickstart: install
	$(PY) -m spade.train +experiment=quickstart

test: install-dev
	$(PY) -m pytest

clean:
	rm -rf $(VENV) outputs logs multirun .pytest_cache
