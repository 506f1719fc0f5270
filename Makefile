# HELIOS testbed: every target sets up what it needs first (Debian libusb for Open3D, .venv, pip).
# Two commands cover a fresh machine:  `make run` (main job) and `make test` (test suite).
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
ARGS   ?=

.PHONY: setup run demo test test-all bench lint clean

setup: $(STAMP)

$(STAMP): setup.cfg pyproject.toml tools/setup_env.sh
	bash tools/setup_env.sh $(VENV)
	touch $(STAMP)

# The main job: a short batch of simulated pick-and-place trials (20 smoke episodes), printing the
# metrics table and writing runs/smoke/{config.yaml,episodes.jsonl,summary.json}.
run: setup
	$(PY) -m tools trials --agent oracle --split smoke --episodes 20 --seed 0 --out runs/smoke $(ARGS)

# Scripted single pick-and-place in a two-table scene with a rerun recording.
demo: setup
	$(PY) -m tools demo --out runs/demo $(ARGS)

# Fast test suite (what CI runs): headless, deterministic, under 5 minutes on 2 cores.
test: setup
	$(PY) -m pytest -m "not slow" -q $(ARGS)

# Everything, including slow multi-episode tests.
test-all: setup
	$(PY) -m pytest -q $(ARGS)

bench: setup
	$(PY) -m tools bench $(or $(ARGS),sim)

clean:
	rm -rf $(VENV) build *.egg-info runs/demo runs/smoke
