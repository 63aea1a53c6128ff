"""The C header: a self-contained C99 header with ``static inline`` step functions.

The C header implements exactly the discrete-time law documented in
:mod:`gaintune.controllers.pid` (and run by :mod:`gaintune.sim.kernel`), for one
sample time ``dt``:

* ``P = Kp*(b*sp - y)``;
* ``I[k] = I[k-1] + Ki*dt*e[k]`` with ``e = sp - y`` (backward Euler);
* ``D[k] = Tf/(Tf+dt)*D[k-1] + Kd/(Tf+dt)*(ed[k] - ed[k-1])`` with ``ed = c*sp - y``;
* ``v = P + I + D`` saturated to the loop's limits (the innermost loop: the actuator);
* clamping anti-windup (conditional integration), or back-calculation
  ``I += dt/Tt*(v_sat - v)``;
* cascade order: loops outer first, each output is the next loop's setpoint;
  the actuator rate limit applies last;
* LQR/LQI innermost loop: ``u = u0 + Nr*(r - y0) - K (x - x0) + Kint*z``,
  ``z += dt*(r - y)`` with clamping.

The first call after ``reset`` sets ``ed[k-1] = c*sp - y`` (no derivative kick);
integrators start at the operating point (bumpless start, as the simulator).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from gaintune.export.coefficients import loop_coefficients
from gaintune.export.common import ExportError, Gains, _ident, _one_line, _unique_idents, _version
from gaintune.export.verdict import _Stamp
from gaintune.spec import TuningSpec

__all__ = ["AW_CODE", "to_c", "check_names", "pid_coef_typedef", "state_typedef", "pid_step"]

AW_CODE = {"none": 0, "clamping": 1, "back_calculation": 2}


def _ascii(text: str) -> str:
    """``text`` on one line, in ASCII: accents dropped, other non-ASCII characters removed."""
    import unicodedata

    t = unicodedata.normalize("NFKD", _one_line(text))
    return "".join(ch for ch in t if ord(ch) < 128 and not unicodedata.combining(ch))


def _c_num(x: float) -> str:
    if math.isinf(x):
        return "INFINITY" if x > 0 else "(-INFINITY)"
    r = repr(float(x))
    return r if ("." in r or "e" in r or "n" in r) else r + ".0"


def _c_str(text: str) -> str:
    """A C string literal of ``text`` (one line; backslash, quote and ``?``, which could start a trigraph, escaped)."""
    return '"' + _ascii(text).replace("\\", "\\\\").replace('"', '\\"').replace("?", "\\?") + '"'


def _c_comment(text: str) -> str:
    """``text`` made safe inside a ``/* */`` comment: one line, ASCII, no ``*/`` or ``/*`` to end or nest it and
    no ``??`` (in C99 ``??/`` is a backslash, and ``-Wall -Werror`` rejects the trigraph)."""
    # the second replacement cannot create a new "*/": every "*" followed by "/" is gone after the first
    text = _ascii(text).replace("*/", "* /").replace("/*", "/ *")
    return re.sub(r"\?(?=\?)", "? ", text)


@dataclass(frozen=True)
class _Header:
    """What every section of the header needs: names, sample time and the resolved loops."""

    P: str  # lower-case prefix of functions and types
    U: str  # upper-case prefix of macros and constants
    dt: float
    coefs: list[dict[str, Any]]  # every loop, outer first (gaintune.export.coefficients)
    pid: list[dict[str, Any]]  # the PID loops
    lq: dict[str, Any] | None  # the state-feedback innermost loop, if any

    @property
    def n_pid(self) -> int:
        """Length of the per-PID-loop state arrays (at least 1: C has no empty arrays)."""
        return max(len(self.pid), 1)


def check_names(spec: TuningSpec, prefix: str) -> None:
    """Refuse a ``prefix`` that is not a C identifier, or loop names that collide as C identifiers."""
    if not isinstance(prefix, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", prefix):
        raise ExportError("prefix",
                          f"must be a C identifier (letters, digits, _; not starting with a digit), got {prefix!r}")
    _unique_idents(spec.loop_names, "c")


def to_c(spec: TuningSpec, gains: Gains, st: _Stamp, dt: float, prefix: str = "gt") -> str:
    """A self-contained C99 header with ``static inline`` step functions (see module docstring).

    Parameters
    ----------
    spec, gains
        The spec and the gains to export.
    st
        The verification stamp at ``dt``.
    dt
        Sample time of the header's discrete law (s).
    prefix
        C identifier prefixing every name (``gt_step``, ``GT_DT``).

    Returns
    -------
    str
        The header's text.
    """
    check_names(spec, prefix)
    coefs = loop_coefficients(spec, gains)
    h = _Header(P=prefix.lower(), U=prefix.upper(), dt=dt, coefs=coefs,
                pid=[c for c in coefs if c["type"] not in ("lqr", "lqi")],
                lq=coefs[-1] if coefs[-1]["type"] in ("lqr", "lqi") else None)
    guard = f"{h.U}_{_ident(spec.name).upper()}_GAINS_H"
    lines = [*_banner(spec, st, h), f"#ifndef {guard}", f"#define {guard}", "", "#include <math.h>", "",
             *_macros(spec, st, h), *_coefficient_tables(h), *_state_and_pid_step(h), *_lq_step(h),
             *_cascade_step(h), f"#endif /* {guard} */", ""]
    _no_redefinition(lines)
    return "\n".join(lines)


def c_banner_head(spec: TuningSpec, st: _Stamp, U: str) -> list[str]:
    """The opening lines of every C header's leading comment: origin, date, verdict, what ``VERIFIED`` means."""
    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    return [f"/* Controller gains for spec '{_c_comment(spec.name)}' (hash {spec.content_hash()[:12]}), "
            f"generated by gaintune {_version()}",
            f" * on {when}.",
            f" * {_c_comment(st.banner())}",
            f" * {U}_VERIFIED is 1 only when the gains passed verification at this header's sample time {U}_DT.",
            " *"]


def c_stamp_macros(st: _Stamp, U: str) -> list[str]:
    """The verdict ``#define`` lines of every C header: ``VERIFIED`` is 1 only for a pass at the header's dt."""
    verified_dt = (f"{_c_num(st.verified_dt)}  /* sample time the verdict was obtained at */"
                   if st.verified_dt is not None else "0.0  /* 0: never verified */")
    return [f"#define {U}_VERIFIED {1 if st.accepted else 0}",
            f"#define {U}_VERDICT {_c_str(st.label)}",
            f"#define {U}_VERIFIED_DT {verified_dt}",
            f"#define {U}_VERDICT_REASON {_c_str(st.reason if st.verdict == 'fail' else '')}"]


def _banner(spec: TuningSpec, st: _Stamp, h: _Header) -> list[str]:
    """The leading comment: where the header comes from, its verdict, its law and how to call it."""
    P, U, coefs, lq = h.P, h.U, h.coefs, h.lq
    loops = ", ".join(f"{i}: {_c_comment(c['name'])} = {_c_comment(c['measure'])}" for i, c in enumerate(coefs))
    lines = [
        *c_banner_head(spec, st, U),
        " * Discrete-time law (backward Euler, sample time " + _c_num(h.dt) + " s), identical to gaintune's simulator:",
        " *   P = Kp*(b*sp - y);  I += Ki*dt*(sp - y);",
        " *   D = Tf/(Tf+dt)*D + Kd/(Tf+dt)*(ed - ed_prev),  ed = c*sp - y;",
        " *   v = sat(P + I + D); clamping anti-windup holds I while saturated and the error drives further.",
        " * Loops run outer first; each loop's output is the next loop's setpoint; the innermost drives u.",
        " * Usage:  " + f"{P}_state s; {P}_reset(&s);  every dt: u = {P}_step(&s, r, y{', x' if lq else ''});",
        " *   y[i] = measurement of loop i (" + loops + ")",
    ]
    if lq:
        lines.append(" *   x[j] = plant state (" + ", ".join(_c_comment(x) for x in lq["states"])
                     + ") for the state-feedback loop")
    return [*lines, " */"]


def _macros(spec: TuningSpec, st: _Stamp, h: _Header) -> list[str]:
    """The ``#define`` block: sample time, verdict, actuator limits, anti-windup codes and the gains as tuned."""
    U, last, rate = h.U, h.coefs[-1], spec.actuator.rate_limit
    lines = [
        f"#define {U}_DT {_c_num(h.dt)}",
        f"#define {U}_N_LOOPS {len(h.coefs)}",
        *c_stamp_macros(st, U),
        f"#define {U}_U_MIN {_c_num(last['lo'])}",
        f"#define {U}_U_MAX {_c_num(last['hi'])}",
        f"#define {U}_RATE_LIMIT {_c_num(rate) if rate is not None else 'INFINITY'}",
        f"#define {U}_AW_NONE 0",
        f"#define {U}_AW_CLAMP 1",
        f"#define {U}_AW_BACKCALC 2",
        "",
        "/* Gains as tuned (spec form). */",
    ]
    for c in h.coefs:
        for k, v in c["gains"].items():
            lines.append(f"#define {U}_{_ident(c['name']).upper()}_{_ident(k).upper()} {_c_num(v)}")
    return lines


def _coefficient_tables(h: _Header) -> list[str]:
    """The PID coefficient struct and table, and the state-feedback constants."""
    P, U, dt, lq = h.P, h.U, h.dt, h.lq
    lines = ["", *pid_coef_typedef(P), ""]
    if h.pid:
        lines.append(f"static const {P}_pid_coef {U}_PID[{len(h.pid)}] = {{")
        for c in h.pid:
            tf, kd = c["Tf"], c["Kd"]
            vals = [c["Kp"], c["Ki"], kd, tf, c["b"], c["c"], tf / (tf + dt), kd / (tf + dt), c["kb"], c["lo"],
                    c["hi"], c["i0"]]
            lines.append("    {" + ", ".join(_c_num(v) for v in vals)
                         + f", {AW_CODE[c['aw']]}}},  /* {_c_comment(c['name'])} ({c['type']}) */")
        lines += ["};", ""]
    if lq:
        n = len(lq["K"])
        lines += [
            f"#define {U}_N_STATES {n}",
            f"static const double {U}_K[{n}] = {{" + ", ".join(_c_num(v) for v in lq["K"]) + "};",
            f"static const double {U}_X0[{n}] = {{" + ", ".join(_c_num(v) for v in lq["x0"]) + "};",
            f"static const double {U}_KINT = {_c_num(lq['Kint'])};",
            f"static const double {U}_NR = {_c_num(lq['Nr'])};",
            f"static const double {U}_LQ_U0 = {_c_num(lq['u0'])};",
            f"static const double {U}_LQ_Y0 = {_c_num(lq['y0'])};",
            "",
        ]
    return lines


def pid_coef_typedef(P: str) -> list[str]:
    """The ``<P>_pid_coef`` struct: one PID loop's per-step coefficients (parallel form, limits, anti-windup)."""
    return [
        "typedef struct {",
        "    double kp, ki, kd, tf, b, c;  /* parallel form */",
        "    double al, be;                /* al = Tf/(Tf+dt), be = Kd/(Tf+dt) */",
        "    double kb;                    /* back-calculation 1/Tt (0 if unused) */",
        "    double lo, hi;                /* output saturation */",
        "    double i0;                    /* integrator start (operating point) */",
        "    int aw;                       /* anti-windup mode */",
        f"}} {P}_pid_coef;",
    ]


def state_typedef(P: str, n_pid: int, n_loops: int) -> list[str]:
    """The ``<P>_state`` struct: every loop's integrator, filter, last error and anti-windup state."""
    n = n_pid
    return [
        "typedef struct {",
        f"    double I[{n}], D[{n}], ed_prev[{n}], awe[{n}];",
        f"    double sp[{n_loops}];   /* setpoint of each loop at the last step */",
        "    double z;         /* LQI integrator */",
        "    double u_prev;    /* last applied actuator value */",
        "    int started;",
        f"}} {P}_state;",
    ]


def _state_and_pid_step(h: _Header) -> list[str]:
    """The controller state struct, ``<p>_reset`` and the one-PID-loop step ``<p>_pid_step``."""
    P, U, n = h.P, h.U, h.n_pid
    return [
        *state_typedef(P, n, len(h.coefs)),
        "",
        f"static inline void {P}_reset({P}_state *s)",
        "{",
        "    int l;",
        f"    for (l = 0; l < {n}; ++l) {{",
        f"        s->I[l] = {'0.0' if not h.pid else f'{U}_PID[l].i0'}; s->D[l] = 0.0; s->ed_prev[l] = 0.0; "
        "s->awe[l] = 0.0;",
        "    }",
        f"    for (l = 0; l < {len(h.coefs)}; ++l) s->sp[l] = 0.0;",
        "    s->z = 0.0;",
        f"    s->u_prev = {_c_num(h.coefs[-1]['i0'])};",
        "    s->started = 0;",
        "}",
        "",
        *pid_step(P, U),
    ]


def pid_step(P: str, U: str, actuator: bool = False) -> list[str]:
    """``<P>_pid_step``: one sample of one PID loop (the simulator's discrete law, see the module docstring).

    ``actuator``: the step also takes ``ff, alo, ahi``, the feedforward added to the loop's output at the
    input it drives and that input's limits, and the clamp also holds I when ``sat(v + ff)`` saturates
    and the error drives further (the MIMO kernel's rule; +-INFINITY limits for a loop behind a decoupler).
    """
    extra = ", double ff, double alo, double ahi" if actuator else ""
    hold = [
        f"    hold = c->aw == {U}_AW_CLAMP && vs != vu && e * (vu - vs) * c->ki > 0.0;",
        f"    if (c->aw == {U}_AW_CLAMP && !hold) {{  /* the input's saturation of v + ff */",
        "        double tot = vs + ff, ts = tot < alo ? alo : (tot > ahi ? ahi : tot);",
        "        hold = ts != tot && e * (tot - ts) * c->ki > 0.0;",
        "    }",
        "    if (hold) {",
    ] if actuator else [f"    if (c->aw == {U}_AW_CLAMP && vs != vu && e * (vu - vs) * c->ki > 0.0) {{"]
    return [
        "/* One PID loop: setpoint sp, measurement y -> saturated output. */",
        f"static inline double {P}_pid_step(const {P}_pid_coef *c, {P}_state *s, int l, double sp, double y{extra})",
        "{",
        "    double e = sp - y, ed = c->c * sp - y, dterm, pterm, iold, it, vu, vs;",
        *(["    int hold;"] if actuator else []),
        "    if (!s->started) s->ed_prev[l] = ed;  /* no derivative kick */",
        "    dterm = c->al * s->D[l] + c->be * (ed - s->ed_prev[l]);",
        "    s->ed_prev[l] = ed;",
        "    s->D[l] = dterm;",
        "    pterm = c->kp * (c->b * sp - y);",
        "    iold = s->I[l];",
        f"    it = iold + c->ki * {U}_DT * e;",
        f"    if (c->aw == {U}_AW_BACKCALC) it += c->kb * {U}_DT * s->awe[l];",
        "    vu = pterm + it + dterm;",
        "    vs = vu < c->lo ? c->lo : (vu > c->hi ? c->hi : vu);",
        *hold,
        "        it = iold;  /* conditional integration */",
        "        vu = pterm + it + dterm;",
        "        vs = vu < c->lo ? c->lo : (vu > c->hi ? c->hi : vu);",
        "    }",
        "    s->I[l] = it;",
        "    s->awe[l] = vs - vu;",
        "    return vs;",
        "}",
        "",
    ]


def _lq_step(h: _Header) -> list[str]:
    """The state-feedback (LQR/LQI) step ``<p>_lq_step``; empty without such a loop."""
    P, U = h.P, h.U
    if not h.lq:
        return []
    return [
        "/* State-feedback (LQR/LQI) innermost loop. */",
        f"static inline double {P}_lq_step({P}_state *s, double sp, double y, const double *x)",
        "{",
        "    int i;",
        f"    double e = sp - y, v = {U}_LQ_U0 + {U}_NR * (sp - {U}_LQ_Y0), zt, vu, vs;",
        f"    for (i = 0; i < {U}_N_STATES; ++i) v -= {U}_K[i] * (x[i] - {U}_X0[i]);",
        f"    zt = s->z + {U}_DT * e;",
        f"    vu = v + {U}_KINT * zt;",
        f"    vs = vu < {U}_U_MIN ? {U}_U_MIN : (vu > {U}_U_MAX ? {U}_U_MAX : vu);",
        f"    if (vs != vu && e * {U}_KINT * (vu - vs) > 0.0) {{",
        f"        vu = v + {U}_KINT * s->z;",
        f"        vs = vu < {U}_U_MIN ? {U}_U_MIN : (vu > {U}_U_MAX ? {U}_U_MAX : vu);",
        "    } else {",
        "        s->z = zt;",
        "    }",
        "    return vs;",
        "}",
        "",
    ]


def _cascade_step(h: _Header) -> list[str]:
    """``<p>_step``: one sample of the whole cascade, outer loop first, then the actuator rate limit."""
    P, U, pid, lq, L = h.P, h.U, h.pid, h.lq, len(h.coefs)
    sig = (f"static inline double {P}_step({P}_state *s, double r, const double y[{U}_N_LOOPS]"
           + (", const double *x)" if lq else ")"))
    lines = [
        "/* One sample of the whole cascade: reference r, measurements y (outer loop first)"
        + (", plant state x" if lq else "") + " -> actuator u. */",
        sig,
        "{",
        "    double sp = r, v, u;",
        "    int l;",
        f"    for (l = 0; l < {len(pid)}; ++l) {{",
        "        s->sp[l] = sp;",
        f"        sp = {P}_pid_step(&{U}_PID[l], s, l, sp, y[l]);" if pid else "        (void)0;",
        "    }",
    ]
    if lq:
        lines += [f"    s->sp[{L - 1}] = sp;", f"    v = {P}_lq_step(s, sp, y[{L - 1}], x);"]
    else:
        lines += ["    v = sp;"]
    lines += [
        "    u = v;",
        f"    if (isfinite({U}_RATE_LIMIT)) {{",
        f"        double lo = s->u_prev - {U}_RATE_LIMIT * {U}_DT, hi = s->u_prev + {U}_RATE_LIMIT * {U}_DT;",
        "        u = u < lo ? lo : (u > hi ? hi : u);",
        "    }",
    ]
    if pid and not lq:
        last = len(pid) - 1
        lines += [f"    if ({U}_PID[{last}].aw == {U}_AW_BACKCALC) s->awe[{last}] += u - v;"
                  "  /* track what was applied */"]
    return [*lines, "    s->u_prev = u;", "    s->started = 1;", "    return u;", "}", ""]


def _no_redefinition(lines: list[str]) -> None:
    """ExportError when one macro is defined twice (a compiler warning, and the first gain silently lost)."""
    seen: set[str] = set()
    for line in lines:
        if line.startswith("#define "):
            name = line.split()[1]
            if name in seen:
                raise ExportError("loops", f"gains.h would define {name} twice; rename the loops (or states) whose "
                                           "names differ only in characters other than A-Z, a-z, 0-9 and _")
            seen.add(name)
