"""``gaintune tuner schedule``: a tuner's gain schedule, verified, exported, and optionally compared with one fixed PI.

:func:`run_schedule` builds the schedule (:func:`gaintune.tuners.scheduling.schedule_from_tuner`),
verifies it at every grid point and midpoint and over the nonlinear sweep
(:func:`gaintune.tuners.schedule.verify_schedule`), writes ``schedule.json`` and the exports
(:func:`gaintune.export.schedule.write_schedule_exports`: the C header and MATLAB file only for a
passed schedule) into ``--out``, and prints a table (or JSON). ``--compare`` adds the best single fixed
PI over the same levels (:func:`~gaintune.tuners.schedule.best_fixed_pi`) and the level-step IAE of
both (:func:`~gaintune.tuners.schedule.compare_fixed`). Exit 3 when the schedule fails verification.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from gaintune.cli.common import EXIT_VERIFY, InputError, _f, _json_num, err, out

if TYPE_CHECKING:  # pragma: no cover
    from gaintune.tuners.schedule import GainSchedule, ScheduleComparison, ScheduleVerification
    from gaintune.tuners.tuner import Tuner

__all__ = ["run_schedule"]


def _write(schedule: GainSchedule, check: ScheduleVerification, out_dir: Path) -> dict[str, Any]:
    """schedule.json and the exports into ``out_dir``: what was written, withheld and removed."""
    from gaintune.export.schedule import write_schedule_exports
    from gaintune.files import write_atomic
    from gaintune.tuners.schedule import schedule_table

    out_dir.mkdir(parents=True, exist_ok=True)
    write_atomic(out_dir / "schedule.json", schedule.to_json())
    files = write_schedule_exports(schedule_table(schedule, "pass" if check.passed else "fail", check.reasons), out_dir)
    return {"written": [str(out_dir / "schedule.json"), *map(str, files)], "withheld": list(files.withheld),
            "removed": [str(p) for p in files.removed]}


def _comparison(schedule: GainSchedule) -> tuple[Any, ScheduleComparison]:
    from gaintune.tuners.schedule import best_fixed_pi, compare_fixed

    fixed = best_fixed_pi(schedule)
    return fixed, compare_fixed(schedule, fixed.gains)


def _print_points(schedule: GainSchedule, check: ScheduleVerification, notes: list[str]) -> None:
    from rich.table import Table

    names = list(schedule.gains[0])
    table = Table(title=f"Gain schedule of loop {schedule.loop!r} over {schedule.var} ({schedule.method})")
    for col in (schedule.var, "kind", *names, "verdict", "reason"):
        table.add_column(col, justify="left" if col in ("kind", "verdict", "reason") else "right")
    for p in check.points:
        table.add_row(_f(p.value), p.kind, *(_f(p.gains.get(g)) for g in names),
                      "PASS" if p.verdict == "pass" else "FAIL", p.reasons[0] if p.reasons else "")
    out.print(table)
    for note in notes:
        out.print(f"fit: {note}", markup=False, highlight=False, soft_wrap=True)
    out.print(check.summary(), markup=False, highlight=False, soft_wrap=True)
    for r in check.reasons:
        out.print(f"  {r}", markup=False, highlight=False, soft_wrap=True)


def _print_comparison(fixed: Any, cmp: ScheduleComparison) -> None:
    from rich.table import Table

    gains = ", ".join(f"{k} = {_f(v)}" for k, v in cmp.fixed_gains.items())
    table = Table(title=f"Level step, scheduled vs the best single fixed PI ({gains})")
    for col in (cmp.var, "kind", "IAE scheduled", "IAE fixed PI", "ratio"):
        table.add_column(col, justify="left" if col == "kind" else "right")
    for lv in cmp.levels:
        table.add_row(_f(lv.level), lv.kind, _f(lv.iae_scheduled), _f(lv.iae_fixed), _f(lv.ratio))
    out.print(table)
    out.print(f"{cmp.step}. Scheduled better at every level: {'yes' if cmp.better_everywhere else 'no'}. "
              f"Fixed PI: {fixed.definition}.", markup=False, highlight=False, soft_wrap=True)


def _as_json(schedule: GainSchedule, check: ScheduleVerification, notes: list[str], files: dict[str, Any] | None,
             compared: tuple[Any, ScheduleComparison] | None) -> dict[str, Any]:
    doc: dict[str, Any] = {
        "schedule": json.loads(schedule.to_json()), "fit_notes": notes,
        "verification": json.loads(check.model_dump_json()), "passed": check.passed, "files": files,
        "comparison": None,
    }
    if compared is not None:
        fixed, cmp = compared
        doc["comparison"] = {"fixed": json.loads(fixed.model_dump_json()), "step": cmp.step,
                             "better_everywhere": cmp.better_everywhere,
                             "levels": [{**lv.model_dump(), "ratio": _json_num(lv.ratio)} for lv in cmp.levels]}
    return doc


def run_schedule(tuner: Tuner, var: str, grid: list[float], out_dir: Path | None, *, json_out: bool,
                 compare: bool) -> None:
    """Build, fit, verify, write and show ``tuner``'s schedule over ``grid`` of ``var``; exit 3 when it fails."""
    from gaintune.tuners.schedule import require_nonlinear, verify_schedule
    from gaintune.tuners.scheduling import schedule_from_tuner
    from gaintune.tuners.tuner import OutsideFamilyError

    try:
        _, schedule, notes = schedule_from_tuner(tuner, var, grid)
    except OutsideFamilyError as exc:
        raise InputError(exc.field, exc.message) from None
    if compare:  # refused before anything is verified or written: the comparison steps a nonlinear plant only
        require_nonlinear(schedule.tuning_spec)
    check = verify_schedule(schedule)
    files = _write(schedule, check, out_dir) if out_dir is not None else None
    compared = _comparison(schedule) if compare else None
    if json_out:
        print(json.dumps(_as_json(schedule, check, notes, files, compared), indent=2))
    else:
        _print_points(schedule, check, notes)
        if compared is not None:
            _print_comparison(*compared)
        if files is not None:
            for p in files["written"]:
                out.print(f"wrote {p}", markup=False, highlight=False, soft_wrap=True)
            if files["withheld"]:
                out.print(f"withheld {', '.join(files['withheld'])}: the schedule did not pass", markup=False)
        else:
            err.print("note: give --out DIR to write schedule.json and the exports", markup=False)
    if not check.passed:
        raise typer.Exit(EXIT_VERIFY)
