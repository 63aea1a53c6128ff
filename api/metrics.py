"""Prometheus text exposition, written by hand (no client library needed)."""

from __future__ import annotations

import threading
from collections import defaultdict
from typing import Protocol

__all__ = ["Metrics", "BUCKETS", "ComputeCounters"]

#: Latency histogram bucket upper bounds in seconds.
BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)


def _esc(v: str) -> str:
    return v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")


class ComputeCounters(Protocol):
    """What :class:`Metrics` reads of the compute pool (``gaintune_api.compute.ComputePool``)."""

    restarts: int
    fallbacks: int


class Metrics:
    """Request-latency histograms keyed by (method, route, status), and the compute pool's counters.

    ``compute``: the running compute pool, set by the app at start-up (None: no pool, counters 0).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._hist: dict[tuple[str, str, str], list[float]] = defaultdict(lambda: [0.0] * (len(BUCKETS) + 2))
        self.compute: ComputeCounters | None = None

    def observe(self, method: str, route: str, status: int, seconds: float) -> None:
        """Count one request of ``route`` in the latency histogram."""
        key = (method, route, str(status))
        with self._lock:
            h = self._hist[key]
            for i, b in enumerate(BUCKETS):
                if seconds <= b:
                    h[i] += 1
            h[-2] += seconds  # sum
            h[-1] += 1  # count

    def render(self, jobs: dict[str, int], queue_depth: int, workers_alive: int, workers_configured: int,
               worker_restarts: int, *, workers_unresponsive: int = 0, frozen_kills: int = 0,
               database_writable: bool | None = None) -> str:
        """The Prometheus text of the job gauges given and the request histograms."""
        out: list[str] = []
        out += ["# HELP gaintune_jobs Jobs in the store by state.", "# TYPE gaintune_jobs gauge"]
        out += [f'gaintune_jobs{{state="{s}"}} {n}' for s, n in sorted(jobs.items())]
        out += ["# HELP gaintune_queue_depth Jobs waiting for a worker.", "# TYPE gaintune_queue_depth gauge",
                f"gaintune_queue_depth {queue_depth}"]
        out += ["# HELP gaintune_workers_alive Job worker processes alive in this server.",
                "# TYPE gaintune_workers_alive gauge", f"gaintune_workers_alive {workers_alive}"]
        out += ["# HELP gaintune_workers_configured Job worker processes configured.",
                "# TYPE gaintune_workers_configured gauge", f"gaintune_workers_configured {workers_configured}"]
        out += ["# HELP gaintune_worker_restarts_total Worker processes restarted after dying.",
                "# TYPE gaintune_worker_restarts_total counter", f"gaintune_worker_restarts_total {worker_restarts}"]
        out += ["# HELP gaintune_workers_unresponsive "
                "Worker processes alive by PID but without a fresh pulse (frozen).",
                "# TYPE gaintune_workers_unresponsive gauge",
                f"gaintune_workers_unresponsive {workers_unresponsive}"]
        out += ["# HELP gaintune_worker_frozen_kills_total Workers killed because their pulse stopped (frozen).",
                "# TYPE gaintune_worker_frozen_kills_total counter",
                f"gaintune_worker_frozen_kills_total {frozen_kills}"]
        if database_writable is not None:
            out += ["# HELP gaintune_database_writable 1 when the supervisor's last write probe of the job database "
                    "committed.", "# TYPE gaintune_database_writable gauge",
                    f"gaintune_database_writable {int(database_writable)}"]
        pool = self.compute
        out += ["# HELP gaintune_compute_restarts_total Compute pool worker processes respawned (a worker died or "
                "its pipe broke).", "# TYPE gaintune_compute_restarts_total counter",
                f"gaintune_compute_restarts_total {pool.restarts if pool else 0}"]
        out += ["# HELP gaintune_compute_fallbacks_total Synchronous requests computed in a server thread because "
                "their compute worker died or failed.", "# TYPE gaintune_compute_fallbacks_total counter",
                f"gaintune_compute_fallbacks_total {pool.fallbacks if pool else 0}"]
        name = "gaintune_http_request_duration_seconds"
        out += [f"# HELP {name} HTTP request latency.", f"# TYPE {name} histogram"]
        with self._lock:
            items = sorted((k, list(v)) for k, v in self._hist.items())
        for (method, route, status), h in items:
            lbl = f'method="{_esc(method)}",route="{_esc(route)}",status="{status}"'
            for i, b in enumerate(BUCKETS):
                out.append(f'{name}_bucket{{{lbl},le="{b:g}"}} {h[i]:g}')
            out.append(f'{name}_bucket{{{lbl},le="+Inf"}} {h[-1]:g}')
            out.append(f"{name}_sum{{{lbl}}} {h[-2]:.6f}")
            out.append(f"{name}_count{{{lbl}}} {h[-1]:g}")
        return "\n".join(out) + "\n"
