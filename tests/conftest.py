"""Shared pytest setup: one native thread per process (see helios.runtime) and sim fixtures."""

from __future__ import annotations

import numpy as np
import pytest

from helios.runtime import configure_threads

configure_threads(1)


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
