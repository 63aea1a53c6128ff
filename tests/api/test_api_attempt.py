"""The job attempt's monitor (gaintune_api.attempt.Attempt) on its own, with a recording stand-in store."""

from __future__ import annotations

import threading
from types import SimpleNamespace

from test_api_routes import BACKSTOP, settings_for

from gaintune_api.attempt import Attempt


class _Store:
    """Answers every heartbeat with (owned, cancel requested) and records final writes."""

    def __init__(self, owned: bool = True, cancel: bool = False) -> None:
        self.beat = (owned, cancel)
        self.finished: list[tuple[str, str | None]] = []

    def heartbeat(self, job_id, claim, progress):
        return self.beat

    def finish(self, job_id, claim, status, *, error=None, **kw):
        self.finished.append((status, error))
        return status


def _attempt(tmp_path, store: _Store, **kw) -> Attempt:
    settings = settings_for(tmp_path, heartbeat_interval=0.01, **kw)
    return Attempt(store, SimpleNamespace(id="job-1", attempts=1), "claim", settings, hard_exit=False)


def test_attempt_first_stop_reason_wins(tmp_path):
    """A cancel request, then a lost claim: the attempt stays cancelled (its final state names the first reason)."""
    a = _attempt(tmp_path, _Store())
    a._check(True, True)
    a._check(False, False)
    assert a.reason == "cancelled" and a.cancel.is_set()


def test_attempt_monitor_writes_cancelled_when_the_search_ignores_the_cancel(tmp_path):
    """The search never returns (``done`` is never set): the monitor writes the final state itself and stops."""
    store = _Store(cancel=True)
    a = _attempt(tmp_path, store, cancel_grace=0.05)
    th = threading.Thread(target=a.watch, daemon=True)
    th.start()
    th.join(BACKSTOP)
    assert not th.is_alive() and a.reason == "cancelled"
    assert len(store.finished) == 1
    status, error = store.finished[0]
    assert status == "cancelled" and "did not stop within 0.05 s" in error


def test_attempt_monitor_writes_nothing_for_a_lost_claim(tmp_path):
    """Another attempt owns the job now: the stuck search's monitor gives up without writing."""
    store = _Store(owned=False)
    a = _attempt(tmp_path, store, cancel_grace=0.05)
    th = threading.Thread(target=a.watch, daemon=True)
    th.start()
    th.join(BACKSTOP)
    assert not th.is_alive() and a.reason == "lost" and store.finished == []
