"""Gain schedules: one loop's gains over a grid of a scheduling variable, verified between the grid points too.

For a nonlinear plant the scheduling variable is the context of the design: the water tank's
operating level ``H0``, a speed, a load. The pieces, each a plain function the CLI calls:

* :mod:`~gaintune.tuners.schedule.table`: :class:`GainSchedule` (versioned JSON),
  :func:`parse_grid`, :func:`build_schedule` (gains per grid point from any ``gains_at``),
  :func:`gains_between` (linear interpolation, clamped), :func:`schedule_table` (the plain data
  the exports take, :mod:`gaintune.export.schedule`);
* :mod:`~gaintune.tuners.schedule.law`: the scheduled PID law in Python, the twin of the C header;
* :mod:`~gaintune.tuners.schedule.sweep`: closed-loop runs of the scheduled controller on the
  nonlinear plant, and the sweep over the operating range;
* :mod:`~gaintune.tuners.schedule.check`: :func:`verify_schedule` (frozen-parameter verification
  at every grid point and midpoint, and the sweep);
* :mod:`~gaintune.tuners.schedule.fit`: :func:`fit_midpoints` (scale the gains next to a failing
  midpoint until the interpolated gains pass there);
* :mod:`~gaintune.tuners.schedule.compare`: the best single fixed PI over the range
  (:func:`best_fixed_pi`) and the level-step comparison (:func:`compare_fixed`), of a nonlinear plant only
  (:func:`require_nonlinear`).
"""

from gaintune.tuners.schedule.check import PointCheck, ScheduleVerification, verify_schedule
from gaintune.tuners.schedule.compare import (
    FixedDesign,
    LevelComparison,
    ScheduleComparison,
    best_fixed_pi,
    cma_gains_at,
    compare_fixed,
    grid_and_midpoints,
    require_nonlinear,
)
from gaintune.tuners.schedule.fit import fit_midpoints
from gaintune.tuners.schedule.law import ScheduledPid, interp
from gaintune.tuners.schedule.sweep import ScheduleModel, SweepReport, nonlinear_sweep
from gaintune.tuners.schedule.table import (
    SCHEDULE_VERSION,
    GainSchedule,
    build_schedule,
    gains_between,
    load_schedule,
    parse_grid,
    schedule_table,
    spec_at,
)

__all__ = [
    "SCHEDULE_VERSION", "GainSchedule", "build_schedule", "gains_between", "load_schedule", "parse_grid",
    "schedule_table", "spec_at", "ScheduledPid", "interp", "ScheduleModel", "SweepReport", "nonlinear_sweep",
    "PointCheck", "ScheduleVerification", "verify_schedule", "FixedDesign", "LevelComparison",
    "ScheduleComparison", "best_fixed_pi", "cma_gains_at", "compare_fixed", "grid_and_midpoints", "fit_midpoints",
    "require_nonlinear",
]
