"""Shared pytest setup: the CPU code paths and one native thread per process (see helios.runtime),
and sim fixtures."""

from __future__ import annotations

from helios.runtime import configure_threads, pin_cpu_dispatch

pin_cpu_dispatch()   # before NumPy and torch load: the code paths `python -m tools` runs (helios.runtime)

import signal  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

configure_threads(1)

# A test run started in the background by a non-interactive shell (`nohup make test &`, a CI
# job launched with `&`) inherits SIGINT ignored, and Python then leaves it ignored; the Ctrl-C
# tests of `tools spot` (tests/test_spot_realtime_faults.py) and the subprocesses they start
# would never see it. Nobody can press Ctrl-C on such a run, so give it Python's default back.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def world():
    """A fresh deterministic PyBullet world, closed after the test."""
    from sim.world import World

    w = World()
    yield w
    w.close()


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture(scope="session")
def picture_runs(tmp_path_factory):
    """Two small real runs with episode pictures and their report: the oracle on smoke-00000 (a
    success, with grasp and release frames) and HELIOS on the same episode with 60 s of robot time
    (a timeout, with a map). About 5 s on the 2-core machine."""
    from helios.schema import with_overrides
    from tasks.episodes import load_split
    from tasks.trial_config import TrialConfig
    from tasks.trials import run_batch
    from tools.report import make_report

    root = tmp_path_factory.mktemp("picture_runs")
    episodes = load_split("smoke")[:1]
    configs = {"oracle": with_overrides(TrialConfig(agent="oracle", episodes=1), []),
               "helios": with_overrides(TrialConfig(agent="helios", episodes=1), ["runner.max_sim_time=60"])}
    records = {name: run_batch(cfg, episodes, root / name)[0] for name, cfg in configs.items()}
    report = make_report([root / "oracle", root / "helios"], root / "report")
    return {"root": root, "episode": episodes[0], "configs": configs, "records": records, "report": report}


def pytest_collection_modifyitems(config, items):
    """Tests marked ``gpu`` run the CUDA path where there is a CUDA device and are skipped, with
    the reason, everywhere else (the fast suite must pass on a CPU-only machine)."""
    gpu_items = [item for item in items if item.get_closest_marker("gpu")]
    if not gpu_items:
        return
    import torch

    if torch.cuda.is_available():
        return
    skip = pytest.mark.skip(reason="needs a CUDA device: torch.cuda.is_available() is False on this machine "
                                   "(run `python -m pytest -m gpu` where one is)")
    for item in gpu_items:
        item.add_marker(skip)
