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

Verdicts are per sample time
----------------------------
Verification depends on ``dt``: it analyses the sampled loop at the largest scenario
``dt`` (:mod:`gaintune.verify.sampled`; frequencies up to ``pi/dt``) and the nonlinear
check simulates at the scenarios' ``dt``. A file therefore only
claims the verdict obtained *at the dt it is exported for*:
:func:`verdict_at_dt` returns the stored verdict when ``dt`` is the one the result
was verified at (:func:`verified_dt`, every scenario at that ``dt``), and otherwise
re-verifies on a copy of the spec whose scenarios all run at ``dt``
(:func:`spec_at_dt`). Every format records ``dt``, ``verified_dt`` and, for
failed gains, why they failed.

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
from gaintune.spec import MAX_STEPS, TuningSpec

__all__ = [
    "FORMATS", "SUFFIX", "FIRMWARE_FORMATS", "ExportError", "ExportFiles", "loop_coefficients", "discrete_pid_tf",
    "verified_dt", "spec_at_dt", "verdict_at_dt", "result_verdict_at_dt", "first_reason", "export_gains",
    "export_result", "write_exports",
]

#: Export formats and the file each is written to by :func:`write_exports`.
FORMATS: tuple[str, ...] = ("json", "yaml", "c", "matlab", "python")
SUFFIX: dict[str, str] = {"json": "gains.json", "yaml": "gains.yaml", "c": "gains.h", "matlab": "gains.m", "python": "gains.py"}
#: Formats that are pasted into controllers as they are: :func:`write_exports` writes them only for gains that passed.
FIRMWARE_FORMATS: tuple[str, ...] = ("c", "matlab", "python")

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
    from gaintune.controllers.direction import measured_indices

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
            # a reverse-acting loop has Kp, Ki, Kd all negative: Ti and Td stay positive
            d["Ti"] = p.Kp / p.Ki if p.Ki * p.Kp > 0 else math.inf
            d["Td"] = p.Kd / p.Kp if p.Kp != 0 else 0.0
            d["N"] = (d["Td"] / p.Tf) if p.Tf > 0 else math.inf
        out.append(d)
    return out


def discrete_pid_tf(coef: dict[str, Any], dt: float, path: str = "feedback") -> tuple[list[float], list[float]]:
    """(num, den) in descending powers of z of one PID loop's discrete law (the simulator's, exactly).

    ``u = Cr(z) r - Cy(z) y`` with ``Cy = Kp + Ki*dt*z/(z-1) + Kd*(z-1)/((Tf+dt)*z - Tf)``
    (``path="feedback"``) and ``Cr = b*Kp + Ki*dt*z/(z-1) + c*Kd*(z-1)/((Tf+dt)*z - Tf)``
    (``path="setpoint"``). Factors of an absent term (``Ki = 0``, ``Kd = 0``) are left out.
    """
    wp, wd = (1.0, 1.0) if path == "feedback" else (float(coef["b"]), float(coef["c"]))
    kp, ki, kd, tf = float(coef["Kp"]), float(coef["Ki"]), float(coef["Kd"]), float(coef["Tf"])
    terms: list[tuple[np.ndarray, np.ndarray]] = [(np.array([wp * kp]), np.array([1.0]))]
    if ki != 0.0:
        terms.append((np.array([ki * dt, 0.0]), np.array([1.0, -1.0])))
    if kd != 0.0:
        terms.append((wd * kd * np.array([1.0, -1.0]), np.array([tf + dt, -tf])))
    num, den = np.array([0.0]), np.array([1.0])
    for n, d in terms:  # num/den + n/d
        num, den = np.polyadd(np.polymul(num, d), np.polymul(n, den)), np.polymul(den, d)
    return [float(v) for v in num], [float(v) for v in den]


# ------------------------------------------------------- verdict at a dt


def _same_dt(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=0.0)


def _fmt_dt(dt: float) -> str:
    return format(float(dt), ".10g")


def _check_dt(dt: Any) -> float:
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise ExportError("dt", f"sample time must be a number of seconds, got {dt!r}") from None
    if not (math.isfinite(dt) and dt > 0):
        raise ExportError("dt", f"sample time must be > 0 seconds, got {dt}")
    return dt


def verified_dt(spec: TuningSpec) -> float:
    """The sample time a verification of ``spec`` holds for: the largest scenario ``dt``.

    The sampled-loop analysis (:mod:`gaintune.verify.sampled`) and the analysis band use it.
    """
    return max(sc.dt for sc in spec.scenarios)


_spec_verified_dt = verified_dt  # for functions whose ``verified_dt`` parameter shadows the name


def spec_at_dt(spec: TuningSpec, dt: float, *, max_steps: int | None = None) -> TuningSpec:
    """A copy of ``spec`` whose scenarios all run at sample time ``dt`` (each keeps its horizon).

    Raises :class:`ExportError` (field ``dt``) when a horizon would need more than
    ``max_steps`` (default and ceiling: :data:`gaintune.spec.MAX_STEPS`) or fewer than 2 steps.
    """
    dt = _check_dt(dt)
    limit = MAX_STEPS if max_steps is None else min(int(max_steps), MAX_STEPS)
    for i, sc in enumerate(spec.scenarios):
        steps = sc.horizon / dt
        if steps > limit:
            raise ExportError(
                "dt", f"dt = {_fmt_dt(dt)} s needs horizon/dt = {steps:.0f} steps for scenario {sc.name!r} "
                f"(horizon {_fmt_dt(sc.horizon)} s), over the limit of {limit}; export at dt >= "
                f"{_fmt_dt(sc.horizon / limit)} s, or shorten scenarios.{i}.horizon and re-tune")
        if steps < 2:
            raise ExportError(
                "dt", f"dt = {_fmt_dt(dt)} s leaves fewer than 2 samples in the {_fmt_dt(sc.horizon)} s horizon of scenario "
                f"{sc.name!r}; export at dt <= {_fmt_dt(sc.horizon / 2)} s, or lengthen scenarios.{i}.horizon and re-tune")
    if all(_same_dt(sc.dt, dt) for sc in spec.scenarios):
        return spec
    from pydantic import ValidationError

    data = spec.model_dump(mode="json")
    for sc in data["scenarios"]:
        sc["dt"] = dt
    try:
        return TuningSpec.model_validate(data)
    except ValidationError as exc:
        e = exc.errors(include_url=False, include_input=False)[0]
        loc = ".".join(str(p) for p in e["loc"])
        raise ExportError("dt", f"the spec is not valid at dt = {_fmt_dt(dt)} s ({loc}: {e['msg']}); choose another dt") from None


def first_reason(report: Any) -> str | None:
    """The first reason of a verification report (dict or :class:`~gaintune.verify.VerificationReport`)."""
    if report is None:
        return None
    reasons = report.get("reasons") if isinstance(report, dict) else getattr(report, "reasons", None)
    return str(reasons[0]) if reasons else None


def verdict_at_dt(
    spec: TuningSpec,
    gains: Gains,
    dt: float | None = None,
    *,
    stored: Any = None,
    robust: bool | None = None,
    max_steps: int | None = None,
) -> tuple[str, dict[str, Any] | None]:
    """The verdict of ``gains`` at sample time ``dt`` and the report it comes from (JSON form).

    ``stored`` is the verification already done on ``spec`` (a report dict or model, e.g.
    ``TuneResult.verification``). It is returned as it is when ``dt`` is the sample time it
    was obtained at (:func:`verified_dt`, with every scenario at that ``dt``). Otherwise
    (another ``dt``, scenarios of mixed ``dt``, or nothing stored) the gains are verified
    with :func:`gaintune.verify.verify` on :func:`spec_at_dt` ``(spec, dt)``; ``robust``
    defaults to what the stored report did (else the spec's default).

    Raises :class:`ExportError` (field ``dt``) for a ``dt`` the spec cannot run at.
    """
    vdt = verified_dt(spec)
    dt = vdt if dt is None else _check_dt(dt)
    if hasattr(stored, "model_dump"):
        stored = stored.model_dump(mode="json")
    if stored is not None and stored.get("verdict") is not None and _same_dt(dt, vdt) \
            and all(_same_dt(sc.dt, vdt) for sc in spec.scenarios):
        return str(stored["verdict"]), stored
    target = spec_at_dt(spec, dt, max_steps=max_steps)
    if robust is None and stored is not None and "robust" in stored:
        robust = stored["robust"] is not None  # as the stored verification did
    from gaintune.verify import verify

    report = verify(target, gains, robust=robust)
    return report.verdict, json.loads(report.model_dump_json())


def result_verdict_at_dt(result: Any, dt: float | None = None, *, max_steps: int | None = None) -> tuple[str, dict[str, Any] | None]:
    """:func:`verdict_at_dt` for a :class:`~gaintune.search.result.TuneResult` (its stored verification included)."""
    spec = TuningSpec.model_validate(result.spec)
    return verdict_at_dt(spec, result.gains, dt, stored=result.verification, max_steps=max_steps)


class _Stamp:
    """What a file says about verification: the verdict at the exported ``dt``."""

    def __init__(self, verdict: str | None, dt: float, verified_dt: float | None, reasons: list[str] | None) -> None:
        self.dt = dt
        self.verified_dt = verified_dt
        self.reasons = [str(r) for r in (reasons or [])]
        self.stale = verdict is not None and verified_dt is not None and not _same_dt(dt, verified_dt)
        #: the verdict that holds at ``dt`` (None: not verified at this dt)
        self.verdict = None if self.stale else verdict
        self.held = verdict  # the verdict as given (for the not-at-this-dt message)

    @property
    def accepted(self) -> bool:
        return self.verdict == "pass"

    @property
    def label(self) -> str:
        return self.verdict or "unverified"

    @property
    def reason(self) -> str:
        if self.reasons:
            return self.reasons[0]
        return "no reason recorded in the verification report"

    def banner(self) -> str:
        dt = _fmt_dt(self.dt)
        if self.verdict == "pass":
            return f"verification: PASS at dt = {dt} s"
        if self.verdict == "fail":
            return (f"verification: FAILED at dt = {dt} s - {self.reason} - these gains did not pass verification "
                    "at this sample time; do not deploy")
        if self.stale:
            return (f"verification: NOT verified at dt = {dt} s (the verdict '{self.held}' holds at dt = "
                    f"{_fmt_dt(self.verified_dt)} s only) - do not deploy; re-verify or re-tune at this sample time")
        return "verification: not run - these gains are unverified"


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _ascii(text: str) -> str:
    import unicodedata

    t = unicodedata.normalize("NFKD", _one_line(text))
    return "".join(ch for ch in t if ord(ch) < 128 and not unicodedata.combining(ch))


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


def _payload(spec: TuningSpec, gains: Gains, st: _Stamp) -> dict[str, Any]:
    coefs = loop_coefficients(spec, gains)
    return {
        "spec": spec.name,
        "spec_hash": spec.content_hash(),
        "verdict": st.label,
        "accepted": st.accepted,
        "dt": st.dt,
        "verified_dt": st.verified_dt,
        "reasons": st.reasons if st.verdict == "fail" else [],
        "gains": gains,
        "loops": _clean(coefs),
        "actuator": _clean({"limits": list(spec.actuator.limits) if spec.actuator.limits else None,
                            "rate_limit": spec.actuator.rate_limit}),
        "generator": f"gaintune {_version()}",
    }


# ------------------------------------------------------------------ formats


def _c_num(x: float) -> str:
    if math.isinf(x):
        return "INFINITY" if x > 0 else "(-INFINITY)"
    r = repr(float(x))
    return r if ("." in r or "e" in r or "n" in r) else r + ".0"


def _ident(name: str) -> str:
    s = re.sub(r"[^0-9A-Za-z_]", "_", name)
    return s if s and not s[0].isdigit() else f"_{s}"


def _c_str(text: str) -> str:
    return '"' + _ascii(text).replace("\\", "\\\\").replace('"', '\\"').replace("?", "\\?") + '"'


def _c_comment(text: str) -> str:
    return _ascii(text).replace("*/", "* /").replace("/*", "/ *")


def to_c(spec: TuningSpec, gains: Gains, st: _Stamp, dt: float, prefix: str = "gt") -> str:
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
        f" * {_c_comment(st.banner())}",
        f" * {U}_VERIFIED is 1 only when the gains passed verification at this header's sample time {U}_DT.",
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
        f"#define {U}_VERIFIED {1 if st.accepted else 0}",
        f'#define {U}_VERDICT "{st.label}"',
        f"#define {U}_VERIFIED_DT {_c_num(st.verified_dt) if st.verified_dt is not None else '0.0'}"
        + ("  /* sample time the verdict was obtained at */" if st.verified_dt is not None else "  /* 0: never verified */"),
        f"#define {U}_VERDICT_REASON {_c_str(st.reason if st.verdict == 'fail' else '')}",
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


def _m_vec(v: list[float]) -> str:
    return "[" + " ".join(_m_num(x) for x in v) + "]"


def _m_str(text: str) -> str:
    return "'" + _one_line(text).replace("'", "''") + "'"


#: MATLAB name-value pair that makes ``pid``/``pid2``/``pidstd`` use the simulator's discretisation.
M_FORMULAS = "'IFormula', 'BackwardEuler', 'DFormula', 'BackwardEuler'"


def to_matlab(spec: TuningSpec, gains: Gains, st: _Stamp, dt: float) -> str:
    """MATLAB/Octave snippet: per loop a plain struct and discrete ``tf`` objects (MATLAB and Octave), and
    discrete ``pid``/``pid2``/``pidstd`` objects with sample time ``Ts`` (MATLAB's Control System Toolbox).

    The discrete objects are exactly the simulator's law: backward Euler for the integral
    (``IFormula``) and for the filtered derivative (``DFormula``), so
    ``Ci = Ki*Ts*z/(z-1)`` and ``Cd = Kd*(z-1)/((Tf+Ts)*z - Tf)``.
    """
    coefs = loop_coefficients(spec, gains)
    out = [
        f"% Controller gains for spec '{spec.name}', generated by gaintune {_version()}",
        f"% {_one_line(st.banner())}",
        "% Loops are listed outer first; each loop's output is the next loop's setpoint.",
        "% Discrete-time law with sample time Ts, identical to gaintune's simulator (backward Euler):",
        "%   u = Kp*(b*r - y) + Ki*Ts*z/(z-1)*(r - y) + Kd*(z-1)/((Tf+Ts)*z - Tf)*(c*r - y)",
        "% i.e. u = Cr*r - Cy*y with Cy = Kp + Ki*Ts*z/(z-1) + Kd*(z-1)/((Tf+Ts)*z - Tf) and Cr the same with",
        "% setpoint weights b (on Kp) and c (on Kd). In MATLAB these are pid(..., Ts, " + M_FORMULAS + ").",
        "% MATLAB and Octave (pkg load control): struct gt_<loop>, Cy_<loop> and Cr_<loop> = tf(num, den, Ts).",
        "% MATLAB (Control System Toolbox) also: C_<loop> = pid/pid2 (parallel), Cstd_<loop> = pidstd (ideal), discrete.",
        f"Ts = {_m_num(dt)};  % sample time of this export (s)",
        f"verified_Ts = {_m_num(st.verified_dt) if st.verified_dt is not None else 'NaN'};"
        "  % sample time the verdict was obtained at (NaN: never verified)",
        f"verdict = {_m_str(st.label)};  % verification verdict at Ts",
        f"accepted = {'true' if st.accepted else 'false'};  % true only when the gains passed verification at Ts",
    ]
    if st.verdict == "fail":
        out.append(f"verdict_reason = {_m_str(st.reason)};")
    out.append("is_matlab = exist('OCTAVE_VERSION', 'builtin') == 0;  % pid, pid2, pidstd: MATLAB only")
    for c in coefs:
        v = _ident(c["name"])
        out.append(f"% --- loop {c['name']} ({c['type']}, measures {c['measure']})")
        if c["type"] in ("lqr", "lqi"):
            out += [
                f"K_{v} = [{' '.join(_m_num(k) for k in c['K'])}];  % u = u0 - K*(x - x0) + Kint*z + Nr*(r - y0); states: {', '.join(c['states'])}",
                f"Kint_{v} = {_m_num(c['Kint'])};  % z(k) = z(k-1) + Ts*(r(k) - y(k)), clamped while saturated",
                f"Nr_{v} = {_m_num(c['Nr'])};",
            ]
            continue
        fields = [("Kp", c["Kp"]), ("Ki", c["Ki"]), ("Kd", c["Kd"]), ("Tf", c["Tf"]), ("b", c["b"]), ("c", c["c"])]
        out.append(
            f"gt_{v} = struct(" + ", ".join(f"'{k}', {_m_num(x)}" for k, x in fields)
            + f", 'Ts', Ts, 'lo', {_m_num(c['lo'])}, 'hi', {_m_num(c['hi'])}, 'aw', '{c['aw']}', "
            f"'Tt', {_m_num(c['Tt']) if c['Tt'] is not None else 'Inf'}, 'i0', {_m_num(c['i0'])});"
            "  % parallel form, plain struct (no toolbox)"
        )
        out.append(f"Kp_{v} = gt_{v}.Kp; Ki_{v} = gt_{v}.Ki; Kd_{v} = gt_{v}.Kd; Tf_{v} = gt_{v}.Tf;")
        ny, dy = discrete_pid_tf(c, dt, "feedback")
        out.append(f"Cy_{v} = tf({_m_vec(ny)}, {_m_vec(dy)}, Ts);  % feedback path y -> -u")
        # MATLAB's pid is 1-DOF, u = C*(r - y): that is b = 1 and, when there is a derivative, c = 1.
        two_dof = c["b"] != 1.0 or (c["Kd"] != 0.0 and c["c"] != 1.0)
        nr, dr = discrete_pid_tf(c, dt, "setpoint")
        out.append(f"Cr_{v} = tf({_m_vec(nr)}, {_m_vec(dr)}, Ts);  % setpoint path r -> u "
                   f"(b = {_m_num(c['b'])}, c = {_m_num(c['c'])})")
        out.append("if is_matlab")
        if two_dof:
            out.append("  % pid is 1-DOF (u = C*(r - y)) and cannot hold the setpoint weights b, c: pid2 carries them"
                       " (C2 = [Cr, -Cy], inputs r and y)")
            out.append(f"  C_{v} = pid2(Kp_{v}, Ki_{v}, Kd_{v}, Tf_{v}, {_m_num(c['b'])}, {_m_num(c['c'])}, Ts, {M_FORMULAS});"
                       "  % 2-DOF, setpoint weights b, c")
            out.append(f"  Cfb_{v} = pid(Kp_{v}, Ki_{v}, Kd_{v}, Tf_{v}, Ts, {M_FORMULAS});  % feedback path (= Cy)")
        else:
            out.append(f"  C_{v} = pid(Kp_{v}, Ki_{v}, Kd_{v}, Tf_{v}, Ts, {M_FORMULAS});  % u = C*(r - y); C = Cy = Cr")
        if c["Kp"] != 0:  # pidstd takes a signed Kp with positive Ti, Td (reverse-acting loops too)
            ti = _m_num(c["Ti"])
            n = _m_num(c["N"]) if c["Kd"] * c["Kp"] > 0 else "Inf"
            out.append(f"  Cstd_{v} = pidstd(Kp_{v}, {ti}, {_m_num(c['Td'])}, {n}, Ts, {M_FORMULAS});  % ideal form (Ti, Td, N) of Cy")
        out.append("end")
        lim = f"[{_m_num(c['lo'])} {_m_num(c['hi'])}]"
        out.append(f"limits_{v} = {lim};  % output saturation; anti-windup: {c['aw']}")
    return "\n".join(out) + "\n"


def to_python(spec: TuningSpec, gains: Gains, st: _Stamp, dt: float) -> str:
    """A Python module defining ``GAINS`` (spec form) and ``LOOPS`` (resolved parallel form)."""
    p = _payload(spec, gains, st)
    doc = _one_line(st.banner()).replace("\\", "\\\\").replace('"', "'")
    return (
        f'"""Controller gains for spec {spec.name!r}, generated by gaintune {_version()}. {doc}."""\n\n'
        f"VERDICT = {p['verdict']!r}\n"
        f"ACCEPTED = {p['accepted']!r}\n"
        f"DT = {dt!r}\n"
        f"VERIFIED_DT = {st.verified_dt!r}\n"
        f"REASONS = {st.reasons if st.verdict == 'fail' else []!r}\n"
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
    verified_dt: float | None = None,
    reasons: list[str] | None = None,
) -> str:
    """Render ``gains`` of ``spec`` in format ``fmt`` (one of :data:`FORMATS`).

    ``verdict`` ("pass", "fail" or None for unverified) is the verdict obtained at sample
    time ``verified_dt`` (default: :func:`verified_dt` of ``spec``), with its ``reasons``.
    ``dt`` (default: ``verified_dt``) is the sample time the file is for. A verdict is only
    written as such when it was obtained at ``dt``; otherwise the file says the gains are
    NOT verified at ``dt`` (use :func:`export_result`, which re-verifies, to get one).
    """
    if fmt not in FORMATS:
        raise ExportError("format", f"unknown export format {fmt!r}; choose from {', '.join(FORMATS)}")
    vdt = None
    if verdict is not None:
        vdt = _check_dt(verified_dt) if verified_dt is not None else _spec_verified_dt(spec)
    dt = _check_dt(dt) if dt is not None else (vdt if vdt is not None else _spec_verified_dt(spec))
    st = _Stamp(verdict, dt, vdt, reasons)
    if fmt == "json":
        return json.dumps(_payload(spec, gains, st), indent=2) + "\n"
    if fmt == "yaml":
        return f"# {_one_line(st.banner())}\n" + yaml.safe_dump(_payload(spec, gains, st), sort_keys=False)
    if fmt == "c":
        return to_c(spec, gains, st, dt, prefix)
    if fmt == "matlab":
        return to_matlab(spec, gains, st, dt)
    return to_python(spec, gains, st, dt)


def export_result(
    result: Any,
    fmt: str,
    *,
    dt: float | None = None,
    prefix: str = "gt",
    checked: tuple[str | None, dict[str, Any] | None] | None = None,
    max_steps: int | None = None,
) -> str:
    """Export the gains of a :class:`~gaintune.search.result.TuneResult` with their verdict *at* ``dt``.

    ``dt`` defaults to the sample time the result was verified at (:func:`verified_dt`).
    At any other ``dt`` the gains are re-verified first (:func:`verdict_at_dt`); pass
    ``checked=(verdict, report)`` from an earlier :func:`result_verdict_at_dt` call with the
    same ``dt`` to skip that. Gains whose verdict at ``dt`` is not "pass" are still
    rendered (marked FAILED, with the first reason): refusing them is the caller's job.
    """
    if fmt not in FORMATS:
        raise ExportError("format", f"unknown export format {fmt!r}; choose from {', '.join(FORMATS)}")
    spec = TuningSpec.model_validate(result.spec)
    dt = verified_dt(spec) if dt is None else _check_dt(dt)
    verdict, report = checked if checked is not None else result_verdict_at_dt(result, dt, max_steps=max_steps)
    reasons = list((report or {}).get("reasons") or []) if isinstance(report, dict) else list(getattr(report, "reasons", []) or [])
    return export_gains(spec, result.gains, fmt, verdict=verdict, dt=dt, prefix=prefix,
                        verified_dt=dt if verdict is not None else None, reasons=reasons)


class ExportFiles(list):
    """The paths :func:`write_exports` wrote (a list), with what it withheld and why."""

    def __init__(self, paths=(), *, verdict: str | None = None, dt: float | None = None, reason: str | None = None,
                 withheld: tuple[str, ...] = (), removed: tuple = ()) -> None:
        super().__init__(paths)
        self.verdict = verdict
        self.dt = dt
        self.reason = reason
        self.withheld = list(withheld)  # file names not written (gains.h, gains.m, ...)
        self.removed = list(removed)  # stale copies of those deleted from the folder


def write_exports(result: Any, out_dir, formats: tuple[str, ...] = ("json", "yaml", "c", "matlab"), dt: float | None = None) -> ExportFiles:
    """Write ``gains.json``, ``gains.yaml``, ``gains.h``, ``gains.m`` (and optionally ``gains.py``) into ``out_dir``.

    The verdict is the one at ``dt`` (default: the dt the result was verified at; see
    :func:`verdict_at_dt`). Unless it is "pass", only ``gains.json``/``gains.yaml`` are
    written (marked ``accepted: false``); the files that go into a controller as they are
    (:data:`FIRMWARE_FORMATS`: ``gains.h``, ``gains.m``, ``gains.py``) are withheld, and a
    stale copy of them from an earlier run in ``out_dir`` is deleted. Returns the paths
    written (an :class:`ExportFiles` list, which also names what was withheld and why).
    """
    from pathlib import Path

    for fmt in formats:
        if fmt not in FORMATS:
            raise ExportError("format", f"unknown export format {fmt!r}; choose from {', '.join(FORMATS)}")
    spec = TuningSpec.model_validate(result.spec)
    dt = verified_dt(spec) if dt is None else _check_dt(dt)
    checked = result_verdict_at_dt(result, dt)
    verdict, report = checked
    ok = verdict == "pass"
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths, withheld, removed = [], [], []
    for fmt in formats:
        p = out / SUFFIX[fmt]
        if not ok and fmt in FIRMWARE_FORMATS:
            withheld.append(SUFFIX[fmt])
            if p.is_file():
                p.unlink()
                removed.append(p)
            continue
        p.write_text(export_result(result, fmt, dt=dt, checked=checked))
        paths.append(p)
    return ExportFiles(paths, verdict=verdict, dt=dt, reason=None if ok else (first_reason(report) or None),
                       withheld=tuple(withheld), removed=tuple(removed))
