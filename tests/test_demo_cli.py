"""The main job of this issue: `python -m tools demo` runs end to end and writes a valid recording."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

RERUN = Path(sys.executable).with_name("rerun")


def test_demo_command_succeeds_and_writes_a_verifiable_recording(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "tools", "demo", "--seed", "2", "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "result                       SUCCESS" in proc.stdout
    assert "mug resting on               table_place" in proc.stdout
    rrd = tmp_path / "demo_seed2.rrd"
    assert rrd.is_file() and rrd.stat().st_size > 200_000
    if not RERUN.exists():
        pytest.fail(f"rerun CLI missing next to {sys.executable}")
    verify = subprocess.run([str(RERUN), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr
    dump = subprocess.run([str(RERUN), "rrd", "print", str(rrd)], capture_output=True, text=True, timeout=120).stdout
    for entity in ("/world/hand_camera/rgb", "/world/hand_camera/depth", "/transforms", "/world/paths/body",
                   "/spot/visual_geometries/arm0.link_wr1", "/world/scene/mug", "/log"):
        assert entity in dump, f"{entity} missing from the recording"


def test_a_physical_failure_exits_nonzero_with_the_reason():
    # A claw that holds with at most 0.5 N cannot lift a 0.3 kg mug: it slips during the lift.
    proc = subprocess.run([sys.executable, "-m", "tools", "demo", "--no-record", "grasp.hold_force=0.5"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1, proc.stdout
    assert "FAILED the object slipped out of the claw during the lift" in proc.stdout
    assert "mug resting on               table_pick" in proc.stdout
