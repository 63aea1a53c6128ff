"""Closed-loop stability of one gain set (exact) or of a batch (the quick estimate).

The continuous loop: the argument principle on the characteristic quasi-polynomial
chi_ol(s) (1 + L_u(s)) along s = -eps + jw (the plant-input cut L_u passes through every
loop), which is exact for delays and counts open-loop unstable poles; for delay-free (or
Padé) loops the closed-loop eigenvalues decide and the two are cross-checked
(:func:`closed_loop_stability`).

The sampled loop is finite-dimensional (its delay is an input buffer): the eigenvalues of
its transition matrix decide (|z| < 1), cross-checked by the discrete Nyquist count on
|z| = e^{-eps dt}; beyond :data:`EIG_MAX` states (long delays) the count decides alone
(:func:`closed_loop_stability_sampled`). :func:`sampled_stability` is the batched version
the quick estimate uses (:data:`QUICK_EIG_MAX`).

Modes no loop measures are not moved by feedback (:func:`observable_part`): they are
judged on their own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, overload

import numpy as np

from gaintune.lti.modes import observable_split, plant_eigvals
from gaintune.plants.plant import LinearModel
from gaintune.verification.cascade import Cascade
from gaintune.verification.freqresp import DelayModel, Evaluator, char_freqs
from gaintune.verification.sampled import SampledPlant
from gaintune.verification.tail import SS, chain_ss, level_clear

__all__ = ["Stability", "closed_loop_stability", "closed_loop_stability_sampled", "sampled_stability",
           "nyquist_count_sampled", "observable_part", "EIG_MAX", "QUICK_EIG_MAX"]


@dataclass
class Stability:
    """Closed-loop stability of one gain set: the verdict, how it was reached, and the poles."""

    stable: bool
    method: str
    rhp_count: int
    nyquist_rhp: int | None
    poles: np.ndarray
    poles_method: str
    max_real_pole: float
    notes: list[str] = field(default_factory=list)
    #: "s": continuous poles; "z": poles of the sampled loop (max_real_pole is then ln(max|z|)/dt)
    domain: str = "s"
    spectral_radius: float | None = None
    #: Why stability could not be decided (non-finite closed loop or count: absurd gains or plant
    #: coefficients); ``stable`` is then False. None when decided.
    uncertain: str | None = None


#: The reason given when overflow leaves the closed loop undecidable.
_OVERFLOW = ("the closed loop overflows (non-finite matrix, poles or Nyquist count): gains or plant coefficients "
             "too large to analyse")


def _eigvals_finite(A: np.ndarray) -> np.ndarray | None:
    """Eigenvalues of A, or None when A or its eigenvalues are not finite (overflow: nothing can be certified)."""
    if not A.size:
        return np.zeros(0, dtype=complex)
    if not np.all(np.isfinite(A)):
        return None
    try:
        poles = np.linalg.eigvals(A)
    except np.linalg.LinAlgError:
        return None
    return poles if np.all(np.isfinite(poles)) else None


_OBS_CACHE: dict[tuple, tuple[LinearModel, LinearModel, np.ndarray]] = {}


def observable_part(lin: LinearModel, measured: tuple[int, ...], tol: float = 1e-9) -> tuple[LinearModel, np.ndarray]:
    """Restrict ``lin`` to the modes observable from the measured outputs.

    Modes no loop measures are not moved by feedback: they are open-loop poles of
    the closed loop too. Returns (reduced model, eigenvalues of the unobservable part).
    Only valid for PID cascades (LQ state feedback sees every state). The split is
    :func:`gaintune.lti.modes.observable_split`; the result is remembered per model object.
    """
    key = (id(lin), measured)
    hit = _OBS_CACHE.get(key)
    if hit is not None and hit[0] is lin:
        return hit[1], hit[2]
    A = lin.A
    split = observable_split(A, lin.C[list(measured)], tol)
    if split is None:
        red, un = lin, np.zeros(0, dtype=complex)
    else:
        V1, V2 = split
        r = V1.shape[1]
        red = LinearModel(V1.T @ A @ V1, V1.T @ lin.B, lin.C @ V1, lin.D, lin.delay, [f"z{i}" for i in range(r)],
                          lin.outputs, np.zeros(r), lin.u0, lin.y0)
        un = np.linalg.eigvals(V2.T @ A @ V2)
    if len(_OBS_CACHE) > 256:
        _OBS_CACHE.clear()
    _OBS_CACHE[key] = (lin, red, un)
    return red, un


# --------------------------------------------------------------- one gain set


#: Offsets (in units of the pole's distance to the contour) sampled around every open-loop pole.
_POLE_OFFSETS = np.concatenate([-(2.0 ** np.arange(9, -4, -1)), [0.0], 2.0 ** np.arange(-3, 10)])


def _contour(ev: Evaluator, ol_poles_s: np.ndarray, w_hi: float, eps: float, n_freq: int):
    """1 + L_u (plant-input cut, row -1) sampled along s = -eps + jw, 0 <= w <= w_hi, finely enough
    to unwrap its phase. ``ol_poles_s``: open-loop poles as s-plane points (for a sampled loop,
    ln(z)/dt), around which the contour is sampled densely. Returns (w, 1 + L_u)."""
    # An open-loop pole p turns 1 + L within a few |Re p + eps| of Im p. A lightly damped one
    # (a resonance) can make 1 + L circle the origin between two log-grid points, which leaves
    # no trace in the phase steps checked below: sample around every pole.
    up = ol_poles_s[ol_poles_s.imag > 0]
    dist = np.maximum(np.abs(up.real + eps), eps)  # pole to contour
    extra = (up.imag[:, None] + dist[:, None] * _POLE_OFFSETS[None, :]).ravel()
    wl = np.logspace(np.log10(eps / 100), np.log10(w_hi), n_freq)
    wl[-1] = w_hi
    w = np.concatenate([[0.0], wl, extra])
    w = np.unique(w[(w >= 0) & (w <= w_hi)])
    phi = 1.0 + ev(w, shift=eps)[-1]
    # the delay alone turns L by T dw over an interval: where |L| is not small, a whole turn of
    # 1 + L could also hide between two points
    T = ev.spin_T
    for _ in range(10):
        d = np.abs(np.angle(phi[1:] / phi[:-1]))
        aL = np.abs(phi - 1.0)
        spin = (T * np.diff(w) > 1.0) & (np.maximum(aL[1:], aL[:-1]) > 0.5)
        bad = np.nonzero((d > 0.3) | spin)[0]
        if bad.size == 0:
            break
        bad = bad[:4000]
        new = (w[bad, None] + (w[bad + 1] - w[bad])[:, None] * np.linspace(0, 1, 10)[None, 1:-1]).ravel()
        wn = np.concatenate([w, new])
        phin = np.concatenate([phi, 1.0 + ev(new, shift=eps)[-1]])
        o = np.argsort(wn)
        w, phi = wn[o], phin[o]
    return w, phi


#: (count or None when L overflowed, distance of the raw count from an integer, tail checked, |L| far out)
_Count = tuple[int | None, float, bool, float]


def _argument_principle(ev: Evaluator, ol_poles: np.ndarray, w_hi: float, eps: float, n_freq: int,
                        tail_proven: bool = False) -> _Count:
    """Number of closed-loop roots right of Re s = -eps (plant-input cut, row -1).

    The contour runs on the grid up to ``w_hi``; above it |L| < 1 keeps 1 + L in the right
    half-plane, so the rest of the contour adds the principal angle from 1 + L(w_hi) to
    1 + L(inf). ``tail_proven``: that bound is proven (:mod:`gaintune.verification.tail`) rather
    than checked at one far point.
    """
    w, phi = _contour(ev, ol_poles, w_hi, eps, n_freq)
    ang = np.unwrap(np.angle(phi))
    d_one_plus_L = ang[-1] - ang[0]
    # tail to infinity: |L| < 1 there keeps 1 + L in the right half-plane
    far = 1.0 + ev(np.array([w_hi * 1e4]), shift=eps)[-1, 0]
    tail_ok = tail_proven or abs(far - 1.0) < 1.0
    d_one_plus_L += np.angle(far / phi[-1])
    c = -eps - ol_poles.real
    y0 = -ol_poles.imag
    with np.errstate(divide="ignore", invalid="ignore"):
        d_ol = np.where(c != 0, np.sign(c) * (np.pi / 2 - np.arctan(y0 / np.abs(c))), 0.0)
    total = d_ol.sum() + d_one_plus_L
    n = ol_poles.size
    z_real = (n * np.pi / 2 - total) / np.pi
    if not math.isfinite(z_real):  # L overflowed on the contour: no count
        return None, math.inf, False, float(np.abs(far - 1.0))
    z = int(round(z_real))
    return z, abs(z_real - z), tail_ok, float(np.abs(far - 1.0))


def _discrete_nyquist(ev: Evaluator, sp: SampledPlant, ol_z: np.ndarray, eps: float,
                      n_freq: int) -> tuple[int | None, float]:
    """Closed-loop roots of the sampled loop on or outside |z| = rho = e^{-eps dt} (discrete Nyquist).

    With chi_cl = chi_ol (1 + L_u) and the contour |z| = rho run counter-clockwise, the roots
    inside are the open-loop poles inside plus the turns of 1 + L_u; by conjugate symmetry
    the upper half (w from 0 to the Nyquist frequency, both ends real) gives half the turn.
    ``sp``: the sampled plant ``ev`` evaluates. Returns (count, distance of the raw count from an integer).
    """
    dt = sp.dt
    rho = math.exp(-eps * dt)
    nz = ol_z[np.abs(ol_z) > 0]
    w, phi = _contour(ev, np.log(nz.astype(complex)) / dt, sp.nyquist, eps, n_freq)
    ang = np.unwrap(np.angle(phi))
    turns = (ang[-1] - ang[0]) / np.pi  # full turns of 1 + L_u around the closed contour
    p_out = int(np.sum(np.abs(ol_z) >= rho))
    z_real = p_out - turns
    if not math.isfinite(z_real):  # L overflowed on the contour (or |z| = rho rounded to 1): no count
        return None, math.inf
    z = int(round(z_real))
    return z, abs(z_real - z)


def _unmeasured_modes(bad: np.ndarray, marginal: np.ndarray, notes: list[str]) -> int:
    """Note the plant modes no loop measures; return how many of them are unstable (they add to the count)."""
    if bad.size:
        notes.append(f"unstable plant mode(s) {np.round(bad, 6).tolist()} not measured by any loop: "
                     "cannot be stabilised")
    if marginal.size:
        notes.append(
            f"marginal plant mode(s) {np.round(marginal, 6).tolist()} not measured by any loop (e.g. an integrator "
            "such as position under speed control): left out of the stability verdict"
        )
    return int(bad.size)


def _closed_loop_poles(A: np.ndarray) -> tuple[np.ndarray, float, int | None]:
    """(poles, largest real part, count with Re >= 0) of the closed-loop matrix ``A``; no poles,
    NaN and None when it overflows."""
    eig = _eigvals_finite(A)
    poles = eig if eig is not None else np.zeros(0, dtype=complex)
    scale = max(1.0, float(np.max(np.abs(poles))) if poles.size else 1.0)
    max_re = float(np.max(poles.real)) if poles.size else (-math.inf if eig is not None else math.nan)
    rhp_poles = int(np.sum(poles.real > -1e-12 * scale)) if eig is not None else None
    return poles, max_re, rhp_poles


def _tail_proven(cas: Cascade, lin: LinearModel, delay: DelayModel, eps: float, w_hi: float,
                 g_u: SS | None) -> bool:
    """|L_u(-eps + jw)| < 1 above ``w_hi``, proven. On this contour the delay factor (exact or
    Padé) has modulus 1 + O(eps T), with eps T < 1e-6 in practice: 0.999 leaves room for it."""
    if g_u is None:
        g_u = chain_ss(cas, lin, 0, len(cas.loops) - 1, "u")
    return level_clear(g_u, 0.999 * math.exp(-2.0 * eps * max(delay.T, 0.0)), w_hi, shift=eps)


def _nyquist_decides(count: _Count, notes: list[str]) -> int | None:
    """The right-half-plane count of an exact-delay loop, from the argument principle."""
    nyq, frac_err, tail_ok, l_inf = count
    rhp = nyq
    if nyq is not None and not tail_ok:
        notes.append(f"|L(jw)| does not fall below 1 at high frequency (|L| -> {l_inf:.3g}): neutral delay loop, "
                     "unstable")
        rhp = max(nyq, 1)
    if frac_err > 0.25 and nyq is not None:
        notes.append("argument-principle count is not close to an integer; grid may be too coarse")
    return rhp


def _poles_decide(nyq: int | None, rhp_poles: int | None, notes: list[str], what: str = "Nyquist count") -> None:
    """Note where the Nyquist cross-check of a pole count fails or disagrees (the poles decide)."""
    if nyq is None and rhp_poles is not None:
        notes.append(f"{what} not computable (the loop response overflows); poles decide")
    elif nyq != rhp_poles and rhp_poles is not None:
        notes.append(f"{what} ({nyq}) differs from the pole count ({rhp_poles}); poles decide")


def _undecided(rhp: int | None, notes: list[str]) -> tuple[int, str | None]:
    """(count, why undecided): an overflow (no count) certifies nothing, so the loop counts as unstable."""
    if rhp is None:
        notes.append(_OVERFLOW)
        return 1, _OVERFLOW
    return rhp, None


@overload
def closed_loop_stability(ev: Evaluator, cas: Cascade, lin: LinearModel, delay: DelayModel, w_hi: float,
                          n_freq: int, capped: Literal[False] = False, g_u: SS | None = None) -> Stability: ...


@overload
def closed_loop_stability(ev: Evaluator, cas: Cascade, lin: LinearModel, delay: DelayModel, w_hi: float,
                          n_freq: int, capped: bool, g_u: SS | None = None) -> Stability | None: ...


def closed_loop_stability(ev: Evaluator, cas: Cascade, lin: LinearModel, delay: DelayModel, w_hi: float,
                          n_freq: int, capped: bool = False, g_u: SS | None = None) -> Stability | None:
    """Closed-loop stability. ``capped``: the grid stops at ``w_hi``, short of where |L| is
    negligible; the Nyquist contour is then closed with a proven bound |L_u| < 1 above
    ``w_hi``, and None is returned when that bound cannot be proven. ``g_u``: the delay-free
    plant-input realisation on the observable part, when already built."""
    notes: list[str] = []
    has_delay = delay.T > 0
    exact_delay = has_delay and delay.pade_order is None
    cf = char_freqs(cas, lin, DelayModel(0.0))
    # pole list of an exact-delay loop: Padé of order 6, or 2 when the delay is tiny for the loop
    pade = delay.pade(6 if delay.T * float(cf.max()) > 0.05 else 2) if has_delay else None
    # modes no loop measures are untouched by feedback: judge them separately
    lin_full = lin
    unobs = np.zeros(0, dtype=complex)
    if cas.measured is not None:
        lin, unobs = observable_part(lin, cas.measured)
    poles, max_re, rhp_poles = _closed_loop_poles(cas.closed_loop_A(lin, pade)[0])
    eps = 1e-7 * float(char_freqs(cas, lin, delay).min())
    ol = cas.open_loop_poles(lin, pade if not exact_delay else None)[0]
    proven = capped and _tail_proven(cas, lin, delay, eps, w_hi, g_u)
    if capped and not proven:
        return None
    count = _argument_principle(ev, ol, w_hi, eps, n_freq, proven)
    nyq = count[0]
    if exact_delay:
        method, rhp = "nyquist", _nyquist_decides(count, notes)
        poles_method = f"pade{pade[1]}" if pade else "exact"
    else:
        method, rhp = "poles", rhp_poles
        poles_method = "exact" if not has_delay else f"pade{delay.pade_order}"
        _poles_decide(nyq, rhp_poles, notes)
    n_rhp, uncertain = _undecided(rhp, notes)
    if unobs.size:
        tol = 1e-9 * max(1.0, float(np.max(np.abs(plant_eigvals(lin_full)))))
        n_rhp += _unmeasured_modes(unobs[unobs.real > tol], unobs[np.abs(unobs.real) <= tol], notes)
    return Stability(n_rhp == 0, method, int(n_rhp), None if nyq is None else int(nyq), poles, poles_method, max_re,
                     notes, uncertain=uncertain)


#: Largest closed-loop state dimension of a sampled loop whose eigenvalues are computed (a long
#: delay is a long input buffer); beyond it the discrete Nyquist criterion decides alone. (LAPACK's
#: eigenvalue solver turns multi-threaded near 80 states, and then costs 100x more on a busy machine.)
EIG_MAX = 64


def closed_loop_stability_sampled(ev: Evaluator, cas: Cascade, lin: LinearModel, sp: SampledPlant,
                                  n_freq: int) -> Stability:
    """Closed-loop stability of the sampled loop: the eigenvalues of its transition matrix decide
    (|z| < 1), the discrete Nyquist count is the cross-check (it decides alone for closed loops
    with more than :data:`EIG_MAX` states)."""
    notes: list[str] = []
    meas = cas.measured
    lin_r, unobs = lin, np.zeros(0, dtype=complex)
    if meas is not None:
        lin_r, unobs = observable_part(lin, meas)
    spr = sp.for_model(lin_r)
    ol = cas.open_loop_poles_sampled(spr)[0]
    N = spr.n + spr.buffer_len + sum(lp.n_states() for lp in cas.loops)
    eps = 1e-7 * float(char_freqs(cas, lin_r, DelayModel(sp.total_delay)).min())
    nyq, frac_err = _discrete_nyquist(ev, sp, ol, eps, n_freq)
    if N <= EIG_MAX:
        A = cas.closed_loop_sampled(spr)[0]
        eig = _eigvals_finite(A)
        poles = eig if eig is not None else np.zeros(0, dtype=complex)
        rad = (float(np.max(np.abs(poles))) if poles.size else 0.0) if eig is not None else math.nan
        rhp = int(np.sum(np.abs(poles) > 1.0 - 1e-10)) if eig is not None else None
        method, poles_method = "poles", "exact"
        _poles_decide(nyq, rhp, notes, "discrete Nyquist count")
    else:
        poles = np.zeros(0, dtype=complex)
        rad = math.nan
        rhp = nyq
        method, poles_method = "nyquist", "none"
        notes.append(f"{N} closed-loop states (input buffer of {spr.buffer_len} samples): the discrete Nyquist "
                     "criterion decides; poles not listed")
        if frac_err > 0.25 and nyq is not None:
            notes.append("discrete Nyquist count is not close to an integer; grid may be too coarse")
    n_rhp, uncertain = _undecided(rhp, notes)
    if unobs.size:
        zu = np.abs(sp.mode_factor(unobs))
        n_rhp += _unmeasured_modes(unobs[zu > 1.0 + 1e-9], unobs[np.abs(zu - 1.0) <= 1e-9], notes)
    with np.errstate(divide="ignore"):
        max_re = math.log(rad) / sp.dt if math.isfinite(rad) and rad > 0 else (-math.inf if rad == 0 else math.nan)
    return Stability(n_rhp == 0, method, int(n_rhp), None if nyq is None else int(nyq), poles, poles_method, max_re,
                     notes, "z", rad if math.isfinite(rad) else None, uncertain)


# --------------------------------------------------------------- batched (the quick estimate)


#: Batched eigenvalue problems of the sampled closed loop are solved up to this many states;
#: longer input buffers (long delays) use the batched discrete Nyquist count, which is cheaper
#: there (B = 64, PID on a lag: 46 ms by eigenvalues vs 20 ms at 53 states) and agrees.
QUICK_EIG_MAX = 32


def sampled_stability(cas: Cascade, lin: LinearModel, sp: SampledPlant, w_lo: float) -> tuple[np.ndarray, np.ndarray]:
    """Batched closed-loop stability of the sampled loop: (stable (B,), max real part (B,)).

    The eigenvalues z of the closed-loop transition matrices decide (stable: |z| < 1); the
    real part reported is the s-plane equivalent ln(max|z|)/dt. Closed loops with long input
    buffers (beyond :data:`QUICK_EIG_MAX` states) are counted with the discrete Nyquist criterion
    instead, and an unstable one is graded by w_lo times its number of unstable roots.
    ``w_lo``: lower end of the analysis grid.
    """
    lin_cl, unobs = lin, np.zeros(0, dtype=complex)
    if cas.measured is not None:  # modes no loop measures are not moved by feedback
        lin_cl, unobs = observable_part(lin, cas.measured)
    extra_unstable = bool(np.any(np.abs(sp.mode_factor(unobs)) > 1.0 + 1e-9)) if unobs.size else False
    spr = sp.for_model(lin_cl)
    B = cas.batch
    N = spr.n + spr.buffer_len + sum(lp.n_states() for lp in cas.loops)
    if N <= QUICK_EIG_MAX:
        Acl = cas.closed_loop_sampled(spr)
        with np.errstate(all="ignore"):
            finite = np.all(np.isfinite(Acl), axis=(1, 2))
            Acl = np.where(finite[:, None, None], Acl, 0.0)
            ev = np.linalg.eigvals(Acl) if N else np.zeros((B, 0))
            rad = np.abs(ev).max(axis=-1) if N else np.zeros(B)
            max_re = np.where(finite, np.log(rad) / sp.dt, np.inf)
        stable = finite & (rad < 1.0 - 1e-10) & (not extra_unstable)
        return stable, max_re
    count = nyquist_count_sampled(cas, lin, sp, cas.open_loop_poles_sampled(spr), w_lo)
    stable = (count == 0) & (not extra_unstable)
    return stable, np.where(stable, -w_lo, w_lo * np.maximum(count, 1))


def nyquist_count_sampled(cas: Cascade, lin: LinearModel, sp: SampledPlant, ol: np.ndarray, w_lo: float) -> np.ndarray:
    """Closed-loop roots on or outside the unit circle (B,), discrete Nyquist criterion, batched.

    The contour |z| = rho = e^{-eps dt} is sampled from w = 0 to pi/dt (conjugate symmetry gives
    the lower half): a log grid, a uniform one fine enough for the buffer's phase spin d w dt,
    points around lightly damped open-loop poles, then intervals where the phase of 1 + L_u
    still steps by more than 0.5 rad are refined. ``ol``: z-plane open-loop poles (B, P) of the
    (observable) loop cut at the plant input.
    """
    dt, wn = sp.dt, sp.nyquist
    eps = 1e-3 * w_lo
    rho = math.exp(-eps * dt)
    spin = max(sp.total_delay, dt)
    parts: list[np.ndarray] = [np.zeros(1), np.logspace(np.log10(eps / 100), np.log10(wn), 400),
                               np.linspace(0.0, wn, int(wn * spin / 0.3) + 2)]
    pz = np.unique(ol[np.abs(ol) > 0.5].ravel())
    if pz.size:
        s_p = np.log(pz.astype(complex)) / dt
        up = s_p[s_p.imag > 0]
        dist = np.maximum(np.abs(up.real + eps), eps)
        parts.append((up.imag[:, None] + dist[:, None] * _POLE_OFFSETS[None, :]).ravel())
    w = np.concatenate(parts)
    w = np.unique(np.clip(w, 0.0, wn))

    def one_plus_L(wv):
        with np.errstate(all="ignore"):
            return 1.0 + cas.loop_responses(-eps + 1j * wv, lin, sampled=sp)[-1]

    phi = one_plus_L(w)
    for _ in range(6):
        with np.errstate(all="ignore"):
            step = np.abs(np.angle(phi[:, 1:] / phi[:, :-1]))
        bad = np.nonzero(np.any(step > 0.5, axis=0))[0][:20000]
        if bad.size == 0:
            break
        new = (w[bad, None] + (w[bad + 1] - w[bad])[:, None] * np.linspace(0, 1, 6)[None, 1:-1]).ravel()
        wn_ = np.concatenate([w, new])
        o = np.argsort(wn_, kind="stable")
        w, phi = wn_[o], np.concatenate([phi, one_plus_L(new)], axis=1)[:, o]
    with np.errstate(all="ignore"):
        ang = np.unwrap(np.angle(phi), axis=1)
        turns = (ang[:, -1] - ang[:, 0]) / np.pi
    p_out = np.sum(np.abs(ol) >= rho, axis=1)
    count = np.rint(p_out - turns)
    return np.where(np.isfinite(count), count, 1).astype(np.int64)

