"""The controllers of a cascade as batched linear signals: the building blocks of the closed-loop
state-space forms (:meth:`gaintune.verification.cascade.Cascade.closed_loop_A` and
:meth:`~gaintune.verification.cascade.Cascade.closed_loop_sampled`, and the delay-free chains of
:mod:`gaintune.verification.tail`).

A signal is a row over the closed loop's states plus a coefficient of the plant input u; each
loop's law maps its setpoint and measurement signals to its output signal and records its own
states' derivatives (continuous) or next values (sampled). The algebraic loop through u is
solved at the end (:func:`solve_u`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gaintune.lti.pade import pade_ss

__all__ = ["LoopCtl", "controller_state_index", "Signal", "Signals", "pade_blocks", "pid_law", "lq_law",
           "pid_law_sampled", "lq_law_sampled", "solve_u", "resolve"]


def controller_state_index(loops: list[LoopCtl], start: int) -> tuple[list[tuple[int | None, int | None]], int]:
    """State indices of each loop's integrator and derivative filter, numbered from ``start``.

    Returns ``[(integrator index or None, filter index or None) per loop]`` and the total count.
    """
    idx = start
    out = []
    for lp in loops:
        ii = idx if lp.has_i else None
        idx += int(lp.has_i)
        di = idx if (lp.kind == "pid" and lp.has_d) else None
        idx += int(lp.kind == "pid" and lp.has_d)
        out.append((ii, di))
    return out, idx


@dataclass
class LoopCtl:
    """One loop's controller, batched: every array has a leading axis B."""

    name: str
    kind: str  # "pid" | "lq"
    out_idx: int
    has_i: bool = False
    has_d: bool = False
    # PID gains (B,) each; empty for an LQ loop
    Kp: np.ndarray = field(default_factory=lambda: np.zeros(0))
    Ki: np.ndarray = field(default_factory=lambda: np.zeros(0))
    Kd: np.ndarray = field(default_factory=lambda: np.zeros(0))
    Tf: np.ndarray = field(default_factory=lambda: np.zeros(0))
    b: float = 1.0
    c: float = 0.0
    # LQ gains: state feedback (B, n), integral gain and reference gain (B,); empty for a PID loop
    K: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    Kint: np.ndarray = field(default_factory=lambda: np.zeros(0))
    Nr: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def n_states(self) -> int:
        """Number of controller states: integrator and derivative filter."""
        return int(self.has_i) + int(self.has_d)


#: A batched linear signal: its row over the N states (B, N) and its coefficient of the input u (B,).
Signal = tuple[np.ndarray, np.ndarray]


class Signals:
    """Builds batched linear :data:`Signal` s over N states for B gain sets."""

    def __init__(self, batch: int, n_states: int):
        self.B, self.N = batch, n_states

    def zero(self) -> Signal:
        """The zero signal."""
        return np.zeros((self.B, self.N)), np.zeros(self.B)

    def unit(self, j: int) -> Signal:
        """State ``j`` itself."""
        r = np.zeros((self.B, self.N))
        r[:, j] = 1.0
        return r, np.zeros(self.B)

    def comb(self, *terms: tuple[float | np.ndarray, Signal]) -> Signal:
        """Sum of coefficient x signal; a coefficient is a scalar or one per gain set (B,)."""
        rx, ru = self.zero()
        for coef, (tx, tu) in terms:
            c = np.asarray(coef, dtype=float)
            rx = rx + (c[:, None] if c.ndim else c) * tx
            ru = ru + c * tu
        return rx, ru


def pade_blocks(pade: tuple[float, int] | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(Ad, Bd, Cd, Dd) of the Padé delay (T, order); no states and Dd = 1 without delay."""
    if pade is not None and pade[0] > 0:
        return pade_ss(*pade)
    return np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), 1.0


def pid_law(sig: Signals, lp: LoopCtl, r: Signal, y: Signal, ii: int | None, di: int | None,
             derivs: dict[int, Signal]) -> Signal:
    """A continuous PID loop's output from its setpoint ``r`` and measurement ``y``; its states'
    derivatives go to ``derivs``."""
    e = sig.comb((1.0, r), (-1.0, y))
    terms: list[tuple[float | np.ndarray, Signal]] = [(lp.Kp * lp.b, r), (-lp.Kp, y)]
    if ii is not None:
        derivs[ii] = e
        terms.append((lp.Ki, sig.unit(ii)))
    if di is not None:
        ed = sig.comb((lp.c, r), (-1.0, y), (-1.0, sig.unit(di)))  # c r - y - xd
        derivs[di] = sig.comb((1.0 / lp.Tf, ed))
        terms.append((lp.Kd / lp.Tf, ed))
    return sig.comb(*terms)


def _lq_feedback(sig: Signals, lp: LoopCtl, n: int) -> Signal:
    """-K x over the first ``n`` (plant) states."""
    fx = np.zeros((sig.B, sig.N))
    fx[:, :n] = -lp.K
    return fx, np.zeros(sig.B)


def lq_law(sig: Signals, lp: LoopCtl, r: Signal, y: Signal, ii: int | None, n: int,
            derivs: dict[int, Signal]) -> Signal:
    """A continuous LQ loop's output (state feedback, optional integrator of r - y, reference gain)."""
    terms: list[tuple[float | np.ndarray, Signal]] = [(1.0, _lq_feedback(sig, lp, n)), (lp.Nr, r)]
    if ii is not None:
        derivs[ii] = sig.comb((1.0, r), (-1.0, y))
        terms.append((lp.Kint, sig.unit(ii)))
    return sig.comb(*terms)


def pid_law_sampled(sig: Signals, lp: LoopCtl, r: Signal, y: Signal, ii: int | None, di: int | None, dt: float,
                     nxt: dict[int, Signal]) -> Signal:
    """A PID loop's discrete law (the simulator's: backward-Euler integrator and derivative filter);
    its states' next values go to ``nxt``."""
    e = sig.comb((1.0, r), (-1.0, y))
    terms: list[tuple[float | np.ndarray, Signal]] = [(lp.Kp * lp.b, r), (-lp.Kp, y)]
    if ii is not None:
        nxt[ii] = sig.comb((1.0, sig.unit(ii)), (1.0, e))  # sum of e up to k
        terms.append((lp.Ki * dt, nxt[ii]))
    if di is not None:
        al = lp.Tf / (lp.Tf + dt)
        be = lp.Kd / (lp.Tf + dt)
        ed = sig.comb((lp.c, r), (-1.0, y))
        nxt[di] = sig.comb((al, sig.unit(di)), (1.0, ed))
        terms += [(be, ed), (be * (al - 1.0), sig.unit(di))]
    return sig.comb(*terms)


def lq_law_sampled(sig: Signals, lp: LoopCtl, r: Signal, y: Signal, ii: int | None, n: int, dt: float,
                    nxt: dict[int, Signal]) -> Signal:
    """An LQ loop's discrete law (the integrator a running sum of r - y)."""
    terms: list[tuple[float | np.ndarray, Signal]] = [(1.0, _lq_feedback(sig, lp, n)), (lp.Nr, r)]
    if ii is not None:
        nxt[ii] = sig.comb((1.0, sig.unit(ii)), (1.0, sig.comb((1.0, r), (-1.0, y))))
        terms.append((lp.Kint * dt, nxt[ii]))
    return sig.comb(*terms)


def solve_u(u: Signal) -> np.ndarray:
    """The input's row over the states, from the signal u = ux X + uu u (the algebraic loop solved)."""
    ux, uu = u
    with np.errstate(divide="ignore", invalid="ignore"):
        return ux / (1.0 - uu)[:, None]


def resolve(sg: Signal, u_row: np.ndarray) -> np.ndarray:
    """A signal's row over the states, with u replaced by its row ``u_row``."""
    sx, su = sg
    return sx + su[:, None] * u_row
