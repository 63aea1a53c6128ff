"""Closed-loop stability of the whole MIMO loop: Padé eigenvalues and the generalised Nyquist count.

Two independent methods (negative feedback ``u = K (r - y)``, :mod:`.mimo_loop`):

* **Eigenvalues** of the closed-loop state matrix built from minimal realisations of the plant's
  loop channels (every delay replaced by its Padé approximant) and of the controller.
* **Generalised Nyquist count** on the exact delays: along s = -eps + jw, with
  chi_cl(s) = chi_ol(s) det(I + L(s)), the closed-loop roots right of the contour are
  Z = P - (change of arg det(I + L) for w from 0 to inf) / pi, P the open-loop poles right of it
  (plant and controller, delay-free); conjugate symmetry gives the lower half. L is taken on the
  smaller side (det(I + Ks Gs) = det(I + Gs Ks)), of size n. The contour runs up
  to where sigma_max(L) < sin(pi / 2n) / 2, so that each eigenvalue of I + L stays within a small
  angle of 1 and the principal angle closes the tail (checked on the grid and one far point).

With delays the Nyquist count decides (it is exact); without, the eigenvalues do. Both are
reported, with whether they agree. Plant modes the loop channels do not see (hidden modes) are
not moved by feedback: an unstable one fails the loop, a marginal one is noted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gaintune.verification.mimo_loop import MimoLoop, char_freqs, closed_loop_matrix, hidden_modes

__all__ = ["MimoStability", "mimo_stability"]

#: Points around every open-loop pole, in units of its distance to the contour (as the SISO count).
_POLE_OFFSETS = np.concatenate([-(2.0 ** np.arange(9, -4, -1)), [0.0], 2.0 ** np.arange(-3, 10)])


@dataclass
class MimoStability:
    """Closed-loop stability of the MIMO loop: the verdict, both counts and the poles."""

    stable: bool
    method: str  # "nyquist" (exact delays decide) | "poles"
    rhp_poles: int  # closed-loop eigenvalues with Re >= 0 (Padé), hidden unstable modes included
    nyquist_rhp: int | None  # generalised Nyquist count (exact delays); None when not computable
    agree: bool
    poles: np.ndarray
    pade_order: int
    max_real_pole: float
    hidden_modes: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=complex))
    notes: list[str] = field(default_factory=list)


def _det_contour(loop: MimoLoop, ol: np.ndarray, eps: float, w_hi: float, T_spin: float,
                 n_freq: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """det(I + L) along s = -eps + jw, 0 <= w <= w_hi, refined until its phase steps stay below 0.3 rad."""
    eye = np.eye(loop.n_small)

    def det(w: np.ndarray) -> np.ndarray:
        with np.errstate(all="ignore"):
            return np.linalg.det(eye + _l_small(loop, -eps + 1j * w))

    up = ol[ol.imag > 0]
    dist = np.maximum(np.abs(up.real + eps), eps)
    w = np.concatenate([[0.0], np.logspace(np.log10(eps / 100), np.log10(w_hi), n_freq),
                        (up.imag[:, None] + dist[:, None] * _POLE_OFFSETS[None, :]).ravel()])
    w = np.unique(w[(w >= 0) & (w <= w_hi)])
    if T_spin > 0:  # the delays turn the phase by about T dw per interval, where det(I + L) is not near 1
        with np.errstate(all="ignore"):
            far = np.abs(det(w) - 1.0) > 0.1
        w_top = float(w[np.nonzero(far)[0][-1]]) if far.any() else 0.0
        w = np.unique(np.concatenate([w, np.linspace(0.0, w_top, min(int(w_top * T_spin / 0.5) + 2, 20000))]))
    phi = det(w)
    for _ in range(10):
        with np.errstate(all="ignore"):
            bad = np.nonzero(np.abs(np.angle(phi[1:] / phi[:-1])) > 0.3)[0][:4000]
        if bad.size == 0:
            break
        new = (w[bad, None] + (w[bad + 1] - w[bad])[:, None] * np.linspace(0, 1, 10)[None, 1:-1]).ravel()
        wn = np.concatenate([w, new])
        o = np.argsort(wn, kind="stable")
        w, phi = wn[o], np.concatenate([phi, det(new)])[o]
    return w, phi


def _sigma_l(loop: MimoLoop, w: np.ndarray, eps: float) -> np.ndarray:
    """An upper bound of sigma_max(L) (its Frobenius norm) at s = -eps + jw."""
    with np.errstate(all="ignore"):
        return np.linalg.norm(_l_small(loop, -eps + 1j * np.asarray(w, dtype=float)), axis=(1, 2))


def _nyquist(loop: MimoLoop, ol: np.ndarray, eps: float, cf: np.ndarray, notes: list[str]) -> int | None:
    """Closed-loop roots right of Re s = -eps by the generalised Nyquist criterion (exact delays)."""
    tau = 0.5 * math.sin(math.pi / (2 * loop.n_small))
    w_hi = 100.0 * float(cf.max())
    for _ in range(8):
        if _sigma_l(loop, np.array([w_hi]), eps)[0] < tau:
            break
        w_hi *= 10.0
    tail_ok = bool(np.all(_sigma_l(loop, w_hi * np.array([10.0, 1e2, 1e4]), eps) < tau))
    w, phi = _det_contour(loop, ol, eps, w_hi, 2.0 * loop.max_delay())
    with np.errstate(all="ignore"):
        far = complex(np.linalg.det(np.eye(loop.n_small) + _l_small(loop, np.array([-eps + 1j * w_hi * 1e4]))[0]))
    ang = np.unwrap(np.angle(phi))
    turn = ang[-1] - ang[0] + float(np.angle(far / phi[-1]))
    P = int(np.sum(ol.real > -eps))
    z_real = P - turn / math.pi
    if not math.isfinite(z_real):
        notes.append("generalised Nyquist count not computable (the loop response overflows)")
        return None
    z = int(round(z_real))
    if abs(z_real - z) > 0.25:
        notes.append("generalised Nyquist count is not close to an integer; the contour may be too coarse")
    if not tail_ok:
        notes.append(f"sigma_max(L) does not fall below {tau:.3g} at high frequency: the Nyquist tail is not "
                     "verified (a loop with direct feedthrough and delay may be neutral)")
        z = max(z, 1) if loop.max_delay() > 0 else z
    return z


def _l_small(loop: MimoLoop, s: np.ndarray) -> np.ndarray:
    """The loop gain on the smaller side (Ks Gs at the inputs or Gs Ks at the outputs) at ``s``."""
    return loop.loop_gains(s, "input" if loop.n_in <= loop.n_out else "output")


def _drop(values: np.ndarray, remove: np.ndarray) -> np.ndarray:
    """``values`` without the entry nearest to each of ``remove`` (one entry each)."""
    keep = np.ones(values.size, dtype=bool)
    for r in remove:
        if not keep.any():
            break
        d = np.where(keep, np.abs(values - r), np.inf)
        keep[int(np.argmin(d))] = False
    return values[keep]


def _hidden_notes(bad: np.ndarray, marginal: np.ndarray, notes: list[str]) -> None:
    if bad.size:
        notes.append(f"unstable plant mode(s) {np.round(bad, 6).tolist()} not seen by the loop channels: "
                     "feedback cannot stabilise them")
    if marginal.size:
        notes.append(f"marginal plant mode(s) {np.round(marginal, 6).tolist()} not seen by the loop channels: "
                     "left out of the verdict")


def _split_hidden(hidden: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unstable, marginal) hidden plant modes."""
    sc = max(1.0, float(np.max(np.abs(hidden)))) if hidden.size else 1.0
    return hidden[hidden.real > 1e-9 * sc], hidden[np.abs(hidden.real) <= 1e-9 * sc]


def _open_loop_poles(loop: MimoLoop) -> np.ndarray:
    """Delay-free open-loop poles of plant channels and controller that feedback can move (hidden ones
    are counted apart), for the Nyquist count."""
    P, Kc = loop.realisations(0)
    parts = []
    for A, B, C, _ in (P, Kc):
        if A.size:
            parts.append(_drop(np.linalg.eigvals(A), hidden_modes(A, B, C, -1e-6)))
    return np.concatenate(parts) if parts else np.zeros(0, dtype=complex)


def mimo_stability(loop: MimoLoop, pade_order: int | None = None) -> MimoStability:
    """Closed-loop stability of ``loop``: Padé eigenvalues (order ``pade_order``, default 6 with
    delays) and the generalised Nyquist count on the exact delays (see the module docstring)."""
    notes: list[str] = []
    T = loop.max_delay()
    order = (6 if pade_order is None else int(pade_order)) if T > 0 else 0
    P, Kc = loop.realisations(order)
    A = closed_loop_matrix(P, Kc)
    with np.errstate(all="ignore"):
        poles = np.linalg.eigvals(A) if A.size and np.all(np.isfinite(A)) else np.zeros(0, dtype=complex)
    hid_p = hidden_modes(P[0], P[1], P[2], -1e-6)
    hid_k = hidden_modes(Kc[0], Kc[1], Kc[2], -1e-6)  # artefacts of the controller's realisation
    poles = _drop(poles, np.concatenate([hid_p, hid_k]))
    bad, marginal = _split_hidden(hid_p)
    _hidden_notes(bad, marginal, notes)
    scale = max(1.0, float(np.max(np.abs(poles))) if poles.size else 1.0)
    rhp = int(np.sum(poles.real > -1e-12 * scale)) + int(bad.size)
    cf = char_freqs(loop)
    eps = 1e-7 * float(cf.min())
    nyq = _nyquist(loop, _open_loop_poles(loop), eps, cf, notes)
    if nyq is not None:
        nyq += int(bad.size)
    agree = nyq == rhp
    method, n_rhp = ("nyquist", nyq) if T > 0 and nyq is not None else ("poles", rhp)
    if not agree:
        notes.append(f"generalised Nyquist count ({nyq}) differs from the Padé pole count ({rhp}); "
                     f"{'the Nyquist count (exact delays)' if method == 'nyquist' else 'the poles'} decide")
    max_re = float(np.max(poles.real)) if poles.size else -math.inf
    poles = poles[np.argsort(-poles.real, kind="stable")]
    return MimoStability(n_rhp == 0, method, rhp, nyq, agree, poles, order, max_re,
                         np.concatenate([bad, marginal]), notes)
