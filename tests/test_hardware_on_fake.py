"""The hardware stages (``tests/test_hardware.py``, marker ``hardware``) work: run as a researcher
runs them (``pytest -m hardware`` in a process of its own, the robot named by ``HELIOS_SPOT_HOST``
and the other variables) against a fake Spot on 127.0.0.1, every stage passes, and the fake ends
sitting, powered off, its lease and e-stop free; without ``HELIOS_SPOT_HOST``, or not selected
with ``-m hardware``, every stage is skipped with the reason; ``make test-hardware`` refuses in one
line without the robot's address or credentials."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

pytest.importorskip("bosdyn.client")

from robots.spot.sdk_config import PASSWORD_ENV, USERNAME_ENV  # noqa: E402
from spot_fake_fixtures import TEST_PASSWORD, TEST_USER, session_pki, start_fake  # noqa: E402

pytestmark = pytest.mark.timeout(180)
ROOT = Path(__file__).resolve().parents[1]
STAGES = ["test_a_connect_only", "test_b_power_stand_sit", "test_c_hand_camera", "test_d_arm_gaze_and_stow"]
HARDWARE_ENV = ("HELIOS_SPOT_HOST", "HELIOS_SPOT_PORT", "HELIOS_SPOT_CA", "HELIOS_SPOT_ESTOP", "HELIOS_SPOT_CONFIG",
                USERNAME_ENV, PASSWORD_ENV, "PYTEST_XDIST_WORKER", "PYTEST_XDIST_TESTRUNUID", "PYTEST_ADDOPTS")


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in HARDWARE_ENV}
    env.update(extra)
    return env


def _run_stages(tmp_path: Path, env: dict, *args: str) -> tuple[dict[str, tuple[str, str]],
                                                                subprocess.CompletedProcess]:
    """``pytest -m hardware tests/test_hardware.py`` in a process of its own: stage -> (outcome,
    message) from its JUnit report, and the finished process."""
    report = tmp_path / "hardware.xml"
    proc = subprocess.run([sys.executable, "-m", "pytest", "tests/test_hardware.py", "-p", "no:cacheprovider",
                           "-q", "-rA", f"--junitxml={report}", *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=150)
    assert report.exists(), proc.stdout + proc.stderr
    outcomes = {}
    for case in ET.parse(report).getroot().iter("testcase"):
        child = next((c for c in case if c.tag in ("failure", "error", "skipped")), None)
        outcomes[case.get("name")] = ("passed", "") if child is None else (child.tag, child.get("message", ""))
    return outcomes, proc


def _fake_env(demo) -> dict[str, str]:
    """The variables a researcher sets for a robot, naming the fake (its port, its throwaway CA)."""
    return _env(HELIOS_SPOT_HOST="127.0.0.1", HELIOS_SPOT_PORT=str(demo.port), HELIOS_SPOT_CA=str(session_pki().ca_cert),
                HELIOS_SPOT_ESTOP="endpoint", **{USERNAME_ENV: TEST_USER, PASSWORD_ENV: TEST_PASSWORD})


def test_every_stage_passes_against_the_fake_spot(tmp_path):
    """In real time (``time_scale=1``: the stand, the gaze and the stow take as long as on Spot)."""
    demo = start_fake(seed=0, time_scale=1.0)
    fake = demo.fake
    try:
        outcomes, proc = _run_stages(tmp_path, _fake_env(demo), "-m", "hardware", "-x")
        assert outcomes == {name: ("passed", "") for name in STAGES}, proc.stdout[-4000:] + proc.stderr[-2000:]
        assert proc.returncode == 0
        # what the stages did on the robot: stood up twice (b, d), gazed and stowed once (d),
        # and left it sitting, powered off, with neither lease holder nor e-stop endpoint
        kinds = [c.kind for c in fake.commands.values()]
        assert kinds.count("stand") == 2 and kinds.count("arm_gaze") == 1 and "arm_named" in kinds, kinds
        assert kinds.count("safe_power_off") == 2, kinds
        assert not fake.powered and fake.lease_owner is None and not fake._endpoints
        for line in ("time sync: robot clock skew +7.2", "battery battery: 80 %", "frame time",
                     "optical axis", "close() took"):
            assert line in proc.stdout, line
    finally:
        demo.stop()


def test_a_robot_with_a_critical_fault_fails_the_first_stage_and_nothing_moves(tmp_path):
    """The stages are not vacuous: a critical battery fails stage (a), and -x stops the run there,
    before any stage powers the robot."""
    demo = start_fake(seed=0)
    fake = demo.fake
    try:
        fake.inject("battery_critical", charge=12)
        outcomes, proc = _run_stages(tmp_path, _fake_env(demo), "-m", "hardware", "-x")
        assert list(outcomes) == STAGES[:1], proc.stdout
        outcome, message = outcomes[STAGES[0]]
        assert outcome == "failure" and "critical system faults: ['battery_critical [battery, robot]']" in message, \
            message
        assert proc.returncode == 1
        kinds = [c.kind for c in fake.commands.values()]
        assert "stand" not in kinds and not fake.powered and fake.lease_owner is None and not fake._endpoints, kinds
    finally:
        demo.stop()


def test_the_stages_skip_with_the_reason_unless_a_robot_is_named_and_they_are_selected(tmp_path):
    outcomes, proc = _run_stages(tmp_path, _env(), "-m", "hardware")
    assert set(outcomes) == set(STAGES), proc.stdout + proc.stderr
    for outcome, message in outcomes.values():
        assert outcome == "skipped" and "set HELIOS_SPOT_HOST" in message, message
    assert "make test-hardware" in proc.stdout
    # a robot named, its credentials set, but the stages not selected with -m hardware: skipped too
    # (a robot address left in the environment must not make a plain `pytest` stand the robot up)
    named = _env(HELIOS_SPOT_HOST="127.0.0.1", HELIOS_SPOT_PORT="1", **{USERNAME_ENV: "u", PASSWORD_ENV: "p"})
    outcomes, proc = _run_stages(tmp_path, named)
    assert {o for o, _ in outcomes.values()} == {"skipped"} and len(outcomes) == len(STAGES), proc.stdout
    assert all("select the hardware stages explicitly with -m hardware" in m for _, m in outcomes.values())
    outcomes, proc = _run_stages(tmp_path, _env(HELIOS_SPOT_HOST="127.0.0.1"), "-m", "hardware")
    assert all(o == "skipped" and f"{USERNAME_ENV} and {PASSWORD_ENV} are not" in m for o, m in outcomes.values())


@pytest.mark.parametrize("env, message", [
    ({}, "error: make test-hardware needs a robot: set HELIOS_SPOT_HOST (its hostname or IP address), "
         "BOSDYN_CLIENT_USERNAME and BOSDYN_CLIENT_PASSWORD"),
    ({"HELIOS_SPOT_HOST": "192.168.80.3", USERNAME_ENV: "user"},
     "error: make test-hardware needs the robot's credentials: set BOSDYN_CLIENT_USERNAME and "
     "BOSDYN_CLIENT_PASSWORD"),
])
def test_make_test_hardware_refuses_without_a_robot_in_one_line(env, message):
    if shutil.which("make") is None:
        pytest.skip("no make here")
    text = (ROOT / "Makefile").read_text()
    assert "\ntest-hardware: test-hardware-env setup" in text        # refused before set-up
    done = subprocess.run(["make", "-s", "-C", str(ROOT), "test-hardware-env"], capture_output=True, text=True,
                          timeout=60, env=_env(**env))
    assert done.returncode == 2 and done.stderr.splitlines()[0] == message, done.stderr
    assert "-m hardware" in text[text.index("\ntest-hardware:"):]
    for target in ("\ntest: ", "\ntest-all: "):        # the unit test suites leave the robot alone
        recipe = text[text.index(target):].split("\n\n")[0]
        assert "not hardware" in recipe, recipe
