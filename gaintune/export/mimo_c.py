"""The C header of a MIMO architecture: every loop's law, the graph wiring, the decoupler and the actuators.

The header implements exactly one step of :mod:`gaintune.sim.mimo_kernel` for one sample time
``dt`` (the per-loop law is the SISO header's ``<p>_pid_step``, :func:`gaintune.export.c.pid_step`):

1. loops in evaluation order (a loop's setpoint source comes first): the setpoint is the
   chain's reference ``r[chain]`` for an outer loop, else the output of its ``PARENT`` loop;
   the loop measures ``y[MEAS[l]]`` (plant outputs by index);
2. the actuators: ``u = W v`` (``v`` the loops' outputs; ``W`` the identity wiring or the
   decoupler, tuned entries at the exported values), plus ``FF r`` when the spec has a reference
   feedforward, each saturated to its limits, then rate limited;
3. back-calculation loops that drive an input directly track the applied value (less the feedforward).

With a feedforward, ``FF r`` is computed before the loops, and a clamping loop that drives an input directly
also holds its integrator when that input saturates on the loop's output plus the feedforward.

Integrators start at 0 (the signals are deviations from the operating point, as the simulator's).
"""

from __future__ import annotations

from typing import Any

from gaintune.export.c import (
    AW_CODE,
    _c_comment,
    _c_num,
    _c_str,
    _no_redefinition,
    c_banner_head,
    c_stamp_macros,
    check_names,
    pid_coef_typedef,
    pid_step,
)
from gaintune.export.common import Gains, _ident
from gaintune.export.mimo import mimo_architecture
from gaintune.export.verdict import _Stamp
from gaintune.spec import TuningSpec

__all__ = ["to_c_mimo"]


def _arr(kind: str, name: str, vals: list[Any], note: str) -> str:
    body = ", ".join(_c_num(v) if kind == "double" else str(v) for v in vals)
    return f"static const {kind} {name}[{max(len(vals), 1)}] = {{{body or '0'}}};  /* {note} */"


def _names(name: str, vals: list[str]) -> str:
    return f"static const char *const {name}[{len(vals)}] = {{{', '.join(_c_str(v) for v in vals)}}};"


def to_c_mimo(spec: TuningSpec, gains: Gains, st: _Stamp, dt: float, prefix: str = "gt") -> str:
    """A self-contained C99 header of the whole MIMO architecture (see the module docstring).

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
    a = mimo_architecture(spec, gains)
    P, U = prefix.lower(), prefix.upper()
    guard = f"{U}_{_ident(spec.name).upper()}_GAINS_H"
    lines = [*_banner(spec, st, a, P, U, dt), f"#ifndef {guard}", f"#define {guard}", "", "#include <math.h>", "",
             *_macros(st, a, U, dt), *_tables(a, P, U, dt), *_state(a, P), *pid_step(P, U, a["FF"] is not None),
             *_step(P, U, a["FF"] is not None),
             f"#endif /* {guard} */", ""]
    _no_redefinition(lines)
    return "\n".join(lines)


def _banner(spec: TuningSpec, st: _Stamp, a: dict[str, Any], P: str, U: str, dt: float) -> list[str]:
    out = [
        *c_banner_head(spec, st, U),
        f" * MIMO architecture: {len(a['loops'])} loops, {len(a['chains'])} chains, {len(a['inputs'])} plant inputs, "
        f"{len(a['outputs'])} plant outputs" + (", a static decoupler." if a["decoupler"] else "."),
        " * Per step (sample time " + _c_num(dt) + " s), identical to gaintune's MIMO simulator:",
        " *   loops in evaluation order l = 0.." + f"{U}_N_LOOPS-1: sp = r[{U}_CHAIN[l]] for a chain's outer loop,",
        f" *   else the output v[{U}_PARENT[l]]; v[l] = PID(sp, y[{U}_MEAS[l]]) (backward Euler, limits, anti-windup);",
        f" *   u[j] = sum_l {U}_W[j][l] v[l]" + (f" + sum_c {U}_FF[j][c] r[c]" if a["FF"] is not None else "")
        + f", saturated to [{U}_U_MIN[j], {U}_U_MAX[j]], then rate limited.",
        f" * Usage:  {P}_state s; {P}_reset(&s);  every dt: {P}_step(&s, r, y, u);",
        f" *   r[c]: reference of chain c ({', '.join(_c_comment(c) for c in a['chains'])})",
        f" *   y[i]: plant output i ({', '.join(_c_comment(o['name']) for o in a['outputs'])})",
        f" *   u[j]: plant input j ({', '.join(_c_comment(i['name']) for i in a['inputs'])})",
        " * Loops (evaluation order): "
        + "; ".join(f"{k}: {_c_comment(lp['name'])} measures {_c_comment(lp['measure'])}, drives "
                    f"{_c_comment(lp['drives'])}" for k, lp in enumerate(a["loops"])),
    ]
    return [*out, " */"]


def _macros(st: _Stamp, a: dict[str, Any], U: str, dt: float) -> list[str]:
    lines = [
        f"#define {U}_DT {_c_num(dt)}",
        f"#define {U}_N_LOOPS {len(a['loops'])}",
        f"#define {U}_N_CHAINS {len(a['chains'])}",
        f"#define {U}_N_INPUTS {len(a['inputs'])}",
        f"#define {U}_N_OUTPUTS {len(a['outputs'])}",
        *c_stamp_macros(st, U),
        f"#define {U}_AW_NONE 0",
        f"#define {U}_AW_CLAMP 1",
        f"#define {U}_AW_BACKCALC 2",
        "",
        "/* Index of each loop, plant input and output in the arrays below. */",
    ]
    for kind, names in (("LOOP", [lp["name"] for lp in a["loops"]]), ("IN", [i["name"] for i in a["inputs"]]),
                        ("OUT", [o["name"] for o in a["outputs"]])):
        lines += [f"#define {U}_{kind}_{_ident(n).upper()} {k}" for k, n in enumerate(names)]
    lines += ["", "/* Gains as tuned (spec form). */"]
    for lp in a["loops"]:
        for k, v in lp["gains"].items():
            lines.append(f"#define {U}_{_ident(lp['name']).upper()}_{_ident(k).upper()} {_c_num(v)}")
    for block, entries in a["blocks"].items():  # tuned decoupler entries and feedforward gains (in W and FF)
        lines += [f"#define {U}_{_ident(block).upper()}_{_ident(k).upper()} {_c_num(v)}" for k, v in entries.items()]
    return lines


def _tables(a: dict[str, Any], P: str, U: str, dt: float) -> list[str]:
    loops, inputs = a["loops"], a["inputs"]
    lines = ["", *pid_coef_typedef(P), "", f"static const {P}_pid_coef {U}_PID[{U}_N_LOOPS] = {{"]
    for c in loops:
        tf, kd = c["Tf"], c["Kd"]
        vals = [c["Kp"], c["Ki"], kd, tf, c["b"], c["c"], tf / (tf + dt), kd / (tf + dt), c["kb"], c["lo"], c["hi"],
                c["i0"]]
        lines.append("    {" + ", ".join(_c_num(v) for v in vals)
                     + f", {AW_CODE[c['aw']]}}},  /* {_c_comment(c['name'])} ({c['type']}) */")
    lims = [i["limits"] or [float("-inf"), float("inf")] for i in inputs]
    rates = [i["rate_limit"] if i["rate_limit"] is not None else float("inf") for i in inputs]
    W = a["W"]
    lines += [
        "};",
        "",
        "/* The loop graph, in evaluation order. */",
        _arr("int", f"{U}_MEAS", [c["meas_index"] for c in loops], "plant output each loop measures"),
        _arr("int", f"{U}_PARENT", [c["parent"] for c in loops], "loop whose output is the setpoint; -1: a reference"),
        _arr("int", f"{U}_CHAIN", [c["chain"] for c in loops], "reference index of a chain's outer loop; -1: inner"),
        _arr("int", f"{U}_DRIVES", [c["drive_index"] for c in loops], "plant input a loop drives; -1: a setpoint"),
        _arr("int", f"{U}_DIRECT", [c["direct"] for c in loops], "input a loop drives without decoupler; -1: none"),
        f"/* u = W v: one row per plant input, one column per loop{' (the decoupler)' if a['decoupler'] else ''} */",
        f"static const double {U}_W[{U}_N_INPUTS][{U}_N_LOOPS] = {{",
        *["    {" + ", ".join(_c_num(x) for x in row) + "}," for row in W],
        "};",
        *_ff_table(a, U),
        _arr("double", f"{U}_U_MIN", [x[0] for x in lims], "actuator saturation, per plant input"),
        _arr("double", f"{U}_U_MAX", [x[1] for x in lims], "actuator saturation, per plant input"),
        _arr("double", f"{U}_RATE", rates, "actuator rate limit |du/dt|, per plant input"),
        _names(f"{U}_LOOP_NAMES", [c["name"] for c in loops]),
        _names(f"{U}_CHAIN_NAMES", a["chains"]),
        _names(f"{U}_INPUT_NAMES", [i["name"] for i in inputs]),
        _names(f"{U}_OUTPUT_NAMES", [o["name"] for o in a["outputs"]]),
        "",
    ]
    return lines


def _state(a: dict[str, Any], P: str) -> list[str]:
    """The controller state (field names of the SISO state, which ``<p>_pid_step`` uses) and ``<p>_reset``."""
    L, m = len(a["loops"]), len(a["inputs"])
    return [
        "typedef struct {",
        f"    double I[{L}], D[{L}], ed_prev[{L}], awe[{L}];",
        f"    double v[{L}];        /* each loop's output at the last step */",
        f"    double sp[{L}];       /* each loop's setpoint at the last step */",
        f"    double u_prev[{m}];   /* last applied value of each plant input */",
        *([f"    double ff[{m}];       /* feedforward part of each plant input at the last step */"]
          if a["FF"] is not None else []),
        "    int started;",
        f"}} {P}_state;",
        "",
        f"static inline void {P}_reset({P}_state *s)",
        "{",
        "    int l, j;",
        f"    for (l = 0; l < {L}; ++l) {{ s->I[l] = 0.0; s->D[l] = 0.0; s->ed_prev[l] = 0.0; s->awe[l] = 0.0; "
        "s->v[l] = 0.0; s->sp[l] = 0.0; }",
        f"    for (j = 0; j < {m}; ++j) s->u_prev[j] = 0.0;",
        *([f"    for (j = 0; j < {m}; ++j) s->ff[j] = 0.0;"] if a["FF"] is not None else []),
        "    s->started = 0;",
        "}",
        "",
    ]


def _ff_table(a: dict[str, Any], U: str) -> list[str]:
    """``FF`` (plant inputs x chains) of a spec with a reference feedforward; nothing otherwise."""
    if a["FF"] is None:
        return []
    return ["/* u += FF r: one row per plant input, one column per chain reference (the feedforward) */",
            f"static const double {U}_FF[{U}_N_INPUTS][{U}_N_CHAINS] = {{",
            *["    {" + ", ".join(_c_num(x) for x in row) + "}," for row in a["FF"]], "};"]


def _step(P: str, U: str, ff: bool = False) -> list[str]:
    """``<p>_step``: the kernel's arithmetic, step for step (``ff``: with the reference feedforward)."""
    # the feedforward first: a clamping loop that drives an input directly judges its saturation
    ff_first = [f"    for (j = 0; j < {U}_N_INPUTS; ++j) {{ double f = 0.0; int c; "
                f"for (c = 0; c < {U}_N_CHAINS; ++c) f += {U}_FF[j][c] * r[c]; s->ff[j] = f; }}"] if ff else []
    add_ff = ["        v += s->ff[j];"] if ff else []
    call = (f"{P}_pid_step(&{U}_PID[l], s, l, sp, y[{U}_MEAS[l]], d >= 0 ? s->ff[d] : 0.0, "
            f"d >= 0 ? {U}_U_MIN[d] : -INFINITY, d >= 0 ? {U}_U_MAX[d] : INFINITY)" if ff else
            f"{P}_pid_step(&{U}_PID[l], s, l, sp, y[{U}_MEAS[l]])")
    track = (f"s->awe[l] += u[{U}_DIRECT[l]] - s->ff[{U}_DIRECT[l]] - s->v[l];" if ff else
             f"s->awe[l] += u[{U}_DIRECT[l]] - s->v[l];")
    return [
        "/* One sample of the whole architecture: chain references r, plant outputs y -> plant inputs u. */",
        f"static inline void {P}_step({P}_state *s, const double r[{U}_N_CHAINS], const double y[{U}_N_OUTPUTS],",
        f"                           double u[{U}_N_INPUTS])",
        "{",
        "    int l, j;",
        *ff_first,
        f"    for (l = 0; l < {U}_N_LOOPS; ++l) {{",
        f"        double sp = {U}_PARENT[l] < 0 ? r[{U}_CHAIN[l]] : s->v[{U}_PARENT[l]];",
        *([f"        int d = {U}_DIRECT[l];"] if ff else []),
        "        s->sp[l] = sp;",
        f"        s->v[l] = {call};",
        "    }",
        f"    for (j = 0; j < {U}_N_INPUTS; ++j) {{",
        "        double v = 0.0;",
        f"        for (l = 0; l < {U}_N_LOOPS; ++l) v += {U}_W[j][l] * s->v[l];",
        *add_ff,
        f"        v = v < {U}_U_MIN[j] ? {U}_U_MIN[j] : (v > {U}_U_MAX[j] ? {U}_U_MAX[j] : v);",
        f"        if (isfinite({U}_RATE[j])) {{",
        f"            double lo = s->u_prev[j] - {U}_RATE[j] * {U}_DT, hi = s->u_prev[j] + {U}_RATE[j] * {U}_DT;",
        "            v = v < lo ? lo : (v > hi ? hi : v);",
        "        }",
        "        u[j] = v;",
        "    }",
        f"    for (l = 0; l < {U}_N_LOOPS; ++l)  /* back-calculation tracks what was applied */",
        f"        if ({U}_PID[l].aw == {U}_AW_BACKCALC && {U}_DIRECT[l] >= 0) {track}",
        f"    for (j = 0; j < {U}_N_INPUTS; ++j) s->u_prev[j] = u[j];",
        "    s->started = 1;",
        "}",
        "",
    ]
