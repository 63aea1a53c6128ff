"""The compute pool of the synchronous endpoints (gaintune_api.compute.ComputePool), without HTTP."""

from __future__ import annotations

import asyncio
import os
import signal
import time
from pathlib import Path

import pytest

from gaintune_api.compute import ComputePool

try:
    import uvloop
except ImportError:  # pragma: no cover - uvloop comes with uvicorn[standard]
    uvloop = None

#: The event loops the pool must work on: asyncio's own, and uvloop (uvicorn's choice when installed),
#: whose add_reader makes the descriptors it watches non-blocking.
LOOPS = ["asyncio", pytest.param("uvloop", marks=pytest.mark.skipif(uvloop is None, reason="needs uvloop"))]


def _run_on(loop: str, coro):
    return uvloop.run(coro) if loop == "uvloop" else asyncio.run(coro)


async def _warm(pool: ComputePool) -> list[int]:
    return list(await asyncio.wait_for(asyncio.gather(*(asyncio.wrap_future(f) for f in pool.warm)), 180))


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def _hold(marks: str, release: str) -> int:
    """In a pool worker: leave a mark in ``marks``, then wait until ``release`` exists (60 s at most); its pid."""
    Path(marks, f"{os.getpid()}-{time.monotonic_ns()}").touch()
    deadline = time.monotonic() + 60
    while not os.path.exists(release) and time.monotonic() < deadline:
        time.sleep(0.01)
    return os.getpid()


def _busy(pool: ComputePool) -> list:
    """The pool's workers computing a request now."""
    return [w for w in pool._workers if w.pending is not None and not w.pending.done()]


async def _until(condition, backstop: float = 60.0) -> None:
    """Poll ``condition`` until it holds (``backstop`` s at most: a failure, never a measure)."""
    deadline = time.monotonic() + backstop
    while not condition():
        assert time.monotonic() < deadline, "condition not reached"
        await asyncio.sleep(0.02)


@pytest.mark.parametrize("loop", LOOPS)
def test_pool_queues_recovers_and_shuts_down(loop: str, tmp_path):
    async def main():
        pool = ComputePool(2)
        pool.start()
        pids = await _warm(pool)
        assert sorted(pids) == pool.pids and os.getpid() not in pids
        # more requests than workers: queued, all answered, spread over both workers
        got = await asyncio.gather(*(pool.run(os.getpid) for _ in range(8)))
        assert set(got) <= set(pids) and len(got) == 8
        # two at a time: while both workers are held, the other two requests wait for a worker
        marks, release = tmp_path / "marks", tmp_path / "release"
        marks.mkdir()
        held = asyncio.gather(*(pool.run(_hold, str(marks), str(release)) for _ in range(4)))
        await _until(lambda: len(list(marks.iterdir())) == 2)
        assert len(pool._waiters) == 2 and len(list(marks.iterdir())) == 2
        release.touch()
        assert sorted(set(await held)) == pids and len(list(marks.iterdir())) == 4
        # a cancelled request frees its worker once the answer arrives
        task = asyncio.create_task(pool.run(time.sleep, 0.5))
        await _until(lambda: len(_busy(pool)) == 1)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert len(await asyncio.gather(*(pool.run(os.getpid) for _ in range(4)))) == 4
        # a worker killed while computing: its request gets None (the caller computes in a thread),
        # and a new worker takes its place
        task = asyncio.create_task(pool.run(time.sleep, 5))
        await _until(lambda: len(_busy(pool)) == 1)
        busy = _busy(pool)
        victim = busy[0].proc.pid
        os.kill(victim, signal.SIGKILL)
        assert await asyncio.wait_for(task, 10) is None
        assert pool.restarts == 1 and victim not in pool.pids and len(pool.pids) == 2
        assert pool.fallbacks == 1
        await _warm(pool)
        # a worker killed while idle is replaced too
        idle = pool.pids[0]
        os.kill(idle, signal.SIGKILL)
        for _ in range(100):
            if pool.restarts == 2:
                break
            await asyncio.sleep(0.05)
        assert pool.restarts == 2 and idle not in pool.pids
        await _warm(pool)
        assert set(await asyncio.gather(*(pool.run(os.getpid) for _ in range(6)))) <= set(pool.pids)
        final = pool.pids
        pool.shutdown()
        assert await pool.run(os.getpid) is None  # a shut-down pool computes nothing
        return final

    final = _run_on(loop, main())
    assert all(_gone(p) for p in final)  # joined: not even a zombie


def test_pool_verify_matches_in_process():
    from gaintune.spec import load_spec
    from gaintune.verification import verify
    from gaintune_api.compute import compute_verify

    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
                      "scenario": {"dt": 0.01}})
    gains = {"loop0": {"Kp": 1.14, "Ki": 0.454}}

    async def main():
        pool = ComputePool(1)
        pool.start()
        try:
            await _warm(pool)
            return await pool.run(compute_verify, spec, gains, None, True)
        finally:
            pool.shutdown()

    tag, data = asyncio.run(main())
    assert tag == "ok"
    from gaintune.verification.report import VerificationReport

    a = VerificationReport.model_validate_json(data)
    b = verify(spec, gains)
    assert a.loops == b.loops and a.verdict == b.verdict and a.stability == b.stability


def _identity(x):
    return x


def test_known_objects_are_sent_once_and_the_mirror_heals():
    """A spec (by its hash) crosses the pipe once per worker; a broken mirror is repaired."""
    from gaintune_api.compute import KNOWN_SIZE, _Ref

    async def main():
        pool = ComputePool(1)
        pool.start()
        try:
            await _warm(pool)
            w = pool._workers[0]
            big = list(range(1000))
            assert await pool.run(_identity, big, ref=(0, "k1")) == big
            assert list(w.known) == ["k1"]
            # the second time only the key travels, and the worker returns its stored object
            assert await pool.run(_identity, ["ignored"], ref=(0, "k1")) == big
            for k in range(KNOWN_SIZE + 3):
                assert await pool.run(_identity, k, ref=(0, f"x{k}")) == k
            assert len(w.known) == KNOWN_SIZE and "k1" not in w.known
            assert await pool.run(_identity, "fresh", ref=(0, "k1")) == "fresh"  # evicted: sent again
            # break the mirror: the server believes the worker knows "ghost"
            w.known["ghost"] = None
            assert await pool.run(_identity, "v", ref=(0, "ghost")) is None  # KeyError in the worker -> None
            assert "ghost" not in w.known and pool.fallbacks == 1 and pool.restarts == 0
            assert await pool.run(_identity, "v", ref=(0, "ghost")) == "v"
            assert isinstance(_Ref("a"), _Ref)
        finally:
            pool.shutdown()

    asyncio.run(main())


def _nested(x):
    return lambda: x  # an answer pickle cannot carry


@pytest.mark.parametrize("loop", LOOPS)
def test_pool_carries_messages_of_any_size_without_respawn(loop: str):
    """Under uvloop, an answer larger than a socket buffer used to raise BlockingIOError in the server,
    which took it for a dead worker: respawn, and the request computed in a thread."""

    async def main():
        pool = ComputePool(1)
        pool.start()
        try:
            await _warm(pool)
            for size in (10, 100_000, 1_500_000, 8_000_000):
                big = os.urandom(size)
                assert await pool.run(_identity, big) == big  # as large a request as an answer
            assert await pool.run(_identity, b"x" * 3_000_000, ref=(0, "big")) == b"x" * 3_000_000
            assert await pool.run(_identity, None, ref=(0, "big")) == b"x" * 3_000_000  # sent once, by key now
            return pool.restarts, pool.fallbacks
        finally:
            pool.shutdown()

    assert _run_on(loop, main()) == (0, 0)


def test_unpicklable_request_or_answer_falls_back_without_respawn():
    """Neither leaks the worker (it serves the next request) nor respawns it; both are counted as fallbacks."""

    async def main():
        pool = ComputePool(1)
        pool.start()
        try:
            await _warm(pool)
            assert await pool.run(_identity, lambda: 0) is None  # not sent: the request cannot be pickled
            assert await pool.run(_nested, 1) is None  # sent, but the worker cannot pickle the answer
            assert await pool.run(_identity, 7) == 7
            return pool.restarts, pool.fallbacks
        finally:
            pool.shutdown()

    assert asyncio.run(main()) == (0, 2)
