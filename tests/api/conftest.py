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


# ------------------------------------------------------------- PostgreSQL: the store's tests run on both backends


@pytest.fixture(scope="session")
def pg_server():
    """A throwaway PostgreSQL for the session (or GAINTUNE_TEST_PG_URL's). In CI its absence fails, never skips."""
    import os

    from pg_cluster import no_postgres_reason, start_cluster

    why = no_postgres_reason()
    if why is not None:
        if os.environ.get("CI"):
            pytest.fail(f"CI must run the PostgreSQL tests, but {why}", pytrace=False)
        pytest.skip(f"no PostgreSQL: {why}")
    cluster = start_cluster()
    yield cluster
    cluster.stop()


@pytest.fixture
def pg_url(pg_server):
    """The URL of a fresh, empty database on :func:`pg_server` (dropped afterwards)."""
    url = pg_server.new_database()
    yield url
    pg_server.drop_database(url)


@pytest.fixture(params=["sqlite", "postgresql"])
def db_settings(request, tmp_path) -> dict:
    """Settings keywords selecting each job store in turn: SQLite in ``tmp_path``, then a PostgreSQL database."""
    if request.param == "sqlite":
        return {}
    return {"db_url": request.getfixturevalue("pg_url")}
