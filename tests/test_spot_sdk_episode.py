"""A task episode through SDK backend -> fake Spot -> PyBullet ends like the same episode on the sim
backend: same agent code, same judge, same outcome flags; and the teardown leaves no thread behind.

The two runs need not issue identical commands: the SDK delivers 16-bit depth (1 mm steps at the
fake's depth_scale), and the agent's drop-place picks the surface point nearest the 99th height
percentile, which a millimetre moves across a seat (on the schema-1 smoke-00001, a chair, the place
point moved ~8 cm; raw vs JPEG colour makes no difference, the simulated detector reads ground truth). The SDK place
also releases from its own grip estimate, not the sim's true object extent. The outcome flags
must still agree.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("bosdyn.client")

from spot_fake_fixtures import (TEST_PASSWORD, TEST_USER, credentials_env, fast_config, python_threads,  # noqa: E402
                                session_pki, wait_for_threads_to_end)
from tasks.episodes import load_split  # noqa: E402
from tasks.fake_sdk import run_fake_sdk_episode, start_episode_fake  # noqa: E402
from tasks.registry import make_agent  # noqa: E402
from tasks.runner import run_sim_episode  # noqa: E402

pytestmark = pytest.mark.timeout(300)
FLAGS = ("find_obj", "pick", "find_rec", "place", "success")


def _episode(episode_id: str):
    return next(e for e in load_split(episode_id.split("-")[0]) if e.episode_id == episode_id)


def test_sdk_observation_resolves_to_the_frame_the_fake_rendered():
    from robots.spot.sdk_backend import SdkSpotBackend

    ep = start_episode_fake(session_pki(), _episode("smoke-00001"), TEST_USER, TEST_PASSWORD)
    try:
        with credentials_env():
            backend = SdkSpotBackend(fast_config(ep.port))
        try:
            obs = ep.backend.watch(backend).observe()
            frame, seg = ep.backend.frame_for(obs.rgb)
            with ep.fake.sim_lock:
                T_world_body = ep.fake.sim.spot.T_world_body()
            # odom of the fake is its world frame: SDK poses are world poses
            np.testing.assert_allclose(obs.T_world_body, T_world_body, atol=1e-9)
            np.testing.assert_allclose(obs.T_world_cam, frame.T_world_cam, atol=1e-9)
            assert seg.shape == obs.rgb.shape[:2]
            valid = obs.depth > 0
            assert valid.mean() > 0.5
            assert np.max(np.abs(obs.depth[valid] - frame.depth[valid])) <= 0.5 / ep.fake.depth_scale + 1e-6
            assert ep.backend.segmentation_for(obs) is seg
            with pytest.raises(KeyError):
                ep.backend.frame_for(obs.rgb.copy())     # only the observation's own array is known
        finally:
            backend.close()
    finally:
        ep.stop()


# A smoke episode HELIOS completes on the sim backend at seed 0 (the same as tests/test_helios_agent.py).
SUCCESS_EPISODE = "smoke-00000"


def test_smoke_episode_through_sdk_matches_sim_backend():
    episode = _episode(SUCCESS_EPISODE)
    sim = run_sim_episode(lambda s: make_agent("helios", s), episode, seed=0)
    assert sim.success, sim.as_dict()

    before = python_threads()
    with credentials_env():
        sdk = run_fake_sdk_episode("helios", episode, seed=0, pki=session_pki())
    leaked = wait_for_threads_to_end(before, timeout=5.0)
    assert not leaked, f"threads left after teardown: {sorted(t.name for t in leaked)}"

    assert sdk.error is None and not sdk.limit_hit, sdk.as_dict()
    assert {f: getattr(sdk.metrics, f) for f in FLAGS} == {f: getattr(sim.metrics, f) for f in FLAGS}
    assert sdk.metrics.released_on == sim.metrics.released_on
    assert sdk.metrics.collisions == sim.metrics.collisions == 0
    assert sdk.agent == sim.agent and sdk.seed == sim.seed == 0
