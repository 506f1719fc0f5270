# HELIOS testbed: every target sets up what it needs first (Debian libusb for Open3D, .venv, pip).
# Two commands cover a fresh machine:  `make run` (main job) and `make test` (test suite).
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
ARGS   ?=

.PHONY: setup run demo compare sensitivity test test-all test-workers test-hardware test-hardware-env bench clean

setup: $(STAMP)

$(STAMP): setup.cfg pyproject.toml tools/setup_env.sh
	bash tools/setup_env.sh $(VENV)
	touch $(STAMP)

# The main job: HELIOS on the 20 smoke episodes (2 worker processes), printing the metrics table,
# then the report (table, PNG plots, HTML) in runs/smoke/report/. Re-running resumes.
run: setup
	$(PY) -m tools trials --config configs/smoke.yaml --workers 2 --out runs/smoke --replace-stale $(ARGS)
	$(PY) -m tools report runs/smoke --out runs/smoke/report

# Scripted single pick-and-place in a two-table scene with a rerun recording.
demo: setup
	$(PY) -m tools demo $(ARGS)

# The paper's ablation table on val: HELIOS, w/o global objective, trusting, 50-50 IG, two -gt
# twins and HELIOS under the earlier readings, on the first N episodes (seed 0, 2 workers;
# resumable, and a larger N extends the runs), then one report on the episodes all runs share
# (one scenario file per run: configs/val_<run>.yaml; more runs: COMPARE="helios helios-place ...").
# About 4-10 min per run for N=200 on the 2-core machine (2026-12-05; trusting runs are the quickest).
# SPLIT=large runs the same scenarios on the split of large homes (18-24 m), where search policies
# rank (README, "Large homes"): make compare SPLIT=large N=500 COMPARE="helios helios-no-global ..."
# (about 30-55 min per run, trusting the quickest); the runs go to runs/<SPLIT>/<run>.
COMPARE ?= helios helios-no-global trusting helios-5050 helios-gt trusting-gt helios-earlier
N ?= 200
SPLIT ?= val
# The paper's "1 pick" and "5 picks" rows besides the unlimited one (tools report --pick-limits).
PICK_LIMITS ?= 1,5
compare: setup
	$(PY) -m tools.compare_check "$(COMPARE)" "$(PICK_LIMITS)" "$(SPLIT)"
	for a in $(COMPARE); do \
	  $(PY) -m tools trials --config configs/val_$$a.yaml --split $(SPLIT) --episodes $(N) --workers 2 --out runs/$(SPLIT)/$$a --progress lines || exit 1; \
	done
	$(PY) -m tools report $(addprefix runs/$(SPLIT)/,$(COMPARE)) --common --pick-limits "$(PICK_LIMITS)" --out runs/$(SPLIT)/report

# The paper's sensitivity analysis (its appendix: one hyper-parameter of its table changed at a
# time): HELIOS once per setting of SENSITIVITY (KEY=VALUE, as `tools trials` takes them) on the
# first N episodes of SPLIT, into runs/<SPLIT>/sensitivity/KEY=VALUE, against HELIOS with the
# paper's values (runs/<SPLIT>/sensitivity/helios: its own run, as `make compare`'s may be longer,
# and a run is never shortened); then one report (tools report: a "settings changed" table names
# each row's setting, paired sign tests against the paper's values, 1-pick and 5-picks rows).
# Resumable and extendable as compare is.
# Tune on train only: make sensitivity SPLIT=train N=100 (7-9 min per run on 2 cores, 2026-12-06).
SENSITIVITY ?= helios.scoring.alpha_cs=0.1 helios.scoring.alpha_cs=2 helios.search.alpha_d=0.0001 \
  helios.search.alpha_d=0.01 helios.decision.tau_object=0.3 helios.decision.tau_object=0.7 \
  helios.decision.tau_increase=0.1
sensitivity: setup
	$(PY) -m tools.compare_check helios "$(PICK_LIMITS)" "$(SPLIT)" "$(SENSITIVITY)"
	$(PY) -m tools trials --config configs/val_helios.yaml --split $(SPLIT) --episodes $(N) --workers 2 --out runs/$(SPLIT)/sensitivity/helios --progress lines
	for s in $(SENSITIVITY); do \
	  $(PY) -m tools trials --config configs/val_helios.yaml --split $(SPLIT) --episodes $(N) --workers 2 --out "runs/$(SPLIT)/sensitivity/$$s" --progress lines "$$s" || exit 1; \
	done
	$(PY) -m tools report $(addprefix runs/$(SPLIT)/sensitivity/,helios $(SENSITIVITY)) --common --pick-limits "$(PICK_LIMITS)" --out runs/$(SPLIT)/sensitivity/report

# Fast test suite (what CI runs): headless, deterministic. Tests run in TEST_WORKERS pytest-xdist
# processes: by default two per core, at most 4 (a test process's memory peaks near 2 GB;
# each test is single-threaded, and two fifths of the tests' time is waiting, not computing: the
# fake Spot's real-time clock, subprocesses, bounded waits; so processes beyond the cores keep the
# cores busy: on a 2-core AMD EPYC 6 min 33 s with 2, 5 min 17 s with 3 (1,533 tests), and, same
# tree back to back, 5 min 13 s with 3 against 4 min 49 s with 4 (1,555 tests, 2026-12-06));
# TEST_WORKERS=auto gives one per core, TEST_WORKERS=0 runs them in this process (a debugger,
# `-s`). Idle processes take tests queued for busy ones (--dist worksteal): the last long tests no
# longer run on one process while the others wait (same tree, back to back: 4 min 57 s with
# --dist load, 4 min 38 s).
DEFAULT_TEST_WORKERS := $(shell n=$$(nproc 2>/dev/null || echo 1); n=$$((n * 2)); [ $$n -gt 4 ] && n=4; echo $$n)
TEST_WORKERS ?= $(DEFAULT_TEST_WORKERS)
XDIST = -n $(TEST_WORKERS) --maxprocesses 4 --dist worksteal
test: test-workers setup
	$(PY) -m pytest -m "not slow and not hardware" -q $(XDIST) $(ARGS)

# TEST_WORKERS checked before set-up (xdist's own parser takes -1 and runs in one process unannounced).
test-workers:
	@case "$(TEST_WORKERS)" in auto|logical) ;; ""|*[!0-9]*) echo "error: TEST_WORKERS must be auto, logical or a number of test processes (0: in this process), got '$(TEST_WORKERS)'" >&2; exit 2;; esac

# Everything, including slow multi-episode tests (not the hardware stages: make test-hardware).
test-all: test-workers setup
	$(PY) -m pytest -m "not hardware" -q $(XDIST) $(ARGS)

# The hardware stages on a real Spot (tests/test_hardware.py; README, "Hardware checks"): connect
# only, power-stand-sit, one hand-camera frame, arm gaze and stow, in that order, in this process,
# stopping at the first failure. The robot: HELIOS_SPOT_HOST, BOSDYN_CLIENT_USERNAME/PASSWORD
# (optional HELIOS_SPOT_PORT, HELIOS_SPOT_CA, HELIOS_SPOT_ESTOP, HELIOS_SPOT_CONFIG). The robot
# stands up and unfolds its arm: a clear 2 m around it, an e-stop at hand.
test-hardware: test-hardware-env setup
	$(PY) -m pytest -m hardware -x -v -rA -p no:cacheprovider tests/test_hardware.py $(ARGS)

# The robot's address and credentials checked before set-up, in one line.
test-hardware-env:
	@if [ -z "$$HELIOS_SPOT_HOST" ]; then echo "error: make test-hardware needs a robot: set HELIOS_SPOT_HOST (its hostname or IP address), BOSDYN_CLIENT_USERNAME and BOSDYN_CLIENT_PASSWORD" >&2; exit 2; fi
	@if [ -z "$$BOSDYN_CLIENT_USERNAME" ] || [ -z "$$BOSDYN_CLIENT_PASSWORD" ]; then echo "error: make test-hardware needs the robot's credentials: set BOSDYN_CLIENT_USERNAME and BOSDYN_CLIENT_PASSWORD" >&2; exit 2; fi

# Benchmarks: SUITES (default sim; e.g. SUITES="scenes agent"), then ARGS (e.g. ARGS=--quick).
SUITES ?= sim
bench: setup
	$(PY) -m tools bench $(SUITES) $(ARGS)

clean:
	rm -rf $(VENV) build *.egg-info runs/demo runs/smoke
