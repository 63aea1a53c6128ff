"""API test set-up: compile the simulator's kernels once before any server starts.

On a fresh clone numba's on-disk cache is empty, and the first job of the first server
test would otherwise compile every kernel variant inside a worker process (minutes of CPU
on a loaded 2-core runner), racing the tests' job deadlines. Compiling here, in the test
process, writes the cache that the server's worker processes then load.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_api_routes import client, make_client  # noqa: F401 - the in-process app fixtures, for every api test file


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels() -> None:
    from gaintune.controllers.layout import GainLayout
    from gaintune.plants import build_plant
    from gaintune.sim import Simulator
    from gaintune.spec import load_spec

    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^2"}}, "loops": [{"type": "pi"}],
                      "scenario": {"dt": 0.05, "horizon": 1.0}})
    plant = build_plant(spec.plant)
    sim = Simulator(spec, plant, GainLayout(spec, plant.states, plant=plant))
    for batch in (1, 7, 129):  # the single-lane, serial (one chunk) and parallel variants
        sim.run(np.tile(sim.layout.full(sim.layout.initial_tuned()), (batch, 1)))
