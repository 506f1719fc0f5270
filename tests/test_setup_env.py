"""tools/setup_env.sh refuses a venv that already serves another checkout.

Why: ``pip install -e .`` into a venv that holds an editable install of this project from another
folder re-points it silently, and the other checkout then runs this one's code (seen when a second
clone shared the first one's .venv by symlink and ran ``make``). The venvs here are bare
(``--without-pip``) with a hand-written dist-info, so the refusal is tested without installing.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "tools" / "setup_env.sh"


def _venv_serving(tmp_path: Path, checkout: Path) -> Path:
    """A bare venv whose site-packages says this project is installed editable from ``checkout``."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    version = f"python{sys.version_info.major}.{sys.version_info.minor}"
    info = venv / "lib" / version / "site-packages" / "helios_testbed-0.1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: helios-testbed\nVersion: 0.1.0\n")
    (info / "direct_url.json").write_text(json.dumps({"dir_info": {"editable": True},
                                                      "url": checkout.resolve().as_uri()}))
    return venv


def _setup(venv: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "HELIOS_NO_BROWSER_INSTALL": "1"}
    return subprocess.run(["bash", str(SCRIPT), str(venv)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=120)


def test_a_venv_serving_another_checkout_is_refused_before_anything_is_installed(tmp_path):
    other = tmp_path / "other-checkout"
    other.mkdir()
    venv = _venv_serving(tmp_path, other)
    before = sorted(p.name for p in (venv / "lib").rglob("*"))
    result = _setup(venv)
    assert result.returncode == 1, result.stdout + result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, result.stderr
    assert f"already serves the checkout at {other.resolve()}" in lines[0]
    assert f"re-point it to {ROOT.resolve()}" in lines[0]
    assert "installing the project" not in result.stdout
    assert sorted(p.name for p in (venv / "lib").rglob("*")) == before


def test_a_checkout_path_with_a_space_is_recognised(tmp_path):
    """pip writes the checkout's path percent-encoded ("other%20checkout"): the guard decodes it."""
    other = tmp_path / "other checkout"
    other.mkdir()
    venv = _venv_serving(tmp_path, other)
    assert "%20" in (next((venv / "lib").rglob("direct_url.json"))).read_text()
    result = _setup(venv)
    assert result.returncode == 1, result.stdout + result.stderr
    assert f"already serves the checkout at {other.resolve()};" in result.stderr


def test_a_venv_left_by_a_deleted_checkout_is_not_refused(tmp_path):
    """A venv left over from a checkout that is gone may be taken over: the guard reads the
    folder it names, and prints nothing about it when that folder does not exist."""
    gone = tmp_path / "deleted-checkout"
    venv = _venv_serving(tmp_path, gone)
    script = SCRIPT.read_text()
    guard = script[script.index('if [ -x "$venv/bin/python" ]'):script.index('if [ ! -x "$venv/bin/python" ]')]
    probe = tmp_path / "guard.sh"
    probe.write_text(f'set -euo pipefail\nvenv="{venv}"\n{guard}\necho "served=$served"\n')
    result = subprocess.run(["bash", str(probe)], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == f"served={gone.resolve()}"
    assert result.stderr == ""
