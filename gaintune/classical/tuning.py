"""Apply a classical rule to every loop of a spec, innermost loop first.

The innermost loop sees the plant path from the actuator to its measured
output (exact delay). Once tuned, it is closed (2-DOF PID with the loop's
b, c weights and derivative filter, the plant delay as a Pade approximation
of order :data:`PADE_ORDER`), and the next loop out sees the path from the
inner setpoint to its own measured output; an FOTD model is fitted to that
path (step-response fit, as its poles are rarely all real), and so on.

Half the sample time of the fastest scenario is added to every loop's
apparent delay: a sampled controller with zero-order hold delays by about
dt/2 (Skogestad 2003); it also keeps the rules finite for delay-free plants.

Every loop's gains take the sign of its direction
(:func:`gaintune.controllers.direction.loop_directions`): the rule gives the
magnitudes (from ``|K|``), the direction the sign, so a reverse-acting loop gets
Kp, Ki, Kd < 0 and the next loop out sees its inner loop correctly closed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gaintune.classical.fotd import Fotd, NoModelError, fit_fotd, siso_minreal
from gaintune.classical.rules import FOTD_RULES, IdealPid, to_loop_gains, ultimate_gain, with_direction, zn_ultimate
from gaintune.classical.timescale import resolve_scenarios
from gaintune.controllers.direction import loop_directions
from gaintune.lti.statespace import StateSpace, with_input_delay
from gaintune.spec import Gains, TuningSpec

__all__ = ["ClassicalResult", "tune_classical", "rule_candidates", "auto_bounds", "PADE_ORDER", "BOUNDS_FACTOR",
           "CLASSICAL_METHODS"]

#: Pade order used to close loops around a delayed plant.
PADE_ORDER = 6
#: auto_bounds span: [g/BOUNDS_FACTOR, g*BOUNDS_FACTOR] around the rule's gain g.
BOUNDS_FACTOR = 30.0
CLASSICAL_METHODS = ("zn_step", "zn_ultimate", "simc", "amigo", "imc")


@dataclass
class ClassicalResult:
    """Gains per loop plus the models the rule used."""

    gains: Gains
    fotd: dict[str, Fotd] = field(default_factory=dict)
    ultimate: dict[str, tuple[float, float]] = field(default_factory=dict)
    pid: dict[str, IdealPid] = field(default_factory=dict)


def _with_input_delay(sys: StateSpace, delay: float) -> StateSpace:
    """Series of a Pade approximation of e^{-delay s} and ``sys`` (single input, any outputs)."""
    return with_input_delay(sys, delay, PADE_ORDER)


def _pid_ss(loop, gains: dict[str, float]) -> StateSpace:
    """2-DOF controller u = Kp (b r - y) + Ki/s (r - y) + Kd s/(Tf s + 1) (c r - y); inputs [r, y]."""
    from gaintune.controllers.pid import pid_params

    p = pid_params(loop, gains)
    # States: integral of r - y (when Ki != 0) and the derivative filter (when Kd != 0); the
    # gains are signed (negative for a reverse-acting loop).
    A, B, C = [], [], []
    D = [p.b * p.Kp, -p.Kp]
    if p.Ki != 0:
        A.append([0.0])
        B.append([1.0, -1.0])
        C.append(p.Ki)
    if p.Kd != 0:
        if not p.Tf > 0:
            raise NoModelError(f"{loop.name}", "a derivative term needs a filter time constant Tf > 0")
        A.append([-1.0 / p.Tf])
        B.append([p.c / p.Tf, -1.0 / p.Tf])
        C.append(-p.Kd / p.Tf)
        D = [D[0] + p.c * p.Kd / p.Tf, D[1] - p.Kd / p.Tf]
    n = len(A)
    Am = np.diag([row[0] for row in A]) if n else np.zeros((0, 0))
    Bm = np.array(B, float).reshape(n, 2)
    Cm = np.array(C, float).reshape(1, n)
    return StateSpace(Am, Bm, Cm, np.array([D], float))


def _close(sys: StateSpace, m: int, K: StateSpace) -> StateSpace:
    """Close u = K [r; y_m] around ``sys`` (u -> all outputs); returns r -> all outputs."""
    A, B, C, D = (np.asarray(x, float) for x in (sys.A, sys.B, sys.C, sys.D))
    Ak, Bk, Ck, Dk = (np.asarray(x, float) for x in (K.A, K.B, K.C, K.D))
    nk = Ak.shape[0]
    Bkr, Bky = Bk[:, :1], Bk[:, 1:2]
    dkr, dky = Dk[0, 0], Dk[0, 1]
    Cm, dm = C[m : m + 1, :], D[m, 0]
    s = 1.0 - dky * dm
    if abs(s) < 1e-12:
        raise NoModelError("loops", "the loop is algebraically ill-posed (direct feedthrough)")
    # u = (Ck xc + dkr r + dky Cm x) / s
    Ux, Uc, Ur = dky * Cm / s, Ck / s, dkr / s
    if nk:
        Acl = np.block([[A + B @ Ux, B @ Uc], [Bky @ (Cm + dm * Ux), Ak + dm * Bky @ Uc]])
    else:
        Acl = A + B @ Ux
    Bcl = np.vstack([B * Ur, Bkr + Bky * dm * Ur]) if nk else B * Ur
    Ccl = np.hstack([C + D @ Ux, D @ Uc]) if nk else C + D @ Ux
    Dcl = D * Ur
    return StateSpace(Acl, Bcl, Ccl, Dcl)


def _fixed_overrides(loop, gains: dict[str, float]) -> dict[str, float]:
    out = dict(gains)
    for name, g in loop.gains.items():
        if not g.tune and g.value is not None and name in out:
            out[name] = float(g.value)
    return out


def sample_time(spec: TuningSpec) -> float:
    """The shortest scenario sample time of a spec whose ``dt`` are resolved (:func:`resolve_scenarios`).

    Raises
    ------
    ValueError
        When a scenario's ``dt`` is still unset.
    """
    dts = [sc.dt for sc in spec.scenarios]
    if any(dt is None for dt in dts):
        raise ValueError("sample_time needs resolved scenarios (resolve_scenarios): a dt is unset")
    return min(dt for dt in dts if dt is not None)


def tune_classical(spec: TuningSpec, plant, method: str, params: dict[str, float] | None = None) -> ClassicalResult:
    """Gains from rule ``method`` for every loop (innermost first), at nominal (or given) parameters.

    Fixed gains (``tune: false``) keep their spec value, also when closing inner loops. The
    gains of every loop have the sign of its direction (negative for a reverse-acting loop).

    Raises
    ------
    NoModelError
        When a loop is LQ, or no FOTD model / rule applies to some loop (the message says which and why).
    SpecError
        When a loop's ``direction: auto`` cannot be resolved.
    """
    if method not in CLASSICAL_METHODS:
        raise ValueError(f"unknown classical method {method!r}; choose from {CLASSICAL_METHODS}")
    if any(lp.is_lq for lp in spec.loops):
        j = next(i for i, lp in enumerate(spec.loops) if lp.is_lq)
        lp = spec.loops[j]
        raise NoModelError(
            f"loops[{j}]", f"{lp.type} loop {lp.name!r}: no classical rule (LQ loops are tuned by Riccati)"
        )
    directions = loop_directions(spec, plant)
    lin = plant.linearize(params)
    h2 = 0.5 * sample_time(resolve_scenarios(spec, plant))
    sys = StateSpace(lin.A, lin.B, lin.C, lin.D)
    delay = float(lin.delay)
    res = ClassicalResult(gains={})
    for j in range(len(spec.loops) - 1, -1, -1):
        loop = spec.loops[j]
        name = loop.name or f"loop{j}"
        if loop.is_lq:
            raise NoModelError(
                f"loops[{j}]", f"{loop.type} loop {name!r}: no classical rule (LQ loops are tuned by Riccati)"
            )
        m = lin.output_index(loop.measure) if loop.measure else 0
        siso = siso_minreal(StateSpace(sys.A, sys.B, sys.C[m : m + 1, :], sys.D[m : m + 1, :]))
        if method == "zn_ultimate":
            try:
                Ku, Pu = ultimate_gain(siso, delay + h2)
            except NoModelError as exc:
                raise NoModelError(f"loops[{j}] ({name})", exc.message) from None
            res.ultimate[name] = (Ku, Pu)
            pid = zn_ultimate(Ku, Pu, loop.type)
        else:
            try:
                model = fit_fotd(siso, delay).with_extra_delay(h2)
                res.fotd[name] = model
                pid = FOTD_RULES[method](model, loop.type)
            except NoModelError as exc:
                raise NoModelError(f"loops[{j}] ({name})", exc.message) from None
        pid = with_direction(pid, directions[j])
        res.pid[name] = pid
        gains = _fixed_overrides(loop, to_loop_gains(pid, loop))
        res.gains[name] = gains
        if j > 0:
            sys = _close(_with_input_delay(sys, delay), m, _pid_ss(loop, gains))
            delay = 0.0
    res.gains = {(lp.name or f"loop{i}"): res.gains[lp.name or f"loop{i}"] for i, lp in enumerate(spec.loops)}
    return res


def rule_candidates(spec: TuningSpec, plant) -> dict[str, Gains]:
    """Every classical rule that applies to this spec, as ``{method: {loop: {gain: value}}}``.

    Each is applied inner loop first (:func:`tune_classical`). Rules that do not apply
    (LQ loops, unstable or oscillatory paths, ...) are left out; ``{}`` when none does.
    """
    out = {}
    for method in CLASSICAL_METHODS:
        try:
            out[method] = tune_classical(spec, plant, method).gains
        except (NoModelError, ValueError, np.linalg.LinAlgError):
            continue
    return out


def auto_bounds(spec: TuningSpec, centre: Gains, factor: float = BOUNDS_FACTOR
                ) -> dict[tuple[str, str], tuple[float, float]]:
    """Log-scale search bounds ``{(loop, gain): (|g|/factor, |g|*factor)}`` around the gain set ``centre``.

    ``factor`` (default 30, about three decades in all) is wide enough to contain the
    cost-optimal gains of every benchmark process we checked. Fixed gains are skipped.
    The bounds are magnitudes (a reverse-acting loop's gains are negative; the layout
    searches their magnitudes). Which gain set to centre on is decided above this
    layer, by the requirements (:mod:`gaintune.evaluation.search_box`).
    """
    out: dict[tuple[str, str], tuple[float, float]] = {}
    for loop in spec.loops:
        if loop.name is None:  # the centre's keys are loop names: an unnamed loop has none
            continue
        for gname, v in centre.get(loop.name, {}).items():
            g = loop.gains.get(gname)
            if g is not None and not g.tune:
                continue
            v = abs(v)
            if math.isfinite(v) and v > 0:
                out[(loop.name, gname)] = (v / factor, v * factor)
    return out
