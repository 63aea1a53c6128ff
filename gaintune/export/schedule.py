"""Gain-schedule exports: a C header with the gain tables and their interpolation, a MATLAB/Octave file, JSON.

The input is plain data, a :class:`ScheduleTable`: the breakpoints of the scheduling
variable, the loop's parallel-form gains at each breakpoint, the integrator start
(operating input) at each, and the loop's settings. (The tuners layer builds it from
a gain schedule; this module knows nothing of how the gains were found.)

The scheduled law, identical in every format and in its Python twin
(:mod:`gaintune.tuners.schedule.law`), at every sample with scheduling value ``x``:

1. each gain ``g`` in ``Kp, Ki, Kd`` is the linear interpolation of its table over the
   breakpoints, clamped at the ends: ``g(x) = t[0]`` for ``x <= x[0]`` (and for NaN),
   ``t[n-1]`` for ``x >= x[n-1]``, else with ``x[i] <= x < x[i+1]`` and
   ``w = (x - x[i])/(x[i+1] - x[i])``: ``g = t[i] + w*(t[i+1] - t[i])`` (exact at every breakpoint);
2. the derivative filter and the back-calculation gain follow from those gains as in
   :func:`gaintune.controllers.pid.pid_params` (``Tf = Kd/(N Kp)`` or the fixed ``Tf``;
   ``1/Tt`` with ``Tt = sqrt(Ti Td)``, ``Ti`` or the fixed tracking time);
3. one step of the simulator's discrete PID law (:mod:`gaintune.export.c`: backward-Euler
   integral ``I += Ki*dt*e``, filtered derivative, saturation, anti-windup) with those
   coefficients, then the actuator rate limit.

The integrator carries over from one sample to the next, so a change of gains moves the
output by ``dKp*(b*r - y)`` only (no integrator bump). ``reset`` starts the integrator at
the interpolated operating input ``i0(x0)``.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from gaintune.export import ExportFiles, _clean
from gaintune.export.c import AW_CODE, _c_comment, _c_num, _c_str, pid_coef_typedef, pid_step, state_typedef
from gaintune.export.common import ExportError, _check_dt, _ident, _one_line, _version
from gaintune.export.matlab import _m_num, _m_str, _m_vec
from gaintune.export.verdict import _Stamp
from gaintune.files import write_atomic

__all__ = ["ScheduleTable", "SCHEDULE_FORMATS", "SCHEDULE_SUFFIX", "EXPORT_VERSION", "schedule_to_c",
           "schedule_to_matlab", "schedule_to_json", "render_schedule", "write_schedule_exports"]

#: Formats of a gain schedule and the file each is written to.
SCHEDULE_FORMATS: tuple[str, ...] = ("json", "c", "matlab")
SCHEDULE_SUFFIX: dict[str, str] = {"json": "schedule_gains.json", "c": "schedule_gains.h",
                                   "matlab": "schedule_gains.m"}
#: Version of the JSON export's layout.
EXPORT_VERSION = 1
#: Most breakpoints a table may have (the C lookup scans them linearly).
MAX_BREAKPOINTS = 1000


@dataclass(frozen=True)
class ScheduleTable:
    """A gain schedule of one PID loop as plain data: breakpoints, gain tables and the loop's settings.

    Attributes
    ----------
    name, spec_hash
        The spec's name and content hash (provenance).
    var
        The scheduling variable (a plant parameter, e.g. ``H0``).
    schedule_on
        What the controller passes as ``x``: ``measurement`` (the loop's measured output, when ``var`` is its
        operating level) or ``parameter`` (a measured value of ``var`` itself).
    loop, measure, type
        The loop's name, the output it measures and its type (``p``, ``pi``, ``pd``, ``pid``).
    grid
        Breakpoints of ``var``, strictly increasing.
    kp, ki, kd
        Parallel-form gains at each breakpoint (zeros for a term the type has not).
    i0
        Integrator start at each breakpoint: the operating input there (bumpless start).
    dt
        Sample time (s).
    b, c, aw, N, Tf, tracking_time
        Setpoint weights, anti-windup mode, derivative filter (``Tf = Kd/(N Kp)`` unless ``Tf`` is fixed) and the
        back-calculation tracking time (None: ``sqrt(Ti Td)`` or ``Ti``).
    lo, hi, rate_limit
        Actuator limits and rate limit (None: none).
    verdict, reasons
        The schedule's verification verdict at ``dt`` (None: not verified) and why it failed.
    """

    name: str
    var: str
    loop: str
    measure: str
    type: str
    grid: tuple[float, ...]
    kp: tuple[float, ...]
    ki: tuple[float, ...]
    kd: tuple[float, ...]
    i0: tuple[float, ...]
    dt: float
    b: float = 1.0
    c: float = 0.0
    aw: str = "clamping"
    N: float = 10.0
    Tf: float | None = None
    tracking_time: float | None = None
    lo: float = -math.inf
    hi: float = math.inf
    rate_limit: float | None = None
    schedule_on: str = "measurement"
    verdict: str | None = None
    reasons: tuple[str, ...] = ()
    spec_hash: str = ""
    generator: str = field(default_factory=lambda: f"gaintune {_version()}")

    def __post_init__(self) -> None:
        if self.type not in ("p", "pi", "pd", "pid"):
            raise ExportError("type", f"a gain schedule is for a PID loop (p, pi, pd, pid), got {self.type!r}")
        if self.aw not in AW_CODE:
            raise ExportError("aw", f"anti-windup must be one of {', '.join(AW_CODE)}, got {self.aw!r}")
        if self.schedule_on not in ("measurement", "parameter"):
            raise ExportError("schedule_on", f"must be 'measurement' or 'parameter', got {self.schedule_on!r}")
        _check_dt(self.dt)
        _check_grid(self.grid)
        for name in ("kp", "ki", "kd", "i0"):
            values = getattr(self, name)
            if len(values) != len(self.grid):
                raise ExportError(name, f"has {len(values)} entries for {len(self.grid)} breakpoints; give one each")
            if not all(math.isfinite(v) for v in values):
                raise ExportError(name, "every entry must be a finite number")
        if not self.lo < self.hi:
            raise ExportError("lo", f"actuator limits must satisfy lo < hi, got [{self.lo}, {self.hi}]")

    @property
    def has_i(self) -> bool:
        """The loop has an integral term."""
        return "i" in self.type[1:]

    @property
    def has_d(self) -> bool:
        """The loop has a derivative term."""
        return "d" in self.type[1:]

    def to_dict(self) -> dict[str, Any]:
        """The table as JSON-safe data (``inf`` as the string "inf")."""
        return _clean(asdict(self))


def _check_grid(grid: tuple[float, ...]) -> None:
    """ExportError (field ``grid``) unless the breakpoints are 2 .. MAX_BREAKPOINTS finite, increasing numbers."""
    if not 2 <= len(grid) <= MAX_BREAKPOINTS:
        raise ExportError("grid", f"needs 2 to {MAX_BREAKPOINTS} breakpoints, got {len(grid)}")
    if not all(math.isfinite(v) for v in grid):
        raise ExportError("grid", "every breakpoint must be a finite number")
    if any(b <= a for a, b in zip(grid, grid[1:], strict=False)):
        raise ExportError("grid", f"breakpoints must be strictly increasing, got {list(grid)}")


def _stamp(t: ScheduleTable) -> _Stamp:
    return _Stamp(t.verdict, t.dt, t.dt if t.verdict is not None else None, list(t.reasons))


# ------------------------------------------------------------------------------------------------- C


def schedule_to_c(t: ScheduleTable, prefix: str = "gt") -> str:
    """A self-contained C99 header: the tables, ``<p>_sched_gains``, ``<p>_reset`` and ``<p>_step``.

    Usage: ``<p>_state s; <p>_reset(&s, x0);`` then every ``dt``: ``u = <p>_step(&s, r, y, x);``
    where ``x`` is the scheduling value (the measured output itself when ``schedule_on`` is
    ``measurement``). See the module docstring for the law.
    """
    if not isinstance(prefix, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", prefix):
        raise ExportError("prefix",
                          f"must be a C identifier (letters, digits, _; not starting with a digit), got {prefix!r}")
    P, U = prefix.lower(), prefix.upper()
    guard = f"{U}_{_ident(t.name).upper()}_SCHEDULE_H"
    lines = [*_c_banner(t, P, U), f"#ifndef {guard}", f"#define {guard}", "", "#include <math.h>", "",
             *_c_macros(t, U), "", *pid_coef_typedef(P), "", *state_typedef(P, 1, 1), "",
             *_c_lookup(t, P, U), *_c_reset(P, U), *pid_step(P, U), *_c_step(P, U), f"#endif /* {guard} */", ""]
    return "\n".join(lines)


def _c_banner(t: ScheduleTable, P: str, U: str) -> list[str]:
    """The leading comment: origin, verdict, the scheduling variable and how to call the header."""
    x_is = ("the loop's measurement y (x = y)" if t.schedule_on == "measurement"
            else f"the measured value of {_c_comment(t.var)}")
    return [
        f"/* Gain schedule of loop '{_c_comment(t.loop)}' for spec '{_c_comment(t.name)}' "
        f"(hash {t.spec_hash[:12]}), generated by {_c_comment(t.generator)}.",
        f" * {_c_comment(_stamp(t).banner())}",
        f" * {U}_VERIFIED is 1 only when the schedule passed verification (grid points, midpoints, sweep) at {U}_DT.",
        f" * Scheduling variable x = {_c_comment(t.var)}: pass {x_is}.",
        " * Gains: linear interpolation of the tables over the breakpoints, clamped at the ends (NaN: first).",
        " * Discrete-time law per sample (backward Euler, identical to gaintune's simulator):",
        " *   P = Kp*(b*sp - y);  I += Ki*dt*(sp - y);  D = Tf/(Tf+dt)*D + Kd/(Tf+dt)*(ed - ed_prev), ed = c*sp - y;",
        " *   v = sat(P + I + D) with the anti-windup; then the actuator rate limit.",
        f" * Usage:  {P}_state s; {P}_reset(&s, x0);  every dt: u = {P}_step(&s, r, y, x);",
        " * Compile without -ffast-math (and without FMA contraction) to reproduce the simulator bit for bit.",
        " */",
    ]


def _c_table(name: str, values: tuple[float, ...]) -> str:
    return f"static const double {name}[{len(values)}] = {{" + ", ".join(_c_num(v) for v in values) + "};"


def _c_macros(t: ScheduleTable, U: str) -> list[str]:
    """Sample time, verdict, actuator and loop settings, and the tables."""
    st = _stamp(t)
    rate = t.rate_limit
    return [
        f"#define {U}_DT {_c_num(t.dt)}",
        f"#define {U}_N_GRID {len(t.grid)}",
        f"#define {U}_VERIFIED {1 if st.accepted else 0}",
        f"#define {U}_VERDICT {_c_str(st.label)}",
        f"#define {U}_VERDICT_REASON {_c_str(st.reason if st.verdict == 'fail' else '')}",
        f"#define {U}_SCHED_VAR {_c_str(t.var)}",
        f"#define {U}_U_MIN {_c_num(t.lo)}",
        f"#define {U}_U_MAX {_c_num(t.hi)}",
        f"#define {U}_RATE_LIMIT {_c_num(rate) if rate is not None else 'INFINITY'}",
        f"#define {U}_AW_NONE 0",
        f"#define {U}_AW_CLAMP 1",
        f"#define {U}_AW_BACKCALC 2",
        "",
        f"/* Breakpoints of {_c_comment(t.var)} and the parallel-form gains at each (loop {_c_comment(t.loop)}). */",
        _c_table(f"{U}_GRID", t.grid),
        _c_table(f"{U}_KP", t.kp),
        _c_table(f"{U}_KI", t.ki),
        _c_table(f"{U}_KD", t.kd),
        "/* Integrator start (operating input) at each breakpoint. */",
        _c_table(f"{U}_I0", t.i0),
    ]


def _c_filter(t: ScheduleTable) -> str:
    """The C expression of the derivative filter time from the interpolated ``kp``, ``kd`` (as pid_params)."""
    if not t.has_d:
        return "0.0"
    if t.Tf is not None:
        return f"kd != 0.0 ? {_c_num(t.Tf)} : 0.0"
    return f"kd * kp > 0.0 ? kd / ({_c_num(t.N)} * kp) : 0.0"


def _c_backcalc(t: ScheduleTable) -> list[str]:
    """C statements setting ``kb`` = 1/Tt from the interpolated gains (as pid_params)."""
    if t.aw != "back_calculation" or not t.has_i:
        return ["    kb = 0.0;"]
    if t.tracking_time is not None:
        return [f"    kb = 1.0 / {_c_num(t.tracking_time)};"]
    return [
        "    {",
        "        double ti = ki * kp > 0.0 ? kp / ki : 1.0, td = kd * kp > 0.0 ? kd / kp : 0.0;",
        "        kb = 1.0 / (td > 0.0 ? sqrt(ti * td) : ti);  /* Tt = sqrt(Ti Td), or Ti without Td */",
        "    }",
    ]


def _c_lookup(t: ScheduleTable, P: str, U: str) -> list[str]:
    """``<p>_sched_interp``, ``<p>_sched_gains`` and ``<p>_sched_coef`` (the coefficients at x)."""
    return [
        "/* Clamped linear interpolation of table t over the breakpoints (exact at every breakpoint). */",
        f"static inline double {P}_sched_interp(const double *t, double x)",
        "{",
        "    int i = 0;",
        "    double w;",
        f"    if (!(x > {U}_GRID[0])) return t[0];  /* also NaN */",
        f"    if (x >= {U}_GRID[{U}_N_GRID - 1]) return t[{U}_N_GRID - 1];",
        f"    while (x >= {U}_GRID[i + 1]) ++i;",
        f"    w = (x - {U}_GRID[i]) / ({U}_GRID[i + 1] - {U}_GRID[i]);",
        "    return t[i] + w * (t[i + 1] - t[i]);",
        "}",
        "",
        "/* The scheduled parallel-form gains at x. */",
        f"static inline void {P}_sched_gains(double x, double *kp, double *ki, double *kd)",
        "{",
        f"    *kp = {P}_sched_interp({U}_KP, x);",
        f"    *ki = {P}_sched_interp({U}_KI, x);",
        f"    *kd = {P}_sched_interp({U}_KD, x);",
        "}",
        "",
        "/* The per-step coefficients at x: gains, derivative filter, back-calculation, limits. */",
        f"static inline void {P}_sched_coef(double x, {P}_pid_coef *c)",
        "{",
        "    double kp, ki, kd, tf, kb;",
        f"    {P}_sched_gains(x, &kp, &ki, &kd);",
        f"    tf = {_c_filter(t)};",
        *_c_backcalc(t),
        "    c->kp = kp; c->ki = ki; c->kd = kd; c->tf = tf;",
        f"    c->b = {_c_num(t.b)}; c->c = {_c_num(t.c)};",
        f"    c->al = tf / (tf + {U}_DT); c->be = kd / (tf + {U}_DT);",
        "    c->kb = kb;",
        f"    c->lo = {U}_U_MIN; c->hi = {U}_U_MAX;",
        f"    c->i0 = {P}_sched_interp({U}_I0, x);",
        f"    c->aw = {AW_CODE[t.aw]};",
        "}",
        "",
    ]


def _c_reset(P: str, U: str) -> list[str]:
    """``<p>_reset(&s, x0)``: integrator at the operating input interpolated at x0, no derivative kick."""
    return [
        "/* Start at the operating point of x0: the integrator holds the interpolated operating input. */",
        f"static inline void {P}_reset({P}_state *s, double x0)",
        "{",
        f"    s->I[0] = {P}_sched_interp({U}_I0, x0); s->D[0] = 0.0; s->ed_prev[0] = 0.0; s->awe[0] = 0.0;",
        "    s->sp[0] = 0.0;",
        "    s->z = 0.0;",
        "    s->u_prev = s->I[0];",
        "    s->started = 0;",
        "}",
        "",
    ]


def _c_step(P: str, U: str) -> list[str]:
    """``<p>_step``: the coefficients at x, one PID sample, the rate limit."""
    return [
        "/* One sample: reference r, measurement y, scheduling value x -> actuator u. */",
        f"static inline double {P}_step({P}_state *s, double r, double y, double x)",
        "{",
        f"    {P}_pid_coef c;",
        "    double v, u;",
        f"    {P}_sched_coef(x, &c);",
        "    s->sp[0] = r;",
        f"    v = {P}_pid_step(&c, s, 0, r, y);",
        "    u = v;",
        f"    if (isfinite({U}_RATE_LIMIT)) {{",
        f"        double lo = s->u_prev - {U}_RATE_LIMIT * {U}_DT, hi = s->u_prev + {U}_RATE_LIMIT * {U}_DT;",
        "        u = u < lo ? lo : (u > hi ? hi : u);",
        "    }",
        f"    if (c.aw == {U}_AW_BACKCALC) s->awe[0] += u - v;  /* track what was applied */",
        "    s->u_prev = u;",
        "    s->started = 1;",
        "    return u;",
        "}",
        "",
    ]


# -------------------------------------------------------------------------------------------- MATLAB


def schedule_to_matlab(t: ScheduleTable) -> str:
    """MATLAB/Octave: a struct ``sched`` of breakpoints, gain tables and loop settings, and the lookup.

    ``gt_sched_gain(sched.Kp, x)`` is the clamped linear interpolation (``interp1`` on ``x``
    clamped to the breakpoints), the same as the C header's. In Simulink, a 1-D Lookup Table
    block per gain (breakpoints ``sched.breakpoints``, table ``sched.Kp``, linear interpolation,
    extrapolation "Clip") gives the same gains.
    """
    st = _stamp(t)
    x_is = "the loop's measurement (x = y)" if t.schedule_on == "measurement" else f"the measured {t.var}"
    out = [
        f"% Gain schedule of loop '{_one_line(t.loop)}' for spec '{_one_line(t.name)}', generated by "
        f"{_one_line(t.generator)}",
        f"% {_one_line(st.banner())}",
        f"% Scheduling variable x = {_one_line(t.var)}: pass {_one_line(x_is)}.",
        "% Gains at x: linear interpolation of each table over sched.breakpoints, clamped at the ends.",
        "% Discrete law with sample time Ts (backward Euler, as gaintune's simulator):",
        "%   u = Kp*(b*r - y) + I + D,  I = I + Ki*Ts*(r - y),  D = Tf/(Tf+Ts)*D + Kd/(Tf+Ts)*(ed - ed_prev)",
        "%   Tf = Kd/(N*Kp) (or the fixed sched.Tf); saturation sched.lo .. sched.hi with sched.aw anti-windup.",
        f"Ts = {_m_num(t.dt)};  % sample time (s)",
        f"verdict = {_m_str(st.label)};  % verification verdict of the schedule at Ts",
        f"accepted = {'true' if st.accepted else 'false'};  % true only when the schedule passed at Ts",
    ]
    if st.verdict == "fail":
        out.append(f"verdict_reason = {_m_str(st.reason)};")
    out += [
        f"sched = struct('var', {_m_str(t.var)}, 'loop', {_m_str(t.loop)}, 'type', {_m_str(t.type)}, 'Ts', Ts);",
        f"sched.breakpoints = {_m_vec(list(t.grid))};",
        f"sched.Kp = {_m_vec(list(t.kp))};",
        f"sched.Ki = {_m_vec(list(t.ki))};",
        f"sched.Kd = {_m_vec(list(t.kd))};",
        f"sched.i0 = {_m_vec(list(t.i0))};  % integrator start (operating input) at each breakpoint",
        f"sched.b = {_m_num(t.b)}; sched.c = {_m_num(t.c)}; sched.aw = {_m_str(t.aw)};",
        f"sched.N = {_m_num(t.N)}; sched.Tf = {_m_num(t.Tf) if t.Tf is not None else '[]'};  % [] : Tf = Kd/(N*Kp)",
        f"sched.Tt = {_m_num(t.tracking_time) if t.tracking_time is not None else '[]'};"
        "  % back-calculation tracking time ([]: sqrt(Ti*Td), or Ti)",
        f"sched.lo = {_m_num(t.lo)}; sched.hi = {_m_num(t.hi)};"
        f" sched.rate_limit = {_m_num(t.rate_limit) if t.rate_limit is not None else 'Inf'};",
        "% Clamped linear lookup: e.g. Kp = gt_sched_gain(sched.Kp, x);",
        "gt_sched_gain = @(tab, x) interp1(sched.breakpoints, tab, "
        "min(max(x, sched.breakpoints(1)), sched.breakpoints(end)), 'linear');",
    ]
    return "\n".join(out) + "\n"


# ---------------------------------------------------------------------------------------------- JSON


def schedule_to_json(t: ScheduleTable) -> str:
    """The tables, the loop's settings and the verdict as JSON (``inf`` written as the string "inf")."""
    st = _stamp(t)
    d = t.to_dict()
    payload = {
        "format": "gaintune-schedule-export",
        "version": EXPORT_VERSION,
        "spec": t.name,
        "spec_hash": t.spec_hash,
        "verdict": st.label,
        "accepted": st.accepted,
        "reasons": list(t.reasons) if st.verdict == "fail" else [],
        "dt": t.dt,
        "var": t.var,
        "schedule_on": t.schedule_on,
        "loop": {k: d[k] for k in ("loop", "measure", "type", "b", "c", "aw", "N", "Tf", "tracking_time")},
        "interpolation": "linear in var, clamped at the first and last breakpoint",
        "breakpoints": d["grid"],
        "tables": {"Kp": d["kp"], "Ki": d["ki"], "Kd": d["kd"], "i0": d["i0"]},
        "actuator": {"limits": [d["lo"], d["hi"]], "rate_limit": d["rate_limit"]},
        "generator": t.generator,
    }
    return json.dumps(payload, indent=2) + "\n"


def render_schedule(t: ScheduleTable, fmt: str, prefix: str = "gt") -> str:
    """``t`` in format ``fmt`` (one of :data:`SCHEDULE_FORMATS`)."""
    if fmt == "json":
        return schedule_to_json(t)
    if fmt == "c":
        return schedule_to_c(t, prefix)
    if fmt == "matlab":
        return schedule_to_matlab(t)
    raise ExportError("format", f"unknown schedule export format {fmt!r}; choose from {', '.join(SCHEDULE_FORMATS)}")


def write_schedule_exports(t: ScheduleTable, out_dir: str | Path,
                           formats: tuple[str, ...] = SCHEDULE_FORMATS) -> ExportFiles:
    """Write the formats into ``out_dir`` (:data:`SCHEDULE_SUFFIX` names); C and MATLAB only for a passed schedule.

    As :func:`gaintune.export.write_exports`: unless the verdict is "pass", the files that go into a
    controller as they are (``.h``, ``.m``) are withheld and a stale copy of them is deleted.
    """
    for fmt in formats:
        if fmt not in SCHEDULE_FORMATS:
            raise ExportError("format", f"unknown schedule export format {fmt!r}; "
                                        f"choose from {', '.join(SCHEDULE_FORMATS)}")
    ok = t.verdict == "pass"
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths, withheld, removed = [], [], []
    for fmt in formats:
        p = out / SCHEDULE_SUFFIX[fmt]
        if not ok and fmt != "json":
            withheld.append(SCHEDULE_SUFFIX[fmt])
            if p.is_symlink() or p.is_file():
                p.unlink()
                removed.append(p)
            continue
        write_atomic(p, render_schedule(t, fmt))
        paths.append(p)
    reason = None if ok else (t.reasons[0] if t.reasons else "the schedule was not verified")
    return ExportFiles(paths, verdict=t.verdict, dt=t.dt, reason=reason, withheld=tuple(withheld),
                       removed=tuple(removed))
