"""Controller action (direct or reverse) of every loop of a cascade.

A loop is *direct-acting* when its gains are positive and *reverse-acting*
when ``Kp``, ``Ki`` and ``Kd`` are all negative (ideal form: ``Kp`` negative,
``Ti`` and ``Td`` positive). ``loops[i].direction: auto`` (the default) reads
the sign from the plant, at the nominal operating point (nonlinear plants:
their linearisation there):

* **innermost loop** - the path from the actuator to the loop's measured
  output, ``G(s)``. Around ``s = 0`` it behaves as ``K s^m``:

  - ``m = 0``: the sign of the **static gain** ``K = G(0)``;
  - ``m < 0`` (integrating path, ``G ~ K/s``): the sign of the **velocity gain** ``K``;
  - ``m > 0`` (a zero at ``s = 0``: zero static gain): undecidable - a
    :class:`~gaintune.errors.SpecError` asks for ``direction``.

  An open-loop unstable path with an odd number of real right-half-plane poles
  is stabilised by the *opposite* sign of its static gain (``1/(s - 1)`` has
  static gain -1 and needs ``Kp > 1``): the sign used is that of the numerator
  at ``s = 0`` with a monic denominator, which the closed-loop characteristic
  polynomial's constant term requires (it is the static-gain sign for stable
  paths).
* **outer loop** - the path from its inner loop's setpoint to its own output,
  inner loops closed. A stable inner loop holds its output at its setpoint in
  steady state (integral action; without it at a positive fraction of it), so
  the sign is that of the ratio ``y_outer/y_inner`` of the plant's responses to
  the actuator near ``s = 0``: the ratio of static gains, or of velocity gains
  when the ratio integrates (position over speed = ``1/s``).

Behind a static decoupler ``u = W v`` (``spec.decoupler``) a loop's output reaches the plant
through the column of ``W`` at the input its chain drives, so the paths above are read from that
column, ``G(s) W[:, j]``, instead of input j alone (a single-input plant: ``G`` times its 1 x 1
``W``). A tuned entry is read at the value the search starts from (its ``value``, else its bounds'
geometric centre); its bounds have one sign, so the entry itself never changes sign, but a
candidate far from the start may flip the column's path: that candidate's loop is wrongly signed,
unstable, and rejected by the verification like any other unstable candidate.

When plant parameters are randomised the sign must be the same at every
corner of the ``randomize.params`` box (one parameter at a time when there are
more than :data:`MAX_CORNER_PARAMS`); a sign change is a ``SpecError`` too.
LQ loops have no direction (their ``K`` takes any sign).

This module imports only the spec, the plants and the errors (the layout
below the simulator, verification and search must not depend on them).
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from gaintune.errors import SpecError
from gaintune.lti.statespace import StateSpace, one_stable_lag
from gaintune.spec import TuningSpec

__all__ = ["LoopDirection", "PathGain", "path_gain", "resolve_directions", "loop_directions", "MAX_CORNER_PARAMS"]

#: Up to this many randomised parameters every corner of the box is checked; beyond, one at a time.
MAX_CORNER_PARAMS = 6

# Roots within this fraction of the largest root magnitude count as at s = 0 (a k-fold root at the
# origin scatters by about eps^(1/k) in eig()); the expansion is read at 1e-3 of the nearest other root.
_ORIGIN_REL = 1e-6
_EPS_REL = 1e-3


@dataclass(frozen=True)
class PathGain:
    """Leading term ``coef * s^order`` of a SISO path near ``s = 0``, and its real unstable poles."""

    order: int
    coef: float
    rhp_real: int

    @property
    def stabilising_sign(self) -> int:
        """Sign a controller needs: sign(coef) flipped once per real right-half-plane pole."""
        return (1 if self.coef > 0 else -1) * (-1) ** self.rhp_real


@dataclass(frozen=True)
class LoopDirection:
    """Resolved action of one loop: ``sign`` (+1 direct, -1 reverse), where it came from and why."""

    sign: int
    source: str  # "auto", "set" (direction: direct/reverse) or "lq"
    rule: str  # "static_gain", "velocity_gain", "unstable", "set", "lq"
    gain: float | None  # the gain the sign was read from (auto only)
    reason: str  # e.g. "plant static gain -2"

    @property
    def word(self) -> str:
        """``direct-acting`` or ``reverse-acting``."""
        return "direct-acting" if self.sign > 0 else "reverse-acting"

    @property
    def other(self) -> str:
        """The opposite direction's spec word (``direct`` or ``reverse``)."""
        return "reverse" if self.sign > 0 else "direct"


# ------------------------------------------------------------------ paths


def _resp(A: np.ndarray, b: np.ndarray, c: np.ndarray, d: float, s: float) -> float:
    n = A.shape[0]
    return float(c @ np.linalg.solve(s * np.eye(n) - A, b) + d) if n else float(d)


def _controllable_observable(A: np.ndarray, b: np.ndarray, c: np.ndarray, p: complex) -> bool:
    """PBH test: is the mode at eigenvalue ``p`` both controllable from b and observable from c?"""
    n = A.shape[0]
    M = A - p * np.eye(n)
    for X in (np.hstack([M, b[:, None]]), np.vstack([M, c[None, :]])):
        sv = np.linalg.svd(X, compute_uv=False)
        if sv[-1] <= 1e-9 * max(sv[0], 1e-300):
            return False
    return True


def path_gain(A: np.ndarray, b: np.ndarray, c: np.ndarray, d: float) -> PathGain | None:
    """Leading term of ``G(s) = c (sI - A)^-1 b + d`` near s = 0, or None when it cannot be read.

    None means G is identically zero (the output does not respond) or the
    expansion is numerically undecidable (roots too close to the origin).
    """
    A, b, c = np.asarray(A, float), np.asarray(b, float).ravel(), np.asarray(c, float).ravel()
    d = float(d)
    n = A.shape[0]
    if n == 0:
        return PathGain(0, d, 0) if d != 0 else None
    if one_stable_lag(A, b, c, np.array([d])) is not None:
        # the expansion below reads order 0 and takes the exact static gain (~0.2 ms saved)
        return PathGain(0, float(d - c @ np.linalg.solve(A, b)), 0)
    path = StateSpace(A, b[:, None], c[None, :], np.array([[d]]))
    poles = path.poles()
    with np.errstate(all="ignore"):
        zeros = path.zeros()  # the Rosenbrock pencil's finite generalized eigenvalues
    zeros = zeros[np.isfinite(zeros)]
    mags = np.abs(np.concatenate([poles, zeros]))
    scale = float(mags.max()) if mags.size and mags.max() > 0 else 1.0
    far = mags[mags > _ORIGIN_REL * scale]
    eps = _EPS_REL * (float(far.min()) if far.size else scale)
    g1, g2 = _resp(A, b, c, d, eps), _resp(A, b, c, d, eps / 10.0)
    if not (math.isfinite(g1) and math.isfinite(g2)) or g1 == 0 or g2 == 0 or (g1 > 0) != (g2 > 0):
        return None
    slope = math.log10(abs(g1 / g2))  # |G| ~ |K| eps^m: one decade of s changes it by m decades
    order = int(round(slope))
    if abs(slope - order) > 0.25:
        return None
    # G/s^m = K (1 + a s + ...): one Richardson step removes the first-order term
    coef = (10.0 * g2 / (eps / 10.0) ** order - g1 / eps**order) / 9.0
    if order == 0 and np.linalg.cond(A) < 1e10:
        exact = float(d - c @ np.linalg.solve(A, b))  # the static gain itself, when A is invertible
        if exact * coef > 0:
            coef = exact
    rhp = 0
    tol_re = _ORIGIN_REL * scale
    for p in poles:
        if p.real > tol_re and abs(p.imag) <= 1e-6 * abs(p) and _controllable_observable(A, b, c, p.real):
            rhp += 1
    return PathGain(order, float(coef), rhp)


def _outputs_gain(lin: Any, m: int) -> PathGain | None:
    return path_gain(lin.A, lin.B[:, 0], lin.C[m], lin.D[m, 0])


def measured_indices(spec: TuningSpec, outputs: list[str]) -> list[int]:
    """Output index measured by each loop (default: the first output); SpecError naming an unknown one."""
    idx = []
    for i, loop in enumerate(spec.loops):
        name = loop.measure or outputs[0]
        if name not in outputs:
            raise SpecError(f"loops[{i}].measure", f"unknown output {name!r}; the plant has {outputs}")
        idx.append(outputs.index(name))
    return idx


def _g(x: float) -> str:
    return f"{x:.4g}"


class _Undecided(Exception):
    """The plant does not decide a loop's sign (internal; becomes a SpecError naming the loop)."""


def _undecided(i: int, why: str) -> SpecError:
    return SpecError(
        f"loops[{i}].direction",
        f"cannot tell this loop's action from the plant: {why}; set direction: direct (positive gains) "
        "or direction: reverse (negative gains)",
    )


def _innermost_rule(gi: PathGain, out: str) -> tuple[int, str, float, str]:
    """(sign, rule, gain, reason) of the innermost loop from its path's leading term; _Undecided(why)."""
    if gi.order > 0:
        power = "s" if gi.order == 1 else f"s^{gi.order}"
        raise _Undecided(f"the static gain from the actuator to {out!r} is zero (G ~ {_g(gi.coef)} {power})")
    if gi.order == 0:
        if gi.rhp_real % 2:
            return (
                gi.stabilising_sign, "unstable", gi.coef,
                f"plant static gain {_g(gi.coef)} with {gi.rhp_real} real unstable pole(s): "
                "only the opposite sign can stabilise it",
            )
        return gi.stabilising_sign, "static_gain", gi.coef, f"plant static gain {_g(gi.coef)}"
    power = "s" if gi.order == -1 else f"s^{-gi.order}"
    flip = f", {gi.rhp_real} real unstable pole(s)" if gi.rhp_real % 2 else ""
    return (
        gi.stabilising_sign, "velocity_gain", gi.coef,
        f"integrating plant, velocity gain {_g(gi.coef)} (G ~ {_g(gi.coef)}/{power}{flip})",
    )


def _loop_rule(spec: TuningSpec, lin: Any, meas: list[int], i: int) -> tuple[int, str, float, str]:
    """(sign, rule, gain, reason) of loop i read from one linear model; _Undecided(why) when it cannot."""
    outputs = lin.outputs
    last = len(spec.loops) - 1
    out = outputs[meas[i]]
    gi = _outputs_gain(lin, meas[i])
    if gi is None:
        raise _Undecided(f"output {out!r} shows no readable response to the actuator near s = 0")
    if i == last:
        w = _siso_decoupler(spec)
        if w == 0:
            raise _Undecided("the decoupler's gain is 0")
        # the loop's output reaches the actuator times w
        sign, rule, gain, reason = _innermost_rule(PathGain(gi.order, gi.coef * w, gi.rhp_real), out)
        return sign, rule, gain, reason + (f" (the plant's times the decoupler's gain {_g(w)})" if w != 1 else "")
    inner = outputs[meas[i + 1]]
    gn = _outputs_gain(lin, meas[i + 1])
    if gn is None:
        raise _Undecided(f"the inner output {inner!r} shows no readable response to the actuator")
    order, coef = gi.order - gn.order, gi.coef / gn.coef
    sign = 1 if coef > 0 else -1
    if order > 0:
        raise _Undecided(
            f"the static gain from the inner setpoint ({inner}) to {out!r} with the inner loop closed is zero"
        )
    if order == 0:
        return sign, "static_gain", coef, (
            f"static gain {_g(coef)} from the inner setpoint to {out!r} with the inner loop closed "
            f"(the plant's static-gain ratio {out}/{inner})"
        )
    power = "s" if order == -1 else f"s^{-order}"
    return sign, "velocity_gain", coef, (
        f"integrating path from the inner setpoint to {out!r} with the inner loop closed, "
        f"velocity gain {_g(coef)} ({out}/{inner} ~ {_g(coef)}/{power})"
    )


def _siso_decoupler(spec: TuningSpec) -> float:
    """A single-input plant's 1 x 1 decoupler gain (its start value when tuned), 1 without one."""
    from gaintune.spec.blocks import entry_value

    return entry_value(spec.decoupler.matrix[0][0]) if spec.decoupler is not None else 1.0


def _is_mimo(spec: TuningSpec, plant: Any) -> bool:
    from gaintune.plants.plant import is_mimo_plant

    return is_mimo_plant(plant) or any(lp.drives is not None for lp in spec.loops)


def _entry_gain(lti: Any, o: int, col: dict[int, float]) -> PathGain | None:
    """The low-frequency behaviour ``K s^m`` of the path from the input combination ``col`` ({input: weight},
    a decoupler's column or one input) to output o of a MIMO form; delays do not change it."""
    from gaintune.lti.mimo import TfMatrix, block_diag

    if isinstance(lti, TfMatrix):  # the entries of row o in parallel, each weighted
        parts = [(w, lti.entries[o][j].realisation()) for j, w in col.items()
                 if w != 0 and not lti.entries[o][j].is_zero]
        if not parts:
            return None
        A = block_diag(*[p[0] for _, p in parts])
        b = np.concatenate([w * p[1][:, 0] for w, p in parts])
        c = np.concatenate([p[2][0] for _, p in parts])
        return path_gain(A, b, c, sum(w * float(p[3][0, 0]) for w, p in parts))
    w = np.zeros(lti.B.shape[1])
    for j, v in col.items():
        w[j] = v
    return path_gain(lti.A, lti.B @ w, lti.C[o], float(lti.D[o] @ w))


def _column(spec: TuningSpec, inputs: list[str], j: int) -> tuple[dict[int, float], str]:
    """How a loop output that drives input j reaches the plant: {input: weight} and a note for the reason.

    Through a decoupler ``u = W v`` that is column ``W[:, j]``, tuned entries at the value the search
    starts from (their spec value, else their bounds' geometric centre); else input j alone.
    """
    from gaintune.spec.blocks import entry_value, is_tuned

    dec = spec.decoupler
    if dec is None or inputs[j] not in dec.inputs:
        return {j: 1.0}, ""
    b = dec.inputs.index(inputs[j])
    col = {inputs.index(dec.inputs[a]): entry_value(row[b]) for a, row in enumerate(dec.matrix)}
    tuned = [f"decoupler.matrix[{a}][{b}]" for a, row in enumerate(dec.matrix) if is_tuned(row[b])]
    terms = ""
    for i, w in col.items():
        if w != 0:
            body = inputs[i] if abs(w) == 1 else f"{_g(abs(w))} {inputs[i]}"
            terms += (f" {'-' if w < 0 else '+'} " if terms else ("-" if w < 0 else "")) + body
    start = f"; tuned {', '.join(tuned)} at the search's start value" if tuned else ""
    return col, f" through the decoupler's column ({terms or '0'}{start})"


def _mimo_direction(spec: TuningSpec, plant: Any, i: int) -> LoopDirection:
    """Loop i's action on a MIMO plant (or a loop graph), read as the single-input rules read a cascade.

    A loop driving an input: the path from the input its chain ends on (through the decoupler's
    column at that input, when there is one) to its output, ``K s^m`` (static gain for m = 0,
    velocity gain for an integrating path). A loop driving another loop's setpoint: the ratio of its
    path to the inner loop's (the inner loop closed): static gains, or velocity gains when the ratio
    integrates.
    """
    from gaintune.plants.mimo import as_mimo
    from gaintune.spec.mimo import chain_input, drive_target

    mp = as_mimo(plant)
    lti = mp.lti()
    names, loop = spec.loop_names, spec.loops[i]
    j = mp.input_names.index(chain_input(spec, i) or mp.input_names[0])
    o = mp.outputs.index(loop.measure or mp.outputs[0])
    kind, target = drive_target(loop.drives) if loop.drives is not None else ("input", "")
    if loop.drives is None and i + 1 < len(spec.loops):
        kind, target = "loop", names[i + 1]
    col, note = _column(spec, mp.input_names, j)
    gi = _entry_gain(lti, o, col)
    src = f"{names[i]}'s output" if note else mp.input_names[j]
    path = f"from {src} to {mp.outputs[o]}{note}"
    if gi is None:
        raise _undecided(i, f"the path {path} shows no readable response near s = 0")
    order, coef = gi.order, gi.coef
    if kind == "loop":
        inner = spec.loops[names.index(target)]
        o2 = mp.outputs.index(inner.measure or mp.outputs[0])
        gn = _entry_gain(lti, o2, col)
        if gn is None or gn.coef == 0:
            raise _undecided(i, f"the inner loop's output {mp.outputs[o2]!r} shows no readable response to "
                             f"{mp.input_names[j]}{note}")
        order, coef = gi.order - gn.order, gi.coef / gn.coef
        path = f"from the setpoint of {target} to {mp.outputs[o]} ({target} closed{note})"
    if order > 0 or not np.isfinite(coef) or coef == 0:
        raise _undecided(i, f"the static gain {path} is zero")
    if order == 0:
        return LoopDirection(1 if coef > 0 else -1, "auto", "static_gain", coef, f"static gain {_g(coef)} {path}")
    power = "s" if order == -1 else f"s^{-order}"
    return LoopDirection(1 if coef > 0 else -1, "auto", "velocity_gain", coef,
                         f"integrating path {path}, velocity gain {_g(coef)} (~ {_g(coef)}/{power})")


def _corners(spec: TuningSpec, plant: Any) -> list[dict[str, float]]:
    box = {k: d.box for k, d in spec.randomize.params.items() if k in plant.params}
    if not box:
        return []
    names = list(box)
    if len(names) <= MAX_CORNER_PARAMS:
        return [dict(zip(names, vals, strict=True)) for vals in itertools.product(*(box[k] for k in names))]
    return [{k: v} for k in names for v in box[k]]


def _compute(spec: TuningSpec, plant: Any) -> tuple[LoopDirection, ...]:
    out: list[LoopDirection | None] = [None] * len(spec.loops)
    auto = []
    for i, loop in enumerate(spec.loops):
        if loop.is_lq:
            if loop.direction == "reverse":
                raise SpecError(f"loops[{i}].direction", f"direction: reverse does not apply to an {loop.type} loop")
            out[i] = LoopDirection(1, "lq", "lq", None, "state feedback (no controller sign)")
        elif loop.direction != "auto":
            sign = 1 if loop.direction == "direct" else -1
            out[i] = LoopDirection(sign, "set", "set", None, f"set by loops[{i}].direction: {loop.direction}")
        else:
            auto.append(i)
    if auto and _is_mimo(spec, plant):  # several inputs or a loop graph: the sign of the loop's path at s = 0
        out = [_mimo_direction(spec, plant, i) if i in auto else d for i, d in enumerate(out)]
        auto = []
    if auto:
        lin = plant.linearize()
        meas = measured_indices(spec, lin.outputs)
        found = {}
        for i in auto:
            try:
                found[i] = _loop_rule(spec, lin, meas, i)
            except _Undecided as exc:
                raise _undecided(i, str(exc)) from None
        for corner in _corners(spec, plant):
            try:
                lin_c = plant.linearize(corner)
            except SpecError:  # an invalid corner is reported by the plant checks, not here
                continue
            at = ", ".join(f"{k} = {_g(v)}" for k, v in corner.items())
            for i in auto:
                sign, rule, gain, _ = found[i]
                try:
                    sign_c, _, gain_c, _ = _loop_rule(spec, lin_c, meas, i)
                except _Undecided as exc:
                    raise _undecided(i, f"at the randomize.params corner {at}, {exc}") from None
                if sign_c != sign:
                    word = rule.replace("_", " ")
                    raise _undecided(
                        i,
                        f"the {word} changes sign over the randomize.params box ({_g(gain)} at nominal, "
                        f"{_g(gain_c)} at {at})",
                    )
        for i, (sign, rule, gain, reason) in found.items():
            out[i] = LoopDirection(sign, "auto", rule, gain, reason)
    return tuple(d for d in out if d is not None)


# ------------------------------------------------------------------ public

_CACHE: dict[str, tuple[LoopDirection, ...]] = {}


def _key(spec: TuningSpec) -> str:
    loops = [(lp.measure, lp.type, lp.direction, lp.drives) for lp in spec.loops]
    box = {k: d.box for k, d in spec.randomize.params.items()}
    dec = spec.decoupler.model_dump(mode="json") if spec.decoupler is not None else None  # it sets the paths
    return json.dumps([spec.plant.model_dump(mode="json"), loops, box, dec], sort_keys=True, default=str)


def resolve_directions(spec: TuningSpec, plant: Any = None) -> tuple[LoopDirection, ...]:
    """:class:`LoopDirection` of every loop (outer first), memoised per plant, loops and randomisation box.

    ``plant`` is the spec's built plant (built here when omitted and needed).

    Raises
    ------
    SpecError
        ``loops[i].direction`` when ``auto`` cannot decide (zero static gain, a sign that changes
        over the randomised parameters, no response), or ``reverse`` is set on an LQ loop.
    """
    needs_plant = any(not lp.is_lq and lp.direction == "auto" for lp in spec.loops)
    key = _key(spec)
    hit = _CACHE.get(key)
    if hit is not None:
        return hit
    if needs_plant and plant is None:
        from gaintune.plants import build_plant

        plant = build_plant(spec.plant)
    res = _compute(spec, plant)
    if len(_CACHE) > 256:
        _CACHE.clear()
    _CACHE[key] = res
    return res


def loop_directions(spec: TuningSpec, plant: Any = None) -> tuple[int, ...]:
    """+1 (direct) or -1 (reverse) per loop, outer first; see :func:`resolve_directions`."""
    return tuple(d.sign for d in resolve_directions(spec, plant))
