"""Helpers for tests that drive the SDK backend against the fake Spot over TLS on 127.0.0.1.

One throwaway CA and server certificate per test process (EC keys, ~50 ms); one fake robot per
test (a fresh demo scene, an ephemeral port). Credentials are random per process and reach the
backend only through the environment, as on a real robot.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import secrets
import shutil
import tempfile
import threading
import time

from robots.spot.fake_spot.certs import TestPKI, make_test_pki
from robots.spot.sdk_backend import PASSWORD_ENV, USERNAME_ENV, SdkBackendConfig, SdkSpotBackend

TEST_USER = "helios-test"
TEST_PASSWORD = "pw-" + secrets.token_urlsafe(12)

_PKI: TestPKI | None = None
_PKI_LOCK = threading.Lock()


def session_pki() -> TestPKI:
    """The test CA + server certificate of this process (made on first use, removed at exit)."""
    global _PKI
    with _PKI_LOCK:
        if _PKI is None:
            folder = tempfile.mkdtemp(prefix="helios-test-pki-")
            atexit.register(shutil.rmtree, folder, True)
            _PKI = make_test_pki(folder)
        return _PKI


@contextlib.contextmanager
def credentials_env(user: str | None = TEST_USER, password: str | None = TEST_PASSWORD):
    """Temporarily set (or, with None, remove) the Spot credential variables."""
    saved = {k: os.environ.get(k) for k in (USERNAME_ENV, PASSWORD_ENV)}
    try:
        for key, value in ((USERNAME_ENV, user), (PASSWORD_ENV, password)):
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def start_fake(seed: int = 0, **kwargs):
    """A fake Spot in the demo scene, serving the session PKI, accepting the test credentials."""
    from robots.spot.fake_spot.launch import start_demo_fake

    return start_demo_fake(session_pki(), TEST_USER, TEST_PASSWORD, seed=seed, **kwargs)


def fast_config(port: int, **overrides) -> SdkBackendConfig:
    """Backend settings for loopback tests: short timeouts so every fault surfaces well within 2 s.

    The arm's budget is the exception: the fake's stow from the carry pose takes about 5.4 s of
    robot time (the hand retracts, then the joints fold), so a 3 s budget turned every close()
    after a carry into a failed stow and the shutdown for a silent robot. Tests of a stow that
    runs out its time pass a shorter ``arm_move_timeout`` themselves."""
    base = dict(hostname="127.0.0.1", port=port, cert_path=str(session_pki().ca_cert), estop_mode="endpoint",
                rpc_timeout=1.0, image_rpc_timeout=2.0, connect_timeout=3.0, command_margin=0.6,
                arm_move_timeout=8.0, grasp_timeout=8.0, feedback_period=0.02, stand_timeout=3.0,
                power_on_timeout=3.0)
    base.update(overrides)
    return SdkBackendConfig(**base)


def connect(demo, stop_fake_on_close: bool = True, **overrides) -> SdkSpotBackend:
    """An SDK backend connected to ``demo``'s fake Spot (closing it stops the fake too)."""
    with credentials_env():
        backend = SdkSpotBackend(fast_config(demo.port, **overrides))
    if stop_fake_on_close:
        backend.add_close_callback(demo.stop)
    return backend


def sdk_backend_factory():
    """For the shared HAL contract suite: (SDK backend -> fake Spot -> PyBullet, scene facts)."""
    demo = start_fake(seed=0)
    try:
        backend = connect(demo)
    except BaseException:
        demo.stop()
        raise
    facts = {"mug_position": demo.facts["mug_position"], "place_table": demo.facts["place_table"]["centre"],
             "table_height": demo.facts["table_height"]}
    return backend, facts


def python_threads() -> set[threading.Thread]:
    # _DummyThread entries are grpc's own native threads that once called into Python (auth
    # metadata plugin); they are not started by Python and never "end".
    return {t for t in threading.enumerate() if not isinstance(t, threading._DummyThread)}


def wait_for_threads_to_end(before: set, timeout: float = 3.0) -> set:
    """Threads started since ``before`` that are still alive after ``timeout`` s (a leak)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        extra = {t for t in python_threads() - before if t.is_alive()}
        if not extra:
            return set()
        time.sleep(0.02)
    return extra


QUIET_TABLET_COMMS_LOSS_TIMEOUT = 60.0
"""``comms_loss_timeout`` (s) for a fake whose robot must stay powered under the tablet of
``take_lease_as_another_client``: that tablet takes the lease and goes quiet, where a real one keeps
retaining it, and a fake with the default 3 s would sit and power off under it (comms_loss.py)."""


def take_lease_as_another_client(backend) -> None:
    """What the tablet does: a second client takes the body lease from ours (with the credentials
    in the environment where a command set them, as ``tools spot --fake`` does, else the tests').
    It does not retain it afterwards (see ``QUIET_TABLET_COMMS_LOSS_TIMEOUT``)."""
    _lease_as_another_client(backend, "take")


def acquire_lease_as_another_client(backend) -> None:
    """Another client acquires the body lease with AcquireLease (not a take), which a robot grants
    only while nobody holds it or its holder's lease is stale (a refusal raises the SDK's
    ResourceAlreadyClaimedError). It does not retain it afterwards either."""
    _lease_as_another_client(backend, "acquire")


def _lease_as_another_client(backend, verb: str) -> None:
    import bosdyn.client
    from bosdyn.client.lease import LeaseClient

    sdk = bosdyn.client.create_standard_sdk("tablet-in-a-test", cert_resource_glob=backend.config.cert_path)
    robot = sdk.create_robot("127.0.0.1")
    robot.update_secure_channel_port(backend.config.port)
    try:
        robot.authenticate(os.environ.get(USERNAME_ENV, TEST_USER), os.environ.get(PASSWORD_ENV, TEST_PASSWORD),
                           timeout=3)
        client = robot.ensure_client(LeaseClient.default_service_name)
        getattr(client, verb)(timeout=2)
    finally:
        sdk.clear_robots()
