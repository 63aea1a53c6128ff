"""Gain exports: JSON, YAML, a C header, a MATLAB/Octave snippet and a Python dict.

Every format carries the verdict of the verification: gains that failed are
exported only on request and are marked ``FAILED`` in the file itself.

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

Example
-------
>>> from gaintune.spec import load_spec
>>> spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}]})
>>> text = export_gains(spec, {"loop0": {"Kp": 1.0, "Ki": 0.5}}, "c")
>>> "static inline double gt_step" in text
True
"""

from __future__ import annotations

import json
import math
import re
from datetime import datetime, timezone
from typing import Any

import numpy as np
import yaml

from gaintune.errors import GaintuneError
from gaintune.spec import TuningSpec

__all__ = ["FORMATS", "SUFFIX", "ExportError", "loop_coefficients", "export_gains", "export_result", "write_exports"]

#: Export formats and the file each is written to by :func:`write_exports`.
FORMATS: tuple[str, ...] = ("json", "yaml", "c", "matlab", "python")
SUFFIX: dict[str, str] = {"json": "gains.json", "yaml": "gains.yaml", "c": "gains.h", "matlab": "gains.m", "python": "gains.py"}

AW_CODE = {"none": 0, "clamping": 1, "back_calculation": 2}

Gains = dict[str, dict[str, float]]


class ExportError(GaintuneError):
    """An export was asked for something it cannot produce."""


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("gaintune")
    except Exception:  # pragma: no cover - not installed
        return "unknown"


def loop_coefficients(spec: TuningSpec, gains: Gains) -> list[dict[str, Any]]:
    """Per loop (outer first): the resolved controller the simulator runs.

    PID loops give parallel-form ``Kp, Ki, Kd, Tf, b, c``, ideal ``Ti, Td, N``,
    limits, anti-windup mode and ``Tt``; LQ loops give ``K, Kint, Nr`` and the
    operating point. Every loop also gets ``i0`` (integrator start) and ``y0``.
    """
    from gaintune.controllers.layout import GainLayout
    from gaintune.controllers.lq import lq_gains
    from gaintune.controllers.pid import pid_params
    from gaintune.plants.plant import build_plant
    from gaintune.sim.build import measured_indices

    plant = build_plant(spec.plant)
    layout = GainLayout(spec, plant.states)
    full = layout.from_dict(gains)
    named = layout.to_dict(full)
    lin = plant.linearize()
    meas = measured_indices(spec, plant.outputs)
    act = spec.actuator.limits or (-math.inf, math.inf)
    out = []
    n_loops = len(spec.loops)
    for i, loop in enumerate(spec.loops):
        g = named[loop.name]
        inner = i == n_loops - 1
        lo, hi = act if inner else (loop.output_limits or (-math.inf, math.inf))
        i0 = float(lin.u0) if inner else float(lin.y0[meas[i + 1]])
        d: dict[str, Any] = {
            "name": loop.name,
            "type": loop.type,
            "form": loop.form,
            "measure": plant.outputs[meas[i]],
            "gains": dict(g),
            "lo": float(lo),
            "hi": float(hi),
            "i0": i0,
            "y0": float(lin.y0[meas[i]]),
        }
        if loop.is_lq:
            s = lq_gains(loop, g, lin, meas[i])
            d.update(K=[float(k) for k in s.K], Kint=s.Kint, Nr=s.Nr, x0=[float(v) for v in lin.x0],
                     u0=float(lin.u0), states=list(plant.states), aw="clamping")
        else:
            p = pid_params(loop, g)
            kb = 1.0 / p.Tt if math.isfinite(p.Tt) else 0.0
            d.update(Kp=p.Kp, Ki=p.Ki, Kd=p.Kd, Tf=p.Tf, b=p.b, c=p.c, aw=loop.anti_windup,
                     Tt=p.Tt if math.isfinite(p.Tt) else None, kb=kb)
            d["Ti"] = p.Kp / p.Ki if p.Ki > 0 else math.inf
            d["Td"] = p.Kd / p.Kp if p.Kp > 0 else 0.0
            d["N"] = (d["Td"] / p.Tf) if p.Tf > 0 else math.inf
        out.append(d)
    return out


# --------------------------------------------------------------------- data


def _clean(x: Any) -> Any:
    """JSON/YAML-safe: inf -> "inf" strings, numpy scalars -> floats."""
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return "inf" if x > 0 else ("-inf" if x < 0 else "nan")
    return x


def _payload(spec: TuningSpec, gains: Gains, verdict: str | None, dt: float) -> dict[str, Any]:
    coefs = loop_coefficients(spec, gains)
    return {
        "spec": spec.name,
        "spec_hash": spec.content_hash(),
        "verdict": verdict or "unverified",
        "accepted": verdict == "pass",
        "dt": dt,
        "gains": gains,
        "loops": _clean(coefs),
        "actuator": _clean({"limits": list(spec.actuator.limits) if spec.actuator.limits else None,
                            "rate_limit": spec.actuator.rate_limit}),
        "generator": f"gaintune {_version()}",
    }


def _banner(verdict: str | None) -> str:
    if verdict == "pass":
        return "verification: PASS"
    if verdict == "fail":
        return "verification: FAILED - these gains did not pass verification; do not deploy"
    return "verification: not run - these gains are unverified"


# ------------------------------------------------------------------ formats


def _c_num(x: float) -> str:
    if math.isinf(x):
        return "INFINITY" if x > 0 else "(-INFINITY)"
    r = repr(float(x))
    return r if ("." in r or "e" in r or "n" in r) else r + ".0"


def _ident(name: str) -> str:
    s = re.sub(r"[^0-9A-Za-z_]", "_", name)
    return s if s and not s[0].isdigit() else f"_{s}"


def to_c(spec: TuningSpec, gains: Gains, verdict: str | None, dt: float, prefix: str = "gt") -> str:
    """A self-contained C99 header with ``static inline`` step functions (see module docstring)."""
    coefs = loop_coefficients(spec, gains)
    P, U = prefix.lower(), prefix.upper()
    L = len(coefs)
    lq = coefs[-1] if coefs[-1]["type"] in ("lqr", "lqi") else None
    pid = [c for c in coefs if c["type"] not in ("lqr", "lqi")]
    guard = f"{U}_{_ident(spec.name).upper()}_GAINS_H"
    rate = spec.actuator.rate_limit
    lines = [
        f"/* Controller gains for spec '{spec.name}' (hash {spec.content_hash()[:12]}), generated by gaintune {_version()}",
        f" * on {datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}.",
        f" * {_banner(verdict)}",
        " *",
        " * Discrete-time law (backward Euler, sample time " + _c_num(dt) + " s), identical to gaintune's simulator:",
        " *   P = Kp*(b*sp - y);  I += Ki*dt*(sp - y);",
        " *   D = Tf/(Tf+dt)*D + Kd/(Tf+dt)*(ed - ed_prev),  ed = c*sp - y;",
        " *   v = sat(P + I + D); clamping anti-windup holds I while saturated and the error drives further.",
        " * Loops run outer first; each loop's output is the next loop's setpoint; the innermost drives u.",
        " * Usage:  " + f"{P}_state s; {P}_reset(&s);  every dt: u = {P}_step(&s, r, y{', x' if lq else ''});",
        " *   y[i] = measurement of loop i (" + ", ".join(f"{i}: {c['name']} = {c['measure']}" for i, c in enumerate(coefs)) + ")",
    ]
    if lq:
        lines.append(" *   x[j] = plant state (" + ", ".join(lq["states"]) + ") for the state-feedback loop")
    lines += [
        " */",
        f"#ifndef {guard}",
        f"#define {guard}",
        "",
        "#include <math.h>",
        "",
        f"#define {U}_DT {_c_num(dt)}",
        f"#define {U}_N_LOOPS {L}",
        f"#define {U}_VERIFIED {1 if verdict == 'pass' else 0}",
        f'#define {U}_VERDICT "{verdict or "unverified"}"',
        f"#define {U}_U_MIN {_c_num(coefs[-1]['lo'])}",
        f"#define {U}_U_MAX {_c_num(coefs[-1]['hi'])}",
        f"#define {U}_RATE_LIMIT {_c_num(rate) if rate is not None else 'INFINITY'}",
        f"#define {U}_AW_NONE 0",
        f"#define {U}_AW_CLAMP 1",
        f"#define {U}_AW_BACKCALC 2",
        "",
        "/* Gains as tuned (spec form). */",
    ]
    for i, c in enumerate(coefs):
        for k, v in c["gains"].items():
            lines.append(f"#define {U}_{_ident(c['name']).upper()}_{_ident(k).upper()} {_c_num(v)}")
    lines += [
        "",
        "typedef struct {",
        "    double kp, ki, kd, tf, b, c;  /* parallel form */",
        "    double al, be;                /* al = Tf/(Tf+dt), be = Kd/(Tf+dt) */",
        "    double kb;                    /* back-calculation 1/Tt (0 if unused) */",
        "    double lo, hi;                /* output saturation */",
        "    double i0;                    /* integrator start (operating point) */",
        "    int aw;                       /* anti-windup mode */",
        f"}} {P}_pid_coef;",
        "",
    ]
    if pid:
        lines.append(f"static const {P}_pid_coef {U}_PID[{len(pid)}] = {{")
        for c in pid:
            tf, kd = c["Tf"], c["Kd"]
            al, be = tf / (tf + dt), kd / (tf + dt)
            vals = [c["Kp"], c["Ki"], kd, tf, c["b"], c["c"], al, be, c["kb"], c["lo"], c["hi"], c["i0"]]
            lines.append("    {" + ", ".join(_c_num(v) for v in vals) + f", {AW_CODE[c['aw']]}}},  /* {c['name']} ({c['type']}) */")
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
    lines += [
        "typedef struct {",
        f"    double I[{max(len(pid), 1)}], D[{max(len(pid), 1)}], ed_prev[{max(len(pid), 1)}], awe[{max(len(pid), 1)}];",
        f"    double sp[{L}];   /* setpoint of each loop at the last step */",
        "    double z;         /* LQI integrator */",
        "    double u_prev;    /* last applied actuator value */",
        "    int started;",
        f"}} {P}_state;",
        "",
        f"static inline void {P}_reset({P}_state *s)",
        "{",
        "    int l;",
        f"    for (l = 0; l < {max(len(pid), 1)}; ++l) {{",
        f"        s->I[l] = {'0.0' if not pid else f'{U}_PID[l].i0'}; s->D[l] = 0.0; s->ed_prev[l] = 0.0; s->awe[l] = 0.0;",
        "    }",
        f"    for (l = 0; l < {L}; ++l) s->sp[l] = 0.0;",
        "    s->z = 0.0;",
        f"    s->u_prev = {_c_num(coefs[-1]['i0'])};",
        "    s->started = 0;",
        "}",
        "",
        "/* One PID loop: setpoint sp, measurement y -> saturated output. */",
        f"static inline double {P}_pid_step(const {P}_pid_coef *c, {P}_state *s, int l, double sp, double y)",
        "{",
        "    double e = sp - y, ed = c->c * sp - y, dterm, pterm, iold, it, vu, vs;",
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
        f"    if (c->aw == {U}_AW_CLAMP && vs != vu && e * (vu - vs) * c->ki > 0.0) {{",
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
    if lq:
        lines += [
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
    sig = f"static inline double {P}_step({P}_state *s, double r, const double y[{U}_N_LOOPS]" + (", const double *x)" if lq else ")")
    lines += [
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
        lines += [f"    if ({U}_PID[{len(pid) - 1}].aw == {U}_AW_BACKCALC) s->awe[{len(pid) - 1}] += u - v;  /* track what was applied */"]
    lines += [
        "    s->u_prev = u;",
        "    s->started = 1;",
        "    return u;",
        "}",
        "",
        f"#endif /* {guard} */",
        "",
    ]
    return "\n".join(lines)


def _m_num(x: float) -> str:
    if math.isinf(x):
        return "Inf" if x > 0 else "-Inf"
    return repr(float(x))


def to_matlab(spec: TuningSpec, gains: Gains, verdict: str | None, dt: float) -> str:
    """MATLAB/Octave (control package) snippet: ``pid``/``pid2`` parallel and ``pidstd`` ideal per loop."""
    coefs = loop_coefficients(spec, gains)
    out = [
        f"% Controller gains for spec '{spec.name}', generated by gaintune {_version()}",
        f"% {_banner(verdict)}",
        "% Loops are listed outer first; each loop's output is the next loop's setpoint.",
        "% Parallel form C = Kp + Ki/s + Kd*s/(Tf*s+1) (pid); ideal form Kp*(1 + 1/(Ti*s) + Td*s/((Td/N)*s+1)) (pidstd).",
        "% Octave: pkg load control",
        f"Ts = {_m_num(dt)};  % sample time the gains were tuned for (s)",
    ]
    for c in coefs:
        v = _ident(c["name"])
        out.append(f"% --- loop {c['name']} ({c['type']}, measures {c['measure']})")
        if c["type"] in ("lqr", "lqi"):
            out += [
                f"K_{v} = [{' '.join(_m_num(k) for k in c['K'])}];  % u = u0 - K*(x - x0) + Kint*z + Nr*(r - y0); states: {', '.join(c['states'])}",
                f"Kint_{v} = {_m_num(c['Kint'])};",
                f"Nr_{v} = {_m_num(c['Nr'])};",
            ]
            continue
        out.append(f"Kp_{v} = {_m_num(c['Kp'])}; Ki_{v} = {_m_num(c['Ki'])}; Kd_{v} = {_m_num(c['Kd'])}; Tf_{v} = {_m_num(c['Tf'])};")
        if c["b"] != 1.0 or c["c"] != 0.0:
            out.append(f"C_{v} = pid2(Kp_{v}, Ki_{v}, Kd_{v}, Tf_{v}, {_m_num(c['b'])}, {_m_num(c['c'])});  % 2-DOF, setpoint weights b, c")
            out.append(f"Cfb_{v} = pid(Kp_{v}, Ki_{v}, Kd_{v}, Tf_{v});  % feedback path")
        else:
            out.append(f"C_{v} = pid(Kp_{v}, Ki_{v}, Kd_{v}, Tf_{v});")
        if c["Kp"] > 0:
            ti = _m_num(c["Ti"])
            n = _m_num(c["N"]) if c["Kd"] > 0 else "Inf"
            out.append(f"Cstd_{v} = pidstd(Kp_{v}, {ti}, {_m_num(c['Td'])}, {n});  % ideal form (Ti, Td, N)")
        lim = f"[{_m_num(c['lo'])} {_m_num(c['hi'])}]"
        out.append(f"limits_{v} = {lim};  % output saturation; anti-windup: {c['aw']}")
    return "\n".join(out) + "\n"


def to_python(spec: TuningSpec, gains: Gains, verdict: str | None, dt: float) -> str:
    """A Python module defining ``GAINS`` (spec form) and ``LOOPS`` (resolved parallel form)."""
    p = _payload(spec, gains, verdict, dt)
    return (
        f'"""Controller gains for spec {spec.name!r}, generated by gaintune {_version()}. {_banner(verdict)}."""\n\n'
        f"VERDICT = {p['verdict']!r}\n"
        f"ACCEPTED = {p['accepted']!r}\n"
        f"DT = {dt!r}\n"
        f"GAINS = {json.dumps(gains, indent=4)}\n"
        f"LOOPS = {_pyrepr(p['loops'])}\n"
    )


def _pyrepr(x: Any) -> str:
    text = json.dumps(x, indent=4)
    return text.replace(": null", ": None").replace(": true", ": True").replace(": false", ": False")


def export_gains(
    spec: TuningSpec,
    gains: Gains,
    fmt: str,
    *,
    verdict: str | None = None,
    dt: float | None = None,
    prefix: str = "gt",
) -> str:
    """Render ``gains`` of ``spec`` in format ``fmt`` (one of :data:`FORMATS`).

    ``dt`` defaults to the first scenario's sample time; ``verdict`` ("pass",
    "fail" or None for unverified) is written into the file.
    """
    if fmt not in FORMATS:
        raise ExportError("format", f"unknown export format {fmt!r}; choose from {', '.join(FORMATS)}")
    dt = float(dt) if dt is not None else spec.scenarios[0].dt
    if not (math.isfinite(dt) and dt > 0):
        raise ExportError("dt", f"sample time must be > 0 seconds, got {dt}")
    if fmt == "json":
        return json.dumps(_payload(spec, gains, verdict, dt), indent=2) + "\n"
    if fmt == "yaml":
        return f"# {_banner(verdict)}\n" + yaml.safe_dump(_payload(spec, gains, verdict, dt), sort_keys=False)
    if fmt == "c":
        return to_c(spec, gains, verdict, dt, prefix)
    if fmt == "matlab":
        return to_matlab(spec, gains, verdict, dt)
    return to_python(spec, gains, verdict, dt)


def export_result(result: Any, fmt: str, *, dt: float | None = None, prefix: str = "gt") -> str:
    """Export the gains of a :class:`~gaintune.search.result.TuneResult` (its verdict included)."""
    spec = TuningSpec.model_validate(result.spec)
    return export_gains(spec, result.gains, fmt, verdict=result.verdict, dt=dt, prefix=prefix)


def write_exports(result: Any, out_dir, formats: tuple[str, ...] = ("json", "yaml", "c", "matlab"), dt: float | None = None):
    """Write ``gains.json``, ``gains.yaml``, ``gains.h``, ``gains.m`` (and optionally ``gains.py``) into ``out_dir``."""
    from pathlib import Path

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for fmt in formats:
        p = out / SUFFIX[fmt]
        p.write_text(export_result(result, fmt, dt=dt))
        paths.append(p)
    return paths
