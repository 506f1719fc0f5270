"""Running a task episode through the Spot SDK against a fake Spot: agent -> ``SdkSpotBackend`` ->
bosdyn-client over TLS -> ``FakeSpot`` -> PyBullet, on the same scene, with the same agent code and
the same ground-truth judge as ``tasks.runner.run_sim_episode``. It is the hardware dry run of a
real episode: whatever the SDK path loses (JPEG colour, 16-bit depth, poses through frame
snapshots, wall-clock command timing) shows up as a difference to the sim backend's result.

Credentials come from the environment (``BOSDYN_CLIENT_USERNAME``/``BOSDYN_CLIENT_PASSWORD``), as
on a robot; the fake accepts exactly them. Times in the result are the robot's (wall) clock.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import asdict, replace
from typing import Callable

from tasks.episodes import Episode
from tasks.metrics import EpisodeJudge, MetricsConfig
from tasks.registry import RunContext, make_agent
from tasks.runner import EpisodeResult, RunnerConfig, build_episode_world, run_episode


def start_episode_fake(pki, episode: Episode, username: str, password: str, sim_config=None,
                       metrics: MetricsConfig | None = None, **fake_kwargs):
    """Build ``episode``'s home (the scene ``SimEpisode.create`` builds), put Spot at its start
    pose, start a fake Spot serving it on an ephemeral 127.0.0.1 port that accepts exactly
    ``username``/``password``; returns its ``robots.spot.fake_spot.launch.EpisodeFake``. ``pki``:
    a ``TestPKI`` or a folder to make one in; ``sim_config``: a ``SimBackendConfig``; ``metrics``
    configures the judge."""
    from robots.spot.fake_spot.certs import TestPKI, make_test_pki
    from robots.spot.fake_spot.launch import EpisodeFake, start_serving
    from robots.spot.fake_spot.server import FakeSpot
    from robots.spot.fake_spot.sim_robot import FakeRobotSim
    from robots.spot.fake_spot.sim_view import FakeSimView, LockedJudge
    from robots.spot.sim_backend import SimBackendConfig

    if not isinstance(pki, TestPKI):
        pki = make_test_pki(pki)
    sim_config = sim_config or SimBackendConfig()
    world, scene, spot = build_episode_world(episode, sim_config)
    try:
        sim = FakeRobotSim(world, spot, sim_config)
        fake = FakeSpot(sim, pki, username, password, **fake_kwargs)
        view = FakeSimView(fake)
        judge = LockedJudge(EpisodeJudge(view, scene, episode, metrics or MetricsConfig()), fake.sim_lock)
    except Exception:
        world.close()
        raise
    start_serving(fake, world)
    return EpisodeFake(fake, pki, episode, scene, view, judge)


def run_fake_sdk_episode(agent_name: str, episode: Episode, seed: int | None = None, *,
                         config: RunnerConfig = RunnerConfig(), backend_config=None, sim_config=None,
                         pki=None, agent_options: dict | None = None,
                         on_connected: Callable | None = None, wrap_agent: Callable | None = None,
                         fake_options: dict | None = None) -> EpisodeResult:
    """Start a fake Spot on ``episode``'s scene, connect an SDK backend to it, run a fresh
    ``agent_name`` agent (``tasks.registry``) through ``tasks.runner.run_episode`` and score it.

    ``seed`` seeds the agent as ``tasks.trials`` does on the sim backend: its simulated perception
    (``RunContext.seed``) and the runner's generator alike (default: the episode's own seed).
    ``tools trials --seed S`` gives an episode the seed ``tasks.trial_config.episode_seed(S, id)``;
    pass that to run it as that trial ran (``tools spot --fake --episode`` does).

    ``backend_config``: an ``SdkBackendConfig`` whose timeouts and modes to use (host, port and
    CA are the fake's). ``pki``: a ``TestPKI`` or a folder to make one in (default: a throwaway
    one, removed afterwards). ``on_connected(backend)`` is called once the robot stands (the
    command line prints and records it there). ``agent_options`` go to the agent's factory (e.g.
    ``perception=(detector, scorer)``: real models instead of the simulated detector);
    ``wrap_agent(agent, ep)`` may wrap the agent (instrumentation, recording); ``fake_options`` go
    to ``FakeSpot`` (e.g. ``time_scale``). Always shuts the robot down, stops the fake and every
    thread it started, also after an error or Ctrl-C; where the shutdown could not stop the robot
    (the lease was not ours), ``result.extra["close_problem"]`` says so.
    """
    from robots.spot.fake_spot.launch import stop_fake
    from robots.spot.sdk_backend import SdkBackendConfig, SdkSpotBackend, credentials_from_env

    user, password = credentials_from_env()
    tmp = tempfile.mkdtemp(prefix="helios-fake-spot-") if pki is None else None
    pki = pki if pki is not None else tmp
    ep = None
    try:
        ep = start_episode_fake(pki, episode, user, password, sim_config=sim_config, metrics=config.metrics,
                                **(fake_options or {}))
        backend = SdkSpotBackend(replace(backend_config or SdkBackendConfig(), hostname="127.0.0.1",
                                         port=ep.port, cert_path=str(ep.pki.ca_cert)))
        try:
            if on_connected is not None:
                on_connected(backend)
            # ``seed`` seeds the agent's simulated perception and its generator, as ``tools trials`` seeds
            # an episode's agent (``tasks.trials``); None: the episode's own seed for both
            agent = make_agent(agent_name, RunContext.for_episode(ep, seed), **(agent_options or {}))
            if wrap_agent is not None:
                agent = wrap_agent(agent, ep)
            result = run_episode(agent, ep.backend.watch(backend), episode, config, ep.judge,
                                 start_time=time.time(), seed=seed)
            result.extra["collision_events"] = [asdict(e) for e in ep.backend.collision_events]
            result.extra["transport"] = "sdk-fake"
        finally:
            backend.close()
        if backend.close_problem:       # e.g. another client took the lease: the robot was not shut down
            result.extra["close_problem"] = backend.close_problem
        return result
    finally:
        stop_fake(ep, tmp)              # a further Ctrl-C/TERM/HUP is held until both are done
