"""MIMO margins: loop-at-a-time margins, multiloop disk margins (structured singular value), sigma peaks.

* **Loop-at-a-time** (one channel broken, all others closed): with S = (I + L)^-1 at the plant
  inputs (L = Ks Gs) or outputs (L = Gs Ks), the SISO loop seen at channel k is
  ``L_k = 1/S_kk - 1``: the Schur complement of I + L gives
  ``S_kk = 1/(1 + l_kk - l_kr (I + L_rr)^-1 l_rk)``, and ``l_kk - l_kr (I + L_rr)^-1 l_rk`` is
  what returns to channel k through its own path and through the other closed loops. Its gain,
  phase and delay margins, Ms, Mt and disk margin are those of the SISO analysis
  (:func:`gaintune.verification.margins.row_margins`).
* **Multiloop disk margin** (every channel perturbed at once, each by its own factor f_k in the
  disk {(1 + (1 - sigma)/2 d)/(1 - (1 + sigma)/2 d) : |d| < alpha}, as MATLAB's ``diskmargin``):
  ``alpha = 1 / max_w mu(S + (sigma - 1)/2 I)`` with mu for a diagonal complex perturbation; for
  the balanced disk (sigma = 0) ``S - I/2 = (S - T)/2``. The upper bound of mu is
  ``min_D sigma_max(D M D^-1)`` over positive diagonal D: Osborne balancing at every grid
  frequency, then a BFGS minimisation over log D (gradient sigma (|u_i|^2 - |v_i|^2)) at the
  frequencies that can hold the peak. The reported alpha is 1/mu_upper (guaranteed, as MATLAB's
  ``DiskMargin``); ``alpha_upper`` = 1/mu_lower from a destabilising perturbation built from the
  singular vectors (the bound is exact for up to three channels).
* **MIMO Ms, Mt**: the peaks of sigma_max(S) and sigma_max(T).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from gaintune.verification.freqresp import Evaluator
from gaintune.verification.margins import PEAK_FIGURES, BreakFigures, row_margins
from gaintune.verification.mimo_loop import MimoLoop, solve_points

__all__ = ["Peak", "MultiloopDisk", "mu_bounds", "osborne", "disk_range", "multiloop_disk", "sigma_peak",
           "loop_at_a_time", "lat_rows"]


@dataclass
class Peak:
    """A peak of a figure over frequency."""

    value: float
    freq: float | None


@dataclass
class MultiloopDisk:
    """Multiloop disk margin of one side (all channels perturbed at once)."""

    alpha: float  # 1/mu_upper: guaranteed
    alpha_upper: float  # 1/mu_lower
    freq: float | None
    gm_low: float  # disk-based gain range [gm_low, gm_high] (factors)
    gm_high: float
    gm_db: float  # 20 log10 min(1/gm_low, gm_high)
    pm_deg: float
    sigma: float = 0.0


def disk_range(alpha: float, sigma: float = 0.0) -> tuple[float, float, float, float]:
    """(gm_low, gm_high, gm_db, pm_deg) of the disk of size ``alpha`` and skew ``sigma``, as
    ``control.disk_margins`` and MATLAB's ``diskmargin`` (gm_high inf beyond the disk's reach)."""
    if not alpha > 0:
        return 1.0, 1.0, 0.0, 0.0
    if not math.isfinite(alpha):
        return 0.0, math.inf, math.inf, 90.0
    lo = (1 - 0.5 * alpha * (1 - sigma)) / (1 + 0.5 * alpha * (1 + sigma))
    den = 1 - 0.5 * alpha * (1 + sigma)
    hi = (1 + 0.5 * alpha * (1 - sigma)) / den if den > 0 else math.inf
    lo = max(lo, 0.0)
    gm = min(1 / lo if lo > 0 else math.inf, hi)
    gm_db = 20 * math.log10(gm) if math.isfinite(gm) else math.inf
    if not math.isfinite(hi):
        pm = 90.0
    else:
        c = (1 + lo * hi) / (lo + hi)
        pm = math.inf if abs(c) >= 1 else math.degrees(math.acos(c))
    return lo, hi, gm_db, pm


# ------------------------------------------------------------------ structured singular value


def osborne(M: np.ndarray, iters: int = 25) -> np.ndarray:
    """Diagonal scalings d (W, n) balancing the off-diagonal row and column norms of d_i M_ij / d_j
    (Osborne's balancing, all indices at once, damped), for M (W, n, n)."""
    B = np.abs(M) ** 2
    idx = np.arange(M.shape[-1])
    B[:, idx, idx] = 0.0
    tiny = 1e-300 + 1e-30 * B.max(axis=(1, 2), keepdims=True)[:, :, 0]
    x = np.ones(M.shape[:2])
    for _ in range(iters):
        num = np.einsum("wj,wji->wi", x, B) + tiny
        den = np.einsum("wij,wj->wi", B, 1.0 / x) + tiny
        x = np.sqrt(x * np.sqrt(num / den))  # damped: the plain (Jacobi) update oscillates
        x /= np.exp(np.mean(np.log(x), axis=1, keepdims=True))
    return np.sqrt(x)


def _sigma_max(X: np.ndarray, floor: float = -np.inf) -> np.ndarray:
    """sigma_max per frequency of X (W, n, n); where the Frobenius norm (an upper bound) is at most
    ``floor`` the Frobenius norm stands in (those points cannot hold a peak above ``floor``)."""
    with np.errstate(all="ignore"):
        v = np.linalg.norm(X, axis=(1, 2))
        v = np.where(np.isfinite(v), v, np.nan)
        need = ~(v <= floor)
        if need.any():
            v[need] = np.linalg.norm(np.where(np.isfinite(X[need]), X[need], 0.0), ord=2, axis=(1, 2))
            v[need & ~np.all(np.isfinite(X), axis=(1, 2))] = np.nan
    return v


def _grid_sigma_max(X: np.ndarray) -> np.ndarray:
    """sigma_max on a grid where only the maximum matters: exact at the points whose Frobenius norm
    exceeds the exact value at the Frobenius maximum, the Frobenius norm (larger) elsewhere."""
    with np.errstate(all="ignore"):
        fro = np.linalg.norm(X, axis=(1, 2))
    fro = np.where(np.isfinite(fro), fro, np.nan)
    if not np.isfinite(fro).any():
        return fro
    i = int(np.nanargmax(fro))
    first = float(np.linalg.norm(X[i], ord=2))
    v = _sigma_max(X, floor=first)
    return np.where(v > fro, fro, v)


def _scaled_norm(M: np.ndarray, d: np.ndarray) -> np.ndarray:
    """sigma_max(D M D^-1) per frequency (the Frobenius norm where it cannot hold the peak)."""
    with np.errstate(all="ignore"):
        return _grid_sigma_max(d[:, :, None] * M / d[:, None, :])


def _lower(M: np.ndarray, d: np.ndarray) -> float:
    """A lower bound of mu(M): the largest of rho(M), max |M_ii| and 1/||Delta|| of the perturbation
    built from the singular vectors of D M D^-1 (with its phases alone, too)."""
    U, sv, Vh = np.linalg.svd(d[:, None] * M / d[None, :])
    x, y = Vh[0].conj() / d, U[:, 0] / d  # M x = sigma y
    lb = max(float(np.max(np.abs(np.linalg.eigvals(M)))), float(np.max(np.abs(np.diag(M)))))
    with np.errstate(all="ignore"):
        ratio = np.abs(y) / np.abs(x)
        if np.all(np.isfinite(ratio)):
            lb = max(lb, float(sv[0] * ratio.min()))
        ph = np.exp(1j * np.angle(x / y))
    if np.all(np.isfinite(ph)):
        lb = max(lb, float(np.max(np.abs(np.linalg.eigvals(M * ph[None, :])))))
    return lb


def mu_bounds(M: np.ndarray, d0: np.ndarray | None = None, gap: float = 5e-3) -> tuple[float, float, np.ndarray]:
    """(upper, lower, d): bounds of mu(M) for a diagonal complex perturbation and the optimal scaling.

    The upper bound minimises sigma_max(D M D^-1) over log D (BFGS from ``d0``, default Osborne's);
    when the bounds at ``d0`` are already within ``gap`` (relative) they are returned as they are."""
    from scipy.optimize import minimize

    n = M.shape[0]
    if n == 1:
        return float(abs(M[0, 0])), float(abs(M[0, 0])), np.ones(1)
    d = osborne(M[None])[0] if d0 is None else d0
    x0 = np.log(d[1:] / d[0])
    ub0 = float(np.linalg.norm(d[:, None] * M / d[None, :], ord=2))
    lb0 = _lower(M, d)
    if ub0 <= lb0 * (1.0 + gap):  # the bounds meet (within gap) already
        return ub0, lb0, d / d[0]

    def f(x: np.ndarray) -> tuple[float, np.ndarray]:
        dd = np.exp(np.concatenate([[0.0], x]))
        U, sv, Vh = np.linalg.svd(dd[:, None] * M / dd[None, :])
        g = sv[0] * (np.abs(U[:, 0]) ** 2 - np.abs(Vh[0]) ** 2)
        return float(sv[0]), g[1:]

    # sigma_max is not smooth where it is repeated: a short run, the best point kept
    res = minimize(f, x0, jac=True, method="BFGS", options={"gtol": 1e-7, "maxiter": 10})
    x = res.x if res.fun <= f(x0)[0] else x0
    dd = np.exp(np.concatenate([[0.0], x]))
    ub = min(float(res.fun), f(x0)[0])
    return ub, min(_lower(M, dd), ub), dd


def _shift(S: np.ndarray, sigma: float) -> np.ndarray:
    return S + 0.5 * (sigma - 1.0) * np.eye(S.shape[-1])


def multiloop_disk(S_at: Callable[[np.ndarray], np.ndarray], w: np.ndarray, S: np.ndarray,
                   sigma: float = 0.0, max_refine: int = 6, rtol: float = 1e-2) -> MultiloopDisk:
    """Multiloop disk margin from the sensitivity S on the grid ``w`` (W, n, n); ``S_at(w)`` evaluates
    S anywhere (the zoom). Grid points are refined (BFGS over log D) in decreasing order of their
    Osborne bound until that bound is within ``rtol`` of the best refined one, which is then raised to
    it (so mu_upper may exceed the optimal bound by < rtol); past ``max_refine`` points the next Osborne
    bound (valid, looser) stands. The peak's frequency is then zoomed in on
    with Osborne bounds and refined there."""
    M = _shift(S, sigma)
    fin = np.all(np.isfinite(M), axis=(1, 2))
    w, M = w[fin], M[fin]
    if w.size == 0:
        return MultiloopDisk(0.0, 0.0, None, *disk_range(0.0, sigma), sigma=sigma)
    d = osborne(M)
    ub0 = _scaled_norm(M, d)
    best, bi, bd = -math.inf, 0, d[0]
    order = np.argsort(-ub0, kind="stable")
    for k, i in enumerate(order):
        if ub0[i] <= best * (1.0 + rtol):  # within rtol: report this (valid) bound if it is the larger
            best = max(best, float(ub0[i]))
            break
        if k >= max_refine:  # the rest keep their (valid, looser) Osborne bound
            best = float(ub0[i])
            break
        ub, _, dd = mu_bounds(M[i], d[i])
        if ub > best:
            best, bi, bd = ub, int(i), dd
    wz, mz = _zoom_mu(S_at, w, bi, sigma)
    ub, lb, _ = mu_bounds(mz, bd)
    if ub < best:  # the zoom found nothing higher: keep the grid's point
        wz, (ub, lb, _) = float(w[bi]), mu_bounds(M[bi], bd)
        ub = max(ub, best)
    alpha = 1.0 / ub if ub > 0 else math.inf
    return MultiloopDisk(alpha, 1.0 / lb if lb > 0 else math.inf, float(wz), *disk_range(alpha, sigma), sigma=sigma)


def _zoom_mu(S_at: Callable[[np.ndarray], np.ndarray], w: np.ndarray, i: int, sigma: float, rounds: int = 6,
             pts: int = 8) -> tuple[float, np.ndarray]:
    """The frequency of the mu peak near grid point i, by the Osborne bound: (w, M there)."""
    w_best = float(w[i])
    M_best = _shift(S_at(np.array([w_best])), sigma)[0]
    best = float(_scaled_norm(M_best[None], osborne(M_best[None]))[0])
    lo, hi = float(w[max(i - 1, 0)]), float(w[min(i + 1, w.size - 1)])
    for _ in range(rounds):
        if not hi > lo:
            break
        W = np.geomspace(max(lo, hi * 1e-6), hi, pts) if lo <= 0 else np.geomspace(lo, hi, pts)
        Ms = _shift(S_at(W), sigma)
        v = _scaled_norm(Ms, osborne(Ms))
        v = np.where(np.isfinite(v), v, -np.inf)
        j = int(np.argmax(v))
        if v[j] > best:
            best, w_best, M_best = float(v[j]), float(W[j]), Ms[j]
        j = int(np.argmin(np.abs(W - w_best)))
        lo, hi = float(W[max(j - 1, 0)]), float(W[min(j + 1, pts - 1)])
    return w_best, M_best


def sigma_peak(X_at: Callable[[np.ndarray], np.ndarray], w: np.ndarray, X: np.ndarray, rounds: int = 3,
               pts: int = 12) -> Peak:
    """Peak of sigma_max(X) over frequency: the grid maximum, then zoomed in between its neighbours."""
    v = _grid_sigma_max(X)
    v = np.where(np.isfinite(v), v, -np.inf)
    i = int(np.argmax(v))
    best, wb = float(v[i]), float(w[i])
    lo, hi = float(w[max(i - 1, 0)]), float(w[min(i + 1, w.size - 1)])
    for _ in range(rounds):
        if not hi > lo:
            break
        W = np.geomspace(max(lo, hi * 1e-6), hi, pts) if lo <= 0 else np.geomspace(lo, hi, pts)
        vz = _grid_sigma_max(X_at(W))
        vz = np.where(np.isfinite(vz), vz, -np.inf)
        j = int(np.argmax(vz))
        if vz[j] > best:
            best, wb = float(vz[j]), float(W[j])
        lo, hi = float(W[max(j - 1, 0)]), float(W[min(j + 1, pts - 1)])
    return Peak(best, wb)


# ------------------------------------------------------------------ loop at a time


def lat_rows(loop: MimoLoop, s: np.ndarray, outputs: bool = True,
             S: tuple[np.ndarray, np.ndarray | None] | None = None) -> np.ndarray:
    """Loop-at-a-time responses (rows, len(s)): the n_in plant inputs, then the n_out plant outputs
    (only the input rows when ``outputs`` is False); ``S``: (S_i, S_o) at ``s`` when known (S_o None:
    not known, or not needed: the cascade's output rows below). With fewer
    inputs than outputs (a cascade, :meth:`~.mimo_loop.MimoLoop.outputs_by_inputs`) the output rows come
    from the input side, as the zooms take them: S_o[k, k] = 1 - (Gs S_i Ks)[k, k]."""
    if not outputs:
        with np.errstate(all="ignore"):
            Si = np.linalg.inv(np.eye(loop.n_in) + loop.loop_gains(s, "input")) if S is None else S[0]
            return 1.0 / np.diagonal(Si, axis1=1, axis2=2).T - 1.0
    if loop.outputs_by_inputs():
        L, Gs, Ks = loop.input_side(s)
        with np.errstate(all="ignore"):
            Si = np.linalg.inv(np.eye(loop.n_in) + L) if S is None else S[0]
            so = 1.0 - np.einsum("wki,wik->wk", Gs, Si @ Ks)
            return np.concatenate([1.0 / np.diagonal(Si, axis1=1, axis2=2).T - 1.0, 1.0 / so.T - 1.0])
    Si, So = loop.sensitivities(s) if S is None or S[1] is None else (S[0], S[1])
    with np.errstate(all="ignore"):
        return np.concatenate([1.0 / np.diagonal(Si, axis1=1, axis2=2).T - 1.0,
                               1.0 / np.diagonal(So, axis1=1, axis2=2).T - 1.0])


class _RowsEvaluator(Evaluator):
    """Loop-at-a-time rows as the SISO analysis' evaluator (it reads spin_T and calls it): every row
    at once (``__call__``), or the zooms' question, one row per point (:meth:`rows_at`): S_kk from one
    solve of (I + L) x = e_k per point, a third of an inverse, all points of all rows in one batch."""

    def __init__(self, loop: MimoLoop, outputs: bool):  # no cascade here
        self.loop, self.outputs = loop, outputs
        #: the delays a loop-at-a-time response can carry: its own channel and a return through another
        self.spin_T = 2.0 * loop.max_delay()
        self.calls = 0
        self.points = 0

    def __call__(self, w: np.ndarray, shift: float = 0.0) -> np.ndarray:
        self.calls += 1
        w = np.asarray(w, dtype=float)
        self.points += w.size
        return lat_rows(self.loop, -shift + 1j * w, self.outputs)

    def rows_at(self, w: np.ndarray, rows: np.ndarray) -> np.ndarray:
        self.calls += 1
        w, rows = np.asarray(w, dtype=float), np.asarray(rows, dtype=np.int64)
        self.points += w.size
        s, ni = 1j * w, self.loop.n_in
        out = np.empty(w.size, dtype=complex)
        inp = rows < ni
        if inp.any():
            out[inp] = self._side_rows(s[inp], rows[inp], "input")
        if not inp.all():
            k = rows[~inp] - ni
            by_inputs = self.loop.outputs_by_inputs()
            out[~inp] = self._output_rows_by_inputs(s[~inp], k) if by_inputs else self._side_rows(s[~inp], k, "output")
        return out

    def _side_rows(self, s: np.ndarray, k: np.ndarray, side: str) -> np.ndarray:
        """1/S_kk - 1 of channel k[i] at s[i] on one side: (I + L) x = e_k, S_kk = x_k."""
        n = self.loop.n_out if side == "output" else self.loop.n_in
        p = np.arange(s.size)
        e = np.zeros((s.size, n, 1))
        e[p, k, 0] = 1.0
        with np.errstate(all="ignore"):
            x = solve_points(np.eye(n) + self.loop.loop_gains(s, side), e)
            return 1.0 / x[p, k, 0] - 1.0

    def _output_rows_by_inputs(self, s: np.ndarray, k: np.ndarray) -> np.ndarray:
        """Output row k[i] at s[i] on the smaller input side: S_o = I - Gs (I + Ks Gs)^-1 Ks, so
        S_o[k, k] = 1 - Gs[k, :] x with (I + Ks Gs) x = Ks[:, k] (fewer inputs than outputs: a cascade)."""
        L, g_row, k_col = self.loop.input_side_rows(s, k)
        with np.errstate(all="ignore"):
            x = solve_points(np.eye(self.loop.n_in) + L, k_col[:, :, None])
            s_kk = 1.0 - np.einsum("wi,wi->w", g_row, x[:, :, 0])
            return 1.0 / s_kk - 1.0


def loop_at_a_time(loop: MimoLoop, w: np.ndarray, L: np.ndarray | None = None,
                   peaks: tuple[str, ...] = PEAK_FIGURES) -> list[BreakFigures]:
    """Margins at every driven plant input (break point ``plant_input``, named after the loop that
    drives it) and measured output (``plant_output``, named after its loop), all other channels
    closed; ``L``: :func:`lat_rows` on ``w`` when known; ``peaks``: the peak figures zoomed in on
    (:func:`~gaintune.verification.margins.row_margins`).
    All break points are analysed together; a zoom evaluates each point's own row only.

    With a diagonal controller (decentralised loops) breaking loop k at its plant input or at its
    plant output opens the same SISO loop (``C_k`` in series either way): it is analysed once, copied."""
    diag = loop.diagonal_controller()
    if L is None:
        L = lat_rows(loop, 1j * np.asarray(w, dtype=float), not diag)
    L0 = lat_rows(loop, np.zeros(1), not diag)[:, 0]
    names = ([(loop.input_label(k), "plant_input") for k in range(loop.n_in)]
             + [(nm, "plant_output") for nm in loop.names])
    rows = loop.n_in if diag else loop.n_in + loop.n_out
    figs = row_margins(_RowsEvaluator(loop, not diag), w, L[:rows], names[:rows], L0[:rows], peaks)
    if diag:
        figs += [replace(f, break_point="plant_output", crossings=[replace(c) for c in f.crossings]) for f in figs]
    return figs
