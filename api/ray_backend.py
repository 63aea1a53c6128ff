"""API jobs on Ray (``GAINTUNE_BACKEND=ray``): the job workers run as Ray tasks instead of local processes.

Each of ``Settings.workers`` Ray tasks runs the ordinary worker loop (:func:`gaintune_api.worker.worker_main`)
against the job store: it claims a job (a lease with a fencing token), heartbeats it and writes its result
fenced by its claim, exactly as a local worker does. The durability promise is therefore the store's:

* an accepted job is a row in the store before the request is answered; a server kill loses nothing, and
  the tasks of a killed server die with it (Ray ends the tasks of a driver that is gone);
* a lost Ray worker (its process killed, its node gone) re-queues its job: on the server's own host the
  supervisor sees the process gone at once; on another host the job's lease (``heartbeat_timeout``)
  expires. Its replacement task is started by :meth:`RaySupervisor.respawn`. A lost attempt that comes
  back can write nothing: its claim token no longer matches.

The server joins the Ray cluster named by ``RAY_ADDRESS`` (``ray start --head`` on one machine, ``ray start
--address=HEAD:6379`` on the others); unset, Ray's default: a cluster running on this machine, else a new
one. Tasks on other machines need the job store on PostgreSQL (``GAINTUNE_DB_URL``) and ``GAINTUNE_DATA_DIR``
on a file system they share.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from typing import Any

from gaintune_api.settings import Settings
from gaintune_api.stores import Store
from gaintune_api.supervisor import Supervisor

__all__ = ["RaySupervisor", "ray_worker", "connect"]

log = logging.getLogger("gaintune.supervisor")


def ray_worker(settings_data: dict[str, Any], index: int) -> None:
    """The body of one Ray worker task: the job worker loop, until the task is cancelled or its process dies."""
    from gaintune_api.worker import worker_main

    worker_main(settings_data, index)


def connect() -> Any:
    """The ``ray`` module, connected: to ``RAY_ADDRESS``'s cluster, else a local Ray (ImportError: no Ray)."""
    import ray

    if not ray.is_initialized():
        # ray.init replaces SIGTERM's handler with sys.exit, which breaks the server's graceful shutdown
        # (uvicorn's handler): keep the handlers the process had.
        main = threading.current_thread() is threading.main_thread()
        saved = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)} if main else {}
        ray.init(address=os.environ.get("RAY_ADDRESS") or None, ignore_reinit_error=True, include_dashboard=False,
                 log_to_driver=False)
        for sig, handler in saved.items():
            signal.signal(sig, handler)
    return ray


class RaySupervisor(Supervisor):
    """Supervision of job workers that are Ray tasks (one CPU each), on any node of the cluster.

    The job checks (deadlines, dead workers on this host, expired leases) are the base class's; the
    local-process parts (pulses, frozen-process kills) have no Ray counterpart: a frozen task's job is
    recovered by its lease, and the fencing token stops the task's writes if it resumes.
    """

    def __init__(self, settings: Settings, store: Store) -> None:
        super().__init__(settings, store)
        self.ray = connect()
        self._remote = self.ray.remote(num_cpus=1, max_retries=0)(ray_worker)
        self.refs: list[Any] = [None] * settings.workers

    def _spawn(self, i: int) -> None:
        self.refs[i] = self._remote.options(name=f"gaintune-worker-{i}").remote(self.settings.model_dump(mode="json"),
                                                                                  i)
        log.info("started worker %d as a Ray task", i)

    def _done(self, i: int) -> bool:
        ref = self.refs[i]
        if ref is None:
            return True
        ready, _ = self.ray.wait([ref], timeout=0)
        return bool(ready)

    def worker_state(self, i: int) -> str:
        """``alive`` (the task runs, or waits for a CPU in the cluster) or ``dead`` (it ended)."""
        return "dead" if self._done(i) else "alive"

    def kill_frozen(self) -> None:
        """Nothing to do: a frozen Ray task's job is recovered when its lease expires."""

    def respawn(self) -> None:
        """Start a new task for every worker task that ended (its worker process died, or its node left)."""
        for i in range(len(self.refs)):
            if self.refs[i] is not None and self._done(i):
                try:
                    self.ray.get(self.refs[i])
                    why = "returned"
                except Exception as exc:  # noqa: BLE001 - any end of the task is logged and the task replaced
                    why = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
                log.warning("worker %d (Ray task) ended (%s); restarting", i, why)
                self.restarts += 1
                self._spawn(i)

    def stop(self, timeout: float = 5.0) -> None:
        """Cancel the worker tasks (their processes are killed; their jobs stay in the store)."""
        for ref in self.refs:
            if ref is not None:
                try:
                    self.ray.cancel(ref, force=True)
                except Exception:  # noqa: BLE001 - the task may be gone already
                    log.debug("cancel failed", exc_info=True)
        self.refs = [None] * len(self.refs)
