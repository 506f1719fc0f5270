"""Packaging: the built wheel holds every module and every runtime data file of the packages
(episode splits, Spot URDFs, ...), so an installed ``helios`` works outside the source tree.

The list of data files is derived from the source tree (every non-Python file under a package
directory), not written out here, so a new data file that setup.cfg forgets fails this test.
"""

from __future__ import annotations

import configparser
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Non-Python files under the package directories that are not read at run time (none ship).
NOT_RUNTIME = {
    "tools/setup_env.sh": "creates the development .venv (the Makefile's setup step)",
    "tools/gpu_checks.sh": "the CUDA checks, run by hand from a checkout on a CUDA machine (README, GPU)",
}
BUILD_LITTER = {"__pycache__", ".pytest_cache"}


def _packages() -> list[str]:
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / "setup.cfg")
    roots = [line.strip() for line in cfg["options.packages.find"]["include"].split() if line.strip()]
    return [r for r in roots if "*" not in r]


def _source_files() -> tuple[set[str], set[str]]:
    """(python modules, runtime data files) under the package directories, as wheel paths."""
    modules, data = set(), set()
    for package in _packages():
        for path in (ROOT / package).rglob("*"):
            rel = path.relative_to(ROOT)
            if path.is_dir() or BUILD_LITTER & set(rel.parts) or path.suffix == ".pyc":
                continue
            name = rel.as_posix()
            if path.suffix == ".py":
                modules.add(name)
            elif name not in NOT_RUNTIME:
                data.add(name)
    return modules, data


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> zipfile.ZipFile:
    """Build the wheel offline from a copy of the source tree (no build/ or egg-info left in it)."""
    src = tmp_path_factory.mktemp("src")
    ignore = shutil.ignore_patterns(".venv", ".git", "runs", "build", "dist", "*.egg-info", "__pycache__",
                                    ".pytest_cache", "*.rrd")
    for item in ROOT.iterdir():
        if item.name in {".venv", ".git", "runs", "build", "dist"} or item.name.endswith(".egg-info"):
            continue
        if item.is_dir():
            shutil.copytree(item, src / item.name, ignore=ignore)
        else:
            shutil.copy2(item, src / item.name)
    out = tmp_path_factory.mktemp("wheel")
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
                           "-q", "-w", str(out), str(src)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (path,) = out.glob("helios_testbed-*.whl")
    with zipfile.ZipFile(path) as zf:
        yield zf


def test_the_wheel_holds_every_runtime_data_file(wheel):
    names = set(wheel.namelist())
    modules, data = _source_files()
    assert {"tasks/data/smoke.jsonl", "tasks/data/val.jsonl", "tasks/data/train.jsonl", "tasks/data/large.jsonl",
            "robots/spot/spot_arm.urdf", "robots/spot/spot_arm_sim.urdf"} <= data      # the derivation sees them
    assert not data - names, f"data files missing from the wheel (add them to setup.cfg package_data): " \
                             f"{sorted(data - names)}"
    assert not modules - names, f"modules missing from the wheel (a folder without __init__.py?): " \
                                f"{sorted(modules - names)}"
    from tasks.episodes import SPLITS

    for split in SPLITS:        # whole files, not empty placeholders
        assert wheel.read(f"tasks/data/{split}.jsonl") == (ROOT / "tasks" / "data" / f"{split}.jsonl").read_bytes()


def test_the_wheel_ships_no_tests_and_declares_the_console_script(wheel):
    names = wheel.namelist()
    assert not [n for n in names if n.startswith(("tests/", "configs/"))]
    entry = next(n for n in names if n.endswith(".dist-info/entry_points.txt"))
    assert "helios = tools.cli:main" in wheel.read(entry).decode()
