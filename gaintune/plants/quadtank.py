"""Johansson's quadruple-tank process: operating point, linearisation and the nonlinear ODE as data.

K. H. Johansson, "The quadruple-tank process: a multivariable laboratory process with an
adjustable zero", IEEE Trans. Control Systems Technology 8(3), 456-465, 2000.

Two pumps feed four tanks. Pump i (voltage ``v_i``, flow ``k_i v_i``) sends the fraction
``gamma_i`` to a lower tank and the rest to the upper tank on the other side; the upper tanks
drain into the lower ones, and the lower levels are measured as ``y_i = kc h_i`` (volts)::

    dh1/dt = -a1/A1*sqrt(2*g*h1) + a3/A1*sqrt(2*g*h3) + gamma1*k1/A1*v1
    dh2/dt = -a2/A2*sqrt(2*g*h2) + a4/A2*sqrt(2*g*h4) + gamma2*k2/A2*v2
    dh3/dt = -a3/A3*sqrt(2*g*h3) + (1 - gamma2)*k2/A3*v2
    dh4/dt = -a4/A4*sqrt(2*g*h4) + (1 - gamma1)*k1/A4*v1

:data:`ODE_RHS` and :data:`ODE_OUTPUTS` hold the same equations as expression strings in the
syntax of :class:`gaintune.spec.plant.OdeSpec` (``sqrt(max(h, 0))`` keeps an empty tank finite),
for a ``models/`` file once ODE plants take several inputs. Units: cm, s, V, cm^2, cm^3/(V s).

Linearised about an operating point, with ``T_i = A_i/a_i sqrt(2 h_i0/g)``,
``c1 = T1 k1 kc/A1`` and ``c2 = T2 k2 kc/A2``::

    G(s) = [[gamma1 c1/(1 + s T1),                      (1 - gamma2) c1/((1 + s T3)(1 + s T1))],
            [(1 - gamma1) c2/((1 + s T4)(1 + s T2)),     gamma2 c2/(1 + s T2)]]

whose transmission zeros solve ``(1 + s T3)(1 + s T4) = (1 - gamma1)(1 - gamma2)/(gamma1 gamma2)``:
both in the left half-plane when ``gamma1 + gamma2 > 1`` (minimum phase), one in the right
half-plane when ``gamma1 + gamma2 < 1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gaintune.lti.mimo import TfEntry, TfMatrix

__all__ = ["QuadTankParams", "OperatingPoint", "MIN_PHASE", "NON_MIN_PHASE", "PAPER_OPERATING_POINTS",
           "ODE_STATES", "ODE_INPUTS", "ODE_RHS", "ODE_OUTPUTS", "operating_point", "levels_point",
           "time_constants", "linearise", "transmission_zeros"]

#: State names, input names and the nonlinear model as OdeSpec expression strings.
ODE_STATES = ("h1", "h2", "h3", "h4")
ODE_INPUTS = ("v1", "v2")
ODE_RHS = {
    "h1": "(-a1*sqrt(2*g*max(h1, 0)) + a3*sqrt(2*g*max(h3, 0)) + gamma1*k1*v1)/A1",
    "h2": "(-a2*sqrt(2*g*max(h2, 0)) + a4*sqrt(2*g*max(h4, 0)) + gamma2*k2*v2)/A2",
    "h3": "(-a3*sqrt(2*g*max(h3, 0)) + (1 - gamma2)*k2*v2)/A3",
    "h4": "(-a4*sqrt(2*g*max(h4, 0)) + (1 - gamma1)*k1*v1)/A4",
}
ODE_OUTPUTS = {"y1": "kc*h1", "y2": "kc*h2"}


@dataclass(frozen=True)
class QuadTankParams:
    """Physical parameters (Johansson 2000) and one valve setting."""

    gamma1: float
    gamma2: float
    k1: float
    k2: float
    A: tuple[float, float, float, float] = (28.0, 32.0, 28.0, 32.0)
    a: tuple[float, float, float, float] = (0.071, 0.057, 0.071, 0.057)
    kc: float = 0.5
    g: float = 981.0

    def values(self) -> dict[str, float]:
        """The parameters by the names :data:`ODE_RHS` uses."""
        out = {"gamma1": self.gamma1, "gamma2": self.gamma2, "k1": self.k1, "k2": self.k2, "kc": self.kc, "g": self.g}
        out |= {f"A{i + 1}": v for i, v in enumerate(self.A)} | {f"a{i + 1}": v for i, v in enumerate(self.a)}
        return out


#: The paper's two settings: P- (minimum phase) and P+ (non-minimum phase).
MIN_PHASE = QuadTankParams(gamma1=0.70, gamma2=0.60, k1=3.33, k2=3.35)
NON_MIN_PHASE = QuadTankParams(gamma1=0.43, gamma2=0.34, k1=3.14, k2=3.29)

#: The paper's operating points: measured levels h0 (cm), pump voltages v0 (V), time constants T (s).
PAPER_OPERATING_POINTS = {
    "min_phase": {"h0": (12.4, 12.7, 1.8, 1.4), "v0": (3.00, 3.00), "T": (62, 90, 23, 30)},
    "non_min_phase": {"h0": (12.6, 13.0, 4.8, 4.9), "v0": (3.15, 3.15), "T": (63, 91, 39, 56)},
}


@dataclass(frozen=True)
class OperatingPoint:
    """Steady state: levels ``h`` (cm) and pump voltages ``v`` (V)."""

    h: tuple[float, float, float, float]
    v: tuple[float, float]


def _level(flow: float, area: float, g: float) -> float:
    """Steady level where the outflow ``area sqrt(2 g h)`` equals ``flow``."""
    return (flow / area) ** 2 / (2 * g)


def operating_point(p: QuadTankParams, v1: float, v2: float) -> OperatingPoint:
    """The steady state reached with constant pump voltages ``v1``, ``v2`` (V)."""
    if v1 < 0 or v2 < 0:
        raise ValueError(f"pump voltages must be >= 0 V, got v1={v1}, v2={v2}")
    f1, f2 = p.k1 * v1, p.k2 * v2
    a1, a2, a3, a4 = p.a
    h3 = _level((1 - p.gamma2) * f2, a3, p.g)
    h4 = _level((1 - p.gamma1) * f1, a4, p.g)
    h1 = _level(p.gamma1 * f1 + (1 - p.gamma2) * f2, a1, p.g)  # tank 3 drains into tank 1
    h2 = _level(p.gamma2 * f2 + (1 - p.gamma1) * f1, a2, p.g)
    return OperatingPoint((h1, h2, h3, h4), (float(v1), float(v2)))


def levels_point(p: QuadTankParams, h1: float, h2: float) -> OperatingPoint:
    """The steady state with lower-tank levels ``h1``, ``h2`` (cm): solves the pump voltages.

    Raises
    ------
    ValueError
        If no non-negative voltages hold these levels (the valve split cannot reach them).
    """
    if h1 <= 0 or h2 <= 0:
        raise ValueError(f"levels must be > 0 cm, got h1={h1}, h2={h2}")
    a1, a2 = p.a[0], p.a[1]
    # total inflow to each lower tank equals its outflow; linear in the pump flows k_i v_i
    M = np.array([[p.gamma1, 1 - p.gamma2], [1 - p.gamma1, p.gamma2]])
    out = np.array([a1 * np.sqrt(2 * p.g * h1), a2 * np.sqrt(2 * p.g * h2)])
    f1, f2 = np.linalg.solve(M, out)
    v1, v2 = f1 / p.k1, f2 / p.k2
    if v1 < 0 or v2 < 0:
        raise ValueError(f"levels h1={h1}, h2={h2} need a negative pump voltage (v1={v1:.3g}, v2={v2:.3g}) "
                         "with this valve setting")
    return operating_point(p, float(v1), float(v2))


def time_constants(p: QuadTankParams, op: OperatingPoint) -> tuple[float, float, float, float]:
    """``T_i = A_i/a_i sqrt(2 h_i0/g)`` (s) of the linearisation at ``op``."""
    return tuple(float(A / a * np.sqrt(2 * h / p.g)) for A, a, h in zip(p.A, p.a, op.h, strict=True))  # type: ignore[return-value]


def linearise(p: QuadTankParams, op: OperatingPoint) -> TfMatrix:
    """The 2x2 transfer-function matrix from pump voltages (V) to measured levels ``kc h`` (V) at ``op``."""
    T1, T2, T3, T4 = time_constants(p, op)
    c1, c2 = T1 * p.k1 * p.kc / p.A[0], T2 * p.k2 * p.kc / p.A[1]

    def lag(gain: float, *T: float) -> TfEntry:
        den = np.array([1.0])
        for t in T:
            den = np.polymul(den, [t, 1.0])
        return TfEntry(np.array([gain]), den, 0.0)

    entries = ((lag(p.gamma1 * c1, T1), lag((1 - p.gamma2) * c1, T3, T1)),
               (lag((1 - p.gamma1) * c2, T4, T2), lag(p.gamma2 * c2, T2)))
    return TfMatrix(entries, inputs=ODE_INPUTS, outputs=("y1", "y2"))


def transmission_zeros(p: QuadTankParams, op: OperatingPoint) -> np.ndarray:
    """The two zeros of ``det G(s)``: roots of ``gamma1 gamma2 (1+sT3)(1+sT4) - (1-gamma1)(1-gamma2)``."""
    _, _, T3, T4 = time_constants(p, op)
    poly = p.gamma1 * p.gamma2 * np.polymul([T3, 1.0], [T4, 1.0])
    poly[-1] -= (1 - p.gamma1) * (1 - p.gamma2)
    return np.sort_complex(np.roots(poly))
