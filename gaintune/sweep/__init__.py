"""Fleet sweeps: tune (or query a trained tuner for) many problems in one go, locally or on Ray.

* :mod:`gaintune.sweep.fleet`: the fleet file (specs, or a base spec with a grid or cases) and
  its expansion into keyed items;
* :mod:`gaintune.sweep.runner`: :func:`run_sweep` (resumable: finished items are never run again);
* :mod:`gaintune.sweep.backends`: local worker processes, or one Ray task per item;
* :mod:`gaintune.sweep.store`: the results store (SQLite, or a folder of JSON files);
* :mod:`gaintune.sweep.worker`: one item in a worker process;
* :mod:`gaintune.sweep.summary`: the summary table and its CSV/Parquet export.

See docs/scale.md.
"""

from __future__ import annotations

from gaintune.sweep.fleet import Fleet, FleetError, Item, expand, load_fleet
from gaintune.sweep.runner import SweepOptions, SweepReport, run_sweep

__all__ = ["Fleet", "FleetError", "Item", "SweepOptions", "SweepReport", "expand", "load_fleet", "run_sweep"]
