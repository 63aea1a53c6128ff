"""Luyben's biggest log-modulus tuning (BLT) of decentralised PI loops on a square MIMO plant.

BLT (W. L. Luyben, "Simple method for tuning SISO controllers in multivariable systems",
Ind. Eng. Chem. Process Des. Dev. 25(3), 654-660, 1986) detunes every loop of a decentralised PI
design by one common factor F:

1. For each loop i (output i driven by input ``pairing[i]``) the Ziegler-Nichols ultimate gain
   ``Ku_i`` and period ``Pu_i`` of the paired entry alone, delays exact (:func:`ultimate`).
   A reverse-acting entry (negative static gain) has a negative ``Ku_i``, so every loop has
   negative feedback.
2. ``Kc_i = Ku_i / (2.2 F)`` and ``Ti_i = F Pu_i / 1.2`` (the Ziegler-Nichols PI settings at F = 1).
3. ``W(jw) = -1 + det(I + G(jw) K(jw))`` and the closed-loop log modulus
   ``L_cm = 20 log10 |W / (1 + W)|``; its peak over frequency is the biggest log modulus.
4. F is chosen so that the peak equals ``2N`` dB (N loops): :func:`blt_tune`.

The peak is searched on a log grid (:data:`POINTS_PER_DECADE`) and refined between the grid
neighbours of the grid maximum, so it is accurate to far below the 0.01 dB the rounding of the
published settings needs. F is found by scanning down from :data:`F_MAX` on a geometric grid to
the first F whose peak reaches the target and solving between it and the previous F with
``brentq``: the answer is the least detuning for which every larger F also keeps the peak below
the target on the grid. Each result also reports closed-loop stability from the eigenvalues of a
Padé realisation (``L_cm`` alone does not prove it). Pure functions of :mod:`gaintune.lti.mimo`'s
:class:`~gaintune.lti.mimo.TfMatrix`; nothing here knows about specs or the simulator.

On the Wood-Berry column this gives F = 2.545, loop 1 Kc = 0.375, Ti = 8.29 min and loop 2
Kc = -0.0754, Ti = 23.6 min: Luyben's published 0.375/8.29 and -0.075/23.6 (F about 2.55).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from gaintune.errors import GaintuneError
from gaintune.lti.mimo import TfEntry, TfMatrix

__all__ = ["BltError", "BltLoop", "BltResult", "ultimate", "biggest_log_modulus", "blt_tune", "POINTS_PER_DECADE"]

#: Log-frequency grid density for the phase crossover and the L_cm peak.
POINTS_PER_DECADE = 400
#: Largest detuning factor tried; F below 1 would tune tighter than Ziegler-Nichols.
F_MAX = 100.0
F_MIN = 0.5
#: Ratio between successive F of the downward scan.
F_STEP = 1.15
#: Padé order of every delay for the closed-loop eigenvalue check.
PADE_ORDER = 8


class BltError(GaintuneError):
    """BLT does not apply to this plant or pairing; the message names the loop and the fix."""


@dataclass(frozen=True)
class BltLoop:
    """One loop of a BLT design: output ``output`` driven by input ``input`` with ``Kc (1 + 1/(Ti s))``."""

    output: str
    input: str
    ku: float
    pu: float
    kc: float
    ti: float

    def gains(self) -> dict[str, float]:
        """The loop's gains in gaintune's parallel form, ``{"Kp", "Ki"}``."""
        return {"Kp": self.kc, "Ki": self.kc / self.ti}


@dataclass(frozen=True)
class BltResult:
    """A BLT design: the detuning factor, the loops, and the achieved peak log modulus."""

    F: float
    loops: tuple[BltLoop, ...]
    lcm_db: float
    target_db: float
    w_peak: float
    iterations: int
    stable: bool


def _sign(entry: TfEntry) -> float:
    """Sign of the entry's low-frequency gain (ratio of the lowest-order nonzero coefficients)."""
    num = np.trim_zeros(np.asarray(entry.num, float), "b")
    den = np.trim_zeros(np.asarray(entry.den, float), "b")
    return float(np.sign(num[-1] / den[-1]))


def _integrators(entry: TfEntry) -> int:
    """Net number of poles at s = 0 (trailing zero coefficients of den minus those of num)."""
    num, den = np.asarray(entry.num, float), np.asarray(entry.den, float)
    return (len(den) - len(np.trim_zeros(den, "b"))) - (len(num) - len(np.trim_zeros(num, "b")))


def _frequency_span(entry: TfEntry) -> tuple[float, float]:
    """A frequency range (rad per time unit) that covers every corner of the entry and its delay."""
    roots = np.concatenate([np.roots(entry.num), np.roots(entry.den)]) if len(entry.den) > 1 else np.zeros(0)
    scales = [abs(r) for r in roots if abs(r) > 0]
    if entry.delay > 0:
        scales.append(1.0 / entry.delay)
    if not scales:
        scales = [1.0]
    return 1e-3 * min(scales), 1e3 * max(scales)


def ultimate(entry: TfEntry, loop: str = "loop") -> tuple[float, float]:
    """Ziegler-Nichols ultimate gain and period of one SISO entry, delay exact.

    Parameters
    ----------
    entry
        ``num/den e^{-s delay}``.
    loop
        Name of the loop, for the error message.

    Returns
    -------
    (ku, pu)
        ``ku = sign(G(0)) / |G(j wu)|`` with ``wu`` the first frequency where the phase of
        ``sign(G(0)) G`` reaches -180 degrees, and ``pu = 2 pi / wu``.

    Raises
    ------
    BltError
        If the entry is zero or its phase never reaches -180 degrees (a first-order lag, a
        delay-free second-order lag): P control alone never oscillates, so no ultimate gain exists.
    """
    if entry.is_zero:
        raise BltError(loop, "the paired entry is zero, so the loop has no effect; pair the output with an input "
                       "that moves it")
    sign = _sign(entry)
    lo, hi = _frequency_span(entry)
    w = np.geomspace(lo, hi, int(POINTS_PER_DECADE * np.log10(hi / lo)) + 2)
    rational = sign * TfEntry(entry.num, entry.den).response(1j * w)
    phase = np.unwrap(np.angle(rational))
    # anchor the unwrapped phase to the low-frequency asymptote (-90 degrees per integrator)
    phase += 2 * np.pi * np.round((-np.pi / 2 * _integrators(entry) - phase[0]) / (2 * np.pi))
    phase -= w * entry.delay
    below = np.nonzero(phase <= -np.pi)[0]
    if below.size == 0 or below[0] == 0:
        raise BltError(loop, "the paired entry's phase never reaches -180 degrees (no Ziegler-Nichols ultimate "
                       "gain: a first-order lag, or a second-order lag without delay), so BLT does not apply; "
                       "tune this loop with another rule")
    k = below[0]

    def excess(x: float) -> float:  # phase + pi, continued from the grid point k-1
        step = np.angle(TfEntry(entry.num, entry.den).response(np.array([1j * x]))[0] / (rational[k - 1] / sign))
        return float(phase[k - 1] + w[k - 1] * entry.delay + step - x * entry.delay + np.pi)

    wu = brentq(excess, w[k - 1], w[k], xtol=1e-14 * w[k], rtol=1e-13)
    ku = sign / abs(entry.response(np.array([1j * wu]))[0])
    return float(ku), float(2 * np.pi / wu)


def _loop_matrix(G: TfMatrix, pairing: Sequence[int], kc: np.ndarray, ti: np.ndarray,
                 w: np.ndarray, Gw: np.ndarray | None = None) -> np.ndarray:
    """``G(jw) K(jw)`` (nw, p, p) for decentralised PI loops: loop i measures output i and drives ``pairing[i]``."""
    Gw = G.freqresp(w) if Gw is None else Gw
    s = 1j * w
    GK = np.zeros((w.size, len(pairing), len(pairing)), dtype=complex)
    for i, j in enumerate(pairing):
        GK[:, :, i] = Gw[:, :, j] * (kc[i] * (1 + 1 / (ti[i] * s)))[:, None]
    return GK


def _lcm(GK: np.ndarray) -> np.ndarray:
    """``20 log10 |W/(1+W)|`` with ``W = det(I + GK) - 1``, per frequency (dB)."""
    det = np.linalg.det(np.eye(GK.shape[1])[None] + GK)
    with np.errstate(divide="ignore"):
        return 20 * np.log10(np.abs((det - 1) / det))


def biggest_log_modulus(G: TfMatrix, pairing: Sequence[int], kc: Sequence[float] | np.ndarray,
                        ti: Sequence[float] | np.ndarray,
                        w: np.ndarray, Gw: np.ndarray | None = None) -> tuple[float, float]:
    """Peak closed-loop log modulus ``max_w L_cm`` (dB) of decentralised PI loops, and where it is.

    Parameters
    ----------
    G, pairing
        The plant, and the input each loop drives (loop i measures output i).
    kc, ti
        Each loop's ``Kc (1 + 1/(Ti s))``.
    w
        Increasing frequency grid; the grid maximum is refined by a bounded search in ``log w``
        between its grid neighbours.
    Gw
        ``G.freqresp(w)``, if already computed.
    """
    kc_a, ti_a = np.asarray(kc, float), np.asarray(ti, float)
    curve = _lcm(_loop_matrix(G, pairing, kc_a, ti_a, w, Gw))
    k = int(np.argmax(curve))
    if not np.isfinite(curve[k]) or k in (0, w.size - 1):
        return float(curve[k]), float(w[k])

    def neg(logw: float) -> float:
        x = np.array([np.exp(logw)])
        return -float(_lcm(_loop_matrix(G, pairing, kc_a, ti_a, x))[0])

    res = minimize_scalar(neg, bounds=(np.log(w[k - 1]), np.log(w[k + 1])), method="bounded",
                          options={"xatol": 1e-10})
    if -res.fun > curve[k]:
        return float(-res.fun), float(np.exp(res.x))
    return float(curve[k]), float(w[k])


def _pairing(G: TfMatrix, pairing: Sequence[int | str] | None) -> tuple[int, ...]:
    """The pairing as input indices, checked: a permutation of the inputs, one per output."""
    if not isinstance(G, TfMatrix):
        raise BltError("plant", f"BLT takes a transfer-function matrix (TfMatrix), got {type(G).__name__}")
    p, m = G.shape
    if p != m:
        raise BltError("plant", f"BLT needs a square plant (one input per loop), got {p} outputs and {m} inputs; "
                       "select as many outputs as inputs")
    if pairing is None:
        return tuple(range(m))
    if len(pairing) != p:
        raise BltError("pairing", f"give one input per output ({p}), got {len(pairing)}")
    out = []
    for i, j in enumerate(pairing):
        if isinstance(j, str):
            if j not in G.inputs:
                raise BltError(f"pairing[{i}]", f"unknown input {j!r}; the inputs are {list(G.inputs)}")
            j = G.inputs.index(j)
        if not isinstance(j, (int, np.integer)) or isinstance(j, bool):
            raise BltError(f"pairing[{i}]", f"give an input name or index, got {j!r}")
        if not 0 <= int(j) < m:
            raise BltError(f"pairing[{i}]", f"input index {j} is out of range 0..{m - 1}")
        out.append(int(j))
    if len(set(out)) != len(out):
        raise BltError("pairing", f"each input may drive one loop only, got {[G.inputs[j] for j in out]}")
    return tuple(out)


def _closed_loop_stable(G: TfMatrix, pairing: Sequence[int], kc: np.ndarray, ti: np.ndarray) -> bool:
    """Whether the decentralised PI loops are stable: eigenvalues with every delay a Padé approximant."""
    ss = G.pade_ss(PADE_ORDER)
    A, B, C, D = ss.A, ss.B, ss.C, ss.D
    m = len(pairing)
    P = np.zeros((m, m))
    P[list(pairing), range(m)] = 1.0  # loop i's output drives input pairing[i]
    Kp, Ki = P @ np.diag(kc), P @ np.diag(kc / ti)
    # u = Kp (r - y) + Ki xi with y = C x + D u, solved for u (biproper entries give D != 0)
    M = np.linalg.inv(np.eye(m) + Kp @ D)
    ux, ui = -M @ Kp @ C, M @ Ki
    Acl = np.block([[A + B @ ux, B @ ui], [-(C + D @ ux), -D @ ui]])
    return bool(np.max(np.linalg.eigvals(Acl).real) < 0) if Acl.size else True


def blt_tune(G: TfMatrix, pairing: Sequence[int | str] | None = None, *,
             target_db: float | None = None) -> BltResult:
    """BLT settings of decentralised PI loops on a square plant.

    Parameters
    ----------
    G
        Square transfer-function matrix (delays per entry).
    pairing
        For each output i, the input (index or name) its loop drives; default output i with input i.
    target_db
        Biggest log modulus to reach, dB; default ``2 N`` for N loops (Luyben's choice).

    Returns
    -------
    BltResult
        F, every loop's Ku, Pu, Kc, Ti, the achieved peak and where it is, the number of peak
        evaluations, and closed-loop stability (Padé eigenvalues).

    Raises
    ------
    BltError
        A non-square plant, a bad pairing, or a paired entry without a Ziegler-Nichols ultimate
        gain (the message names the loop), or loops that interact so strongly that even
        F = 100 leaves the peak above the target.

    Notes
    -----
    F never goes below 0.5: if the peak stays under the target down to there, the F = 0.5
    design is returned and ``lcm_db < target_db`` says so.
    """
    pair = _pairing(G, pairing)
    n = len(pair)
    target = 2.0 * n if target_db is None else float(target_db)
    if not np.isfinite(target) or target <= 0:
        raise BltError("target_db", f"must be a positive number of dB (Luyben: 2 per loop), got {target_db}")
    names = [f"loops[{i}] ({G.outputs[i]} <- {G.inputs[j]})" for i, j in enumerate(pair)]
    ult = np.array([ultimate(G.entries[i][j], names[i]) for i, j in enumerate(pair)])
    ku, pu = ult[:, 0], ult[:, 1]
    wu = 2 * np.pi / pu
    lo, hi = wu.min() / 1e3, wu.max() * 1e2
    w = np.geomspace(lo, hi, int(POINTS_PER_DECADE * np.log10(hi / lo)) + 1)
    Gw = G.freqresp(w)
    calls = 0

    def excess(F: float) -> float:
        nonlocal calls
        calls += 1
        return biggest_log_modulus(G, pair, ku / (2.2 * F), F * pu / 1.2, w, Gw)[0] - target

    F_hi, F = F_MAX, F_MAX
    if excess(F_hi) >= 0:
        raise BltError("pairing", f"even F = {F_MAX:g} leaves the biggest log modulus above {target:g} dB: the loops "
                       "interact too strongly for this pairing; try another pairing or a decoupler")
    while F > F_MIN:
        F = max(F / F_STEP, F_MIN)
        if excess(F) >= 0:
            F = brentq(excess, F, F_hi, xtol=1e-10, rtol=1e-12)
            break
        F_hi = F
    kc, ti = ku / (2.2 * F), F * pu / 1.2
    lcm, w_peak = biggest_log_modulus(G, pair, kc, ti, w, Gw)
    loops = tuple(BltLoop(G.outputs[i], G.inputs[j], float(ku[i]), float(pu[i]), float(kc[i]), float(ti[i]))
                  for i, j in enumerate(pair))
    return BltResult(float(F), loops, lcm, target, w_peak, calls, _closed_loop_stable(G, pair, kc, ti))
