"""Start a fake Spot in the demo scene (two tables and a mug), for tests and ``tools spot --fake``.
A fake in a task episode's procedural home (:class:`EpisodeFake`) is started by
``tasks.fake_sdk.start_episode_fake``: building an episode's scene and judge is the tasks' job."""

from __future__ import annotations

import secrets
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from robots.spot.fake_spot.certs import TestPKI, make_test_pki
from robots.spot.fake_spot.server import FakeSpot
from robots.spot.fake_spot.sim_robot import FakeRobotSim
from robots.spot.fake_spot.sim_view import FakeSimView, LockedJudge
from robots.spot.signals import signals_deferred
from robots.spot.sim_backend import SimBackendConfig

TEARDOWN_MESSAGE = "stopping the fake Spot and removing its throwaway CA first (a few seconds)"


class _RunningFake:
    """What every handle on a running fake Spot offers (needs a ``fake`` attribute)."""

    fake: FakeSpot

    @property
    def port(self) -> int:
        return int(self.fake.port)

    @property
    def world(self):
        return self.fake.sim.world

    def stop(self) -> None:
        self.fake.stop()


@dataclass
class DemoFake(_RunningFake):
    """A running fake Spot plus what a test or a dry run needs to know about its scene."""

    fake: FakeSpot
    pki: TestPKI
    scene: dict                      # sim.scenes.demo.build_demo_scene's facts
    facts: dict = field(default_factory=dict)   # ground truth: mug position, table poses, sizes


def start_serving(fake: FakeSpot, world) -> None:
    """``fake.start()``; when it fails (e.g. not listening within ``START_TIMEOUT_S``) the fake is
    stopped and its world closed, so nothing half-started is left."""
    try:
        fake.start()
    except BaseException:
        fake.stop()
        world.close()
        raise


def stop_fake(fake: "_RunningFake | None", pki_dir: str | Path | None) -> None:
    """Stop a fake Spot (if it started) and remove its throwaway CA and server key (``pki_dir``;
    None: a PKI the caller keeps), also when stopping fails. Ctrl-C, SIGTERM and SIGHUP are held
    until both are done, then delivered (main thread): a further Ctrl-C there left the fake
    half-stopped and the CA's private key in the temp folder (review 2026-12-04). Bounded:
    ``FakeSpot.stop()`` is."""
    with signals_deferred(message=TEARDOWN_MESSAGE):
        try:
            if fake is not None:
                fake.stop()
        finally:
            if pki_dir is not None:
                shutil.rmtree(pki_dir, ignore_errors=True)


def scene_facts(world, scene: dict) -> dict:
    """Ground truth of the demo scene (world = odometry frame of the fake robot)."""
    facts = {"mug_position": world.position(scene["mug"]), "table_height": scene["layout"].table_height}
    for key in ("pick_table", "place_table"):
        info = world.body(scene[key])
        T = world.pose(info.body_id)
        facts[key] = {"name": scene[key], "centre": T[:2, 3].copy(), "yaw": float(np.arctan2(T[1, 0], T[0, 0])),
                      "half_extents": tuple(float(v) for v in info.extra["top_half_extents"]),
                      "top_height": float(info.extra["top_height"])}
    return facts


def start_demo_fake(pki: TestPKI | str | Path, username: str | None = None, password: str | None = None,
                    seed: int = 0, sim_config: SimBackendConfig = SimBackendConfig(), **fake_kwargs) -> DemoFake:
    """Build the demo scene (``seed`` jitters the mug), start a fake Spot serving it on an
    ephemeral 127.0.0.1 port. ``pki`` is a made PKI or a folder to make one in. Without
    credentials the fake accepts a throwaway pair nobody knows (callers that log in pass theirs)."""
    from sim.scenes.demo import build_demo_scene
    from sim.spot import SpotBody
    from sim.world import World

    if not isinstance(pki, TestPKI):
        pki = make_test_pki(pki)
    world = World(sim_config.world)
    try:
        scene = build_demo_scene(world, np.random.default_rng(seed))
        spot = SpotBody(world, scene["robot_start"])
        sim = FakeRobotSim(world, spot, sim_config)
    except Exception:
        world.close()
        raise
    try:
        fake = FakeSpot(sim, pki, username or "helios", password or secrets.token_urlsafe(16), **fake_kwargs)
    except BaseException:
        world.close()
        raise
    start_serving(fake, world)
    return DemoFake(fake, pki, scene, scene_facts(world, scene))


@dataclass
class EpisodeFake(_RunningFake):
    """A running fake Spot in an episode's scene (made by ``tasks.fake_sdk.start_episode_fake``).
    Shaped like ``tasks.runner.SimEpisode`` (``episode``, ``world``, ``scene``, ``backend``,
    ``judge``) so the agent registry and the judge
    take it unchanged; but ``backend`` is the simulator side of the SDK observations
    (:class:`FakeSimView`: for simulated perception and the judge), not the HAL an agent drives:
    that is an ``SdkSpotBackend`` connected to ``port``, wrapped by ``backend.watch``."""

    fake: FakeSpot
    pki: TestPKI
    episode: object                  # tasks.episodes.Episode
    scene: object                    # sim.scenes.home.HomeScene
    backend: FakeSimView
    judge: LockedJudge               # tasks.metrics.EpisodeJudge, run under the fake's sim_lock
