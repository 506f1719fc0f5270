"""`python -m tools spot`: the dry run against the fake Spot succeeds end to end; bad input (wrong
hostname, untrusted certificate, certificate for other names, nothing listening, missing
credentials, bad arguments) gives one clear error line and exit status 2, never a traceback; and no
credential or token ever reaches a log, the terminal or the run folder."""

from __future__ import annotations

import json
import logging
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("bosdyn.client")

from robots.spot.fake_spot.certs import make_test_pki  # noqa: E402
from robots.spot.fake_spot.server import FakeSpot  # noqa: E402
from robots.spot.sdk_backend import PASSWORD_ENV, USERNAME_ENV  # noqa: E402
from spot_fake_fixtures import (  # noqa: E402
    TEST_PASSWORD,
    TEST_USER,
    connect,
    session_pki,
    start_fake,
    take_lease_as_another_client,
)
from tools.cli import main  # noqa: E402

pytestmark = pytest.mark.timeout(120)
TASK = "Move the mug from the stool to the table"
ROOT = Path(__file__).resolve().parents[1]


def _cli(args: list[str], env_extra: dict | None = None, drop_credentials: bool = False, timeout: float = 60):
    env = dict(os.environ)
    env.pop(USERNAME_ENV, None)
    env.pop(PASSWORD_ENV, None)
    if not drop_credentials:
        env[USERNAME_ENV], env[PASSWORD_ENV] = TEST_USER, TEST_PASSWORD
    env.update(env_extra or {})
    return subprocess.run([sys.executable, "-m", "tools", "spot", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT, env=env)


def _one_clear_error(proc, *fragments: str) -> str:
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    for f in fragments:
        assert f in lines[0], lines[0]
    return lines[0]


# ----------------------------------------------------------------------------- the dry run
def test_fake_dry_run_succeeds_end_to_end(tmp_path):
    proc = _cli(["--fake", "--task", TASK, "--out", str(tmp_path), "--name", "dry"])
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = proc.stdout
    for text in ("fake Spot (demo scene, seed 0)", "connected to helios-fake-spot", "grasp at pixel",
                 "release 10 cm above the table", "shutting down", "result                     SUCCESS",
                 "mug resting on             table_place"):
        assert text in out, out
    run = tmp_path / "dry"
    outcome = json.loads((run / "outcome.json").read_text())
    assert outcome["success"] and outcome["physical"]["resting_on"] == "table_place"
    assert "port:" in (run / "config.yaml").read_text()
    log = (run / "session.log").read_text()
    assert "body lease acquired" in log and "powering off" in log
    everything = out + proc.stderr + "".join(p.read_text() for p in run.iterdir())
    assert TEST_PASSWORD not in everything


# ----------------------------------------------------------------------------- security
def _secrets_absent(texts: list[str], secrets_: list[str]) -> None:
    blob = "\n".join(texts)
    for s in secrets_:
        assert s and s not in blob, "a credential or token leaked into the logs/output"


def test_no_credential_or_token_in_logs_of_a_session(caplog, capfd):
    caplog.set_level(logging.DEBUG)           # everything, including bosdyn's request/response dumps
    demo = start_fake(seed=0)
    backend = connect(demo, stop_fake_on_close=False)
    try:
        backend.observe()
        backend.navigate_to((0.3, 0.0, 0.0))
        backend.move_arm_joints((0.0, -1.2, 1.9, 0.0, -0.7, 0.0))
    finally:
        backend.close()
        demo.stop()
    tokens = demo.fake.issued_tokens
    assert tokens
    out, err = capfd.readouterr()
    texts = [caplog.text, out, err] + [str(r.__dict__) for r in caplog.records]
    assert "blocking request" in caplog.text      # bosdyn's DEBUG request logging was on
    _secrets_absent(texts, [TEST_PASSWORD] + tokens)


def test_no_credential_or_token_in_the_run_folder_or_terminal(tmp_path, caplog, capfd, monkeypatch):
    caplog.set_level(logging.DEBUG)
    issued: list[str] = []
    original = FakeSpot.issue_token

    def recording(self):
        token = original(self)
        issued.append(token)
        return token

    monkeypatch.setattr(FakeSpot, "issue_token", recording)
    monkeypatch.setenv(USERNAME_ENV, TEST_USER)
    monkeypatch.setenv(PASSWORD_ENV, TEST_PASSWORD)
    assert main(["spot", "--fake", "--task", TASK, "--out", str(tmp_path), "--name", "sec"]) == 0
    out, err = capfd.readouterr()
    files = [p.read_text(errors="replace") for p in (tmp_path / "sec").rglob("*") if p.is_file()]
    assert len(files) == 3 and issued
    _secrets_absent([caplog.text, out, err, *files], [TEST_PASSWORD] + issued)


def test_tls_verification_is_never_disabled_in_the_backend():
    files = sorted((ROOT / "robots" / "spot").glob("sdk_*.py"))          # the backend and its parts
    assert ROOT / "robots" / "spot" / "sdk_backend.py" in files and len(files) >= 4
    source = "".join(p.read_text().lower() for p in files)
    for forbidden in ("insecure", "cert_none", "check_hostname = false", "verify_mode", "channel="):
        assert forbidden not in source, forbidden


# ----------------------------------------------------------------------------- bad input
def test_missing_credentials():
    proc = _cli(["127.0.0.1", "--port", "1", "--cert", str(session_pki().ca_cert), "--task", TASK],
                drop_credentials=True)
    _one_clear_error(proc, "credentials missing", USERNAME_ENV, PASSWORD_ENV)


def test_wrong_certificate_default_bd_root_ca():
    demo = start_fake(seed=0)
    try:
        proc = _cli(["127.0.0.1", "--port", str(demo.port), "--task", TASK])   # no --cert: BD's root CA
    finally:
        demo.stop()
    _one_clear_error(proc, "TLS verification", "Boston Dynamics root CA", "--cert")
    assert not demo.fake.issued_tokens


def test_certificate_for_other_names(tmp_path):
    from robots.spot.fake_spot.launch import start_demo_fake

    pki = make_test_pki(tmp_path, dns_names=("robot.example.com",))
    demo = start_demo_fake(pki, TEST_USER, TEST_PASSWORD)
    try:
        proc = _cli(["127.0.0.1", "--port", str(demo.port), "--cert", str(pki.ca_cert), "--task", TASK])
    finally:
        demo.stop()
    _one_clear_error(proc, "TLS verification", "mismatch")
    assert not demo.fake.issued_tokens


def test_wrong_hostname(capsys, monkeypatch):
    real = socket.getaddrinfo

    def no_dns(host, *args, **kwargs):        # loopback only: no query leaves the machine
        if host == "spot-does-not-exist.invalid":
            raise socket.gaierror(socket.EAI_NONAME, "Name or service not known")
        return real(host, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", no_dns)
    monkeypatch.setenv(USERNAME_ENV, TEST_USER)
    monkeypatch.setenv(PASSWORD_ENV, TEST_PASSWORD)
    assert main(["spot", "spot-does-not-exist.invalid", "--task", TASK]) == 2
    err = capsys.readouterr().err
    assert err.strip() == "error: cannot resolve robot hostname 'spot-does-not-exist.invalid': Name or service not known"


@pytest.mark.parametrize("args, fragment", [
    (["127.0.0.1", "--task", "   "], "--task must not be empty"),
    (["127.0.0.1", "--task", TASK, "--agent", "helios-v9"],
     "unknown agent 'helios-v9'; valid agents: helios, helios-5050, helios-no-global, helios-place, scripted-demo, "
     "trusting"),
    (["127.0.0.1", "--task", TASK, "--agent", "helios"], "real perception needs the models' weight folders"),
    (["--fake", "--task", TASK, "--agent", "helios"],
     "agent 'helios' runs on task episodes, not on the demo layout; valid agents: scripted-demo"),
    (["--fake", "--episode", "smoke-00001", "--agent", "scripted-demo"],
     "agent 'scripted-demo' runs on the demo layout, not on task episodes; valid agents: helios"),
    (["--task", TASK], "HOSTNAME is required"),
    (["127.0.0.1", "--fake", "--task", TASK], "leave out the hostname"),
    (["127.0.0.1", "--task", TASK, "--cert", "/nonexistent/ca.pem"], "certificate file '/nonexistent/ca.pem' does not exist"),
    (["127.0.0.1", "--task", TASK, "--set", "rpc_timeout=-1"], "rpc_timeout must be a positive number"),
    (["127.0.0.1", "--task", TASK, "--set", "password=hunter2"], "unknown config key 'password'"),
    (["spot..local", "--task", TASK], "cannot resolve robot hostname 'spot..local'"),
])
def test_bad_arguments_are_one_clear_error(args, fragment, capsys, monkeypatch, tmp_path):
    monkeypatch.setenv(USERNAME_ENV, TEST_USER)
    monkeypatch.setenv(PASSWORD_ENV, TEST_PASSWORD)
    monkeypatch.chdir(tmp_path)
    assert main(["spot", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and fragment in err, err


@pytest.mark.parametrize("key, value", [("hostname", "10.1.2.3"), ("port", "1234"), ("cert_path", "/x.pem")])
@pytest.mark.parametrize("mode", [["--task", TASK], ["--episode", "smoke-00001"]])
def test_fake_refuses_connection_keys_from_the_config_file(key, value, mode, capsys, monkeypatch, tmp_path):
    """The fake Spot replaces hostname, port and cert_path with its own (as it does --port/--cert):
    a scenario file setting one is refused before anything starts, not silently overridden."""
    from tools.spot import FAKE_CONNECTION_KEYS

    assert key in FAKE_CONNECTION_KEYS
    monkeypatch.chdir(tmp_path)
    cfg = tmp_path / "robot.yaml"
    cfg.write_text(f"rpc_timeout: 2.0\n{key}: {value}\n")
    assert main(["spot", "--fake", *mode, "--config", str(cfg), "--out", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err, err
    assert f"config file '{cfg}' sets {key}, which --fake ignores" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["robot.yaml"]       # no run folder, nothing started


def test_nothing_listening(capsys, monkeypatch, tmp_path):
    with socket.socket() as s:            # a port that was free a moment ago: connection refused
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setenv(USERNAME_ENV, TEST_USER)
    monkeypatch.setenv(PASSWORD_ENV, TEST_PASSWORD)
    monkeypatch.chdir(tmp_path)
    assert main(["spot", "127.0.0.1", "--port", str(port), "--cert", str(session_pki().ca_cert), "--task", TASK]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: cannot connect to 127.0.0.1:{port}") and "refused" in err, err


def test_a_lease_taken_during_the_shutdown_fails_the_run_with_one_line(tmp_path, capsys, monkeypatch):
    """The tablet takes the lease right after the task's last stow, before the shutdown's first
    command: the robot is left standing under it. The run once printed SUCCESS and exited 0 (one
    warning in session.log); now it ends with one error line saying so."""
    from robots.spot.sdk_backend import SdkSpotBackend

    real_stow = SdkSpotBackend.stow_arm
    stows = []

    def stow(self):
        result = real_stow(self)
        stows.append(1)
        if len(stows) == 2:                       # the scripted demo's second and last stow
            take_lease_as_another_client(self)
        return result

    monkeypatch.setattr(SdkSpotBackend, "stow_arm", stow)
    rc = main(["spot", "--fake", "--task", TASK, "--out", str(tmp_path), "--name", "taken"])
    out, err = capsys.readouterr()
    assert rc == 1, (out[-2000:], err[-2000:])
    assert err.strip().splitlines()[-1].startswith("error: the robot was not shut down by us: the body lease "
                                                   "was taken by another client during the shutdown"), err
    assert "Traceback" not in err
    outcome = json.loads((tmp_path / "taken" / "outcome.json").read_text())
    assert len(stows) == 2 and outcome["close_problem"] and outcome["success"]   # the task went well, not the shutdown


def test_a_session_log_on_a_full_disk_is_one_warning_and_the_run_goes_on(capsys):
    """Each line once printed logging's "--- Logging error ---" traceback (audit 2026-12-05)."""
    import errno

    from tools.spot import _RunLog

    class FullDisk:
        def write(self, *text):
            raise OSError(errno.ENOSPC, "No space left on device")

        flush = write
        close = write

    handler = _RunLog()
    handler._fh = FullDisk()
    for i in range(3):
        handler.handle(logging.LogRecord("helios.spot", logging.WARNING, __file__, 1, f"line {i}", None, None))
    handler.close()
    err = capsys.readouterr().err
    assert err.splitlines() == ["[spot] warning: session.log cannot be written (No space left on device); the run "
                                "goes on without it"], err


@pytest.mark.parametrize("missing", ["cryptography", "bosdyn.client"])
def test_a_missing_extra_names_an_install_command_that_works(missing, monkeypatch):
    """The package is not on any index: the install hint is the checkout's extra
    (`pip install -e '.[spot]'`), never `pip install 'helios-testbed[...]'`, which finds nothing."""
    import builtins

    from robots.spot.sdk_backend import SpotSdkMissingError, _Bosdyn
    from tools import spot
    from tools.cli import CliError

    real_import = builtins.__import__

    def fake_import(name, *args, **kwargs):
        if name == missing or name.startswith(missing + "."):
            raise ImportError(f"No module named {missing!r}", name=missing)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake_import)
    if missing == "cryptography":
        with pytest.raises(CliError) as err:
            spot._check_fake_available()
    else:
        with pytest.raises(SpotSdkMissingError) as err:
            _Bosdyn()
    assert "pip install -e '.[spot]'" in str(err.value)
    assert "helios-testbed[" not in str(err.value)
