"""Cascade loop algebra, vectorised over a leading batch axis of gain sets.

Structure (loops listed outer first; loop ``k`` has reference ``r_k`` and output ``v_k``)::

    r_0 = 0 (external reference),  r_k = v_{k-1},  u = v_{n-1}
    PID loop:  v_k = F_k(s) r_k - C_k(s) y_k
               C_k = Kp + Ki/s + Kd s/(Tf s + 1)          (feedback path)
               F_k = b Kp + Ki/s + c Kd s/(Tf s + 1)      (setpoint path)
    LQ loop:   v = -K x + Kint/s (r - y_m) + Nr r       (innermost only)
    plant:     y = (C (sI - A)^-1 B + D) e^{-sT} u,    T = plant delay + sampling delay

Every loop's feedback signal is linear in ``u``: ``v_k = F_k r_k + m_k u`` with
``m_k = -C_k p_k`` (``p_k`` = u -> y_k) or ``m = -(K X + Kint/s p_m)`` for LQ
(``X`` = u -> x). From that, per frequency:

* ``g_k`` (v_k per unit u with the loops 0..k closed around it):
  ``g_{-1} = 0``, ``g_k = F_k g_{k-1} + m_k``;
* ``H_k`` (r_k -> u with loops k..n-1 closed): ``H_n = 1``,
  ``H_k = H_{k+1} F_k / (1 - H_{k+1} m_k)``;
* loop ``i`` broken at its controller output (others closed): ``L_i = -g_i H_{i+1}``;
* loop broken at the plant input (every loop passes through u): ``L_u = -g_{n-1}``.

The same structure gives the delay-free (or Padé) closed-loop state matrix whose
eigenvalues are the closed-loop poles, and the open-loop poles of the system cut
at the plant input (needed by the argument-principle stability test).

The algebra works on any response arrays: ``loop_responses(..., sampled=sp)`` feeds
it the sampled plant and the controllers' discrete laws at z = e^{s dt}
(:mod:`gaintune.verify.sampled`), and :meth:`Cascade.closed_loop_sampled` is the
sampled closed loop's transition matrix (plant, input buffer, controller states).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.controllers.pid import pid_params
from gaintune.errors import GainError, SpecError
from gaintune.plants.plant import LinearModel
from gaintune.spec import TuningSpec
from gaintune.verify.sampled import SampledPlant, discrete_ops, sample_plant

__all__ = ["LoopCtl", "Cascade", "build_cascade", "observable_part", "sampling_delay", "pade_coeffs", "pade_response",
           "pade_poles", "pade_ss", "sampled_grid", "sampled_stability", "nyquist_count_sampled", "SampledPlant", "sample_plant"]


def sampling_delay(spec: TuningSpec) -> float:
    """Sample-and-hold approximation: dt/2 of extra input delay (largest scenario dt)."""
    return 0.5 * max(sc.dt for sc in spec.scenarios)


@lru_cache(maxsize=32)
def _pade_unit(order: int) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Padé (order, order) of e^{-p} (unit delay) and a state-space realisation of it."""
    import control
    import scipy.signal

    num, den = control.pade(1.0, order)
    num, den = np.asarray(num, dtype=float), np.asarray(den, dtype=float)
    Ad, Bd, Cd, Dd = scipy.signal.tf2ss(num, den)
    return num, den, (Ad, Bd, Cd, float(Dd[0, 0]))


def pade_coeffs(T: float, order: int) -> tuple[np.ndarray, np.ndarray]:
    """(num, den) of the (order, order) Padé approximant of e^{-sT} (descending powers of s)."""
    if T <= 0:
        return np.array([1.0]), np.array([1.0])
    num, den, _ = _pade_unit(order)
    k = np.arange(num.size - 1, -1, -1)
    return num * T**k, den * T**k


def pade_response(s: np.ndarray, T: float, order: int) -> np.ndarray:
    """Padé approximant of e^{-sT} at s, evaluated in the well-conditioned variable p = sT."""
    num, den, _ = _pade_unit(order)
    p = s * T
    return np.polyval(num, p) / np.polyval(den, p)


def pade_poles(T: float, order: int) -> np.ndarray:
    return np.roots(_pade_unit(order)[1]) / T


def pade_ss(T: float, order: int):
    """(Ad, Bd, Cd, Dd) of the Padé delay: the unit-delay realisation with time scaled by T."""
    Ad, Bd, Cd, Dd = _pade_unit(order)[2]
    return Ad / T, Bd / T, Cd, Dd


def controller_state_index(loops, start: int) -> tuple[list[tuple[int | None, int | None]], int]:
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
    Kp: np.ndarray | None = None
    Ki: np.ndarray | None = None
    Kd: np.ndarray | None = None
    Tf: np.ndarray | None = None
    b: float = 1.0
    c: float = 0.0
    K: np.ndarray | None = None  # (B, n)
    Kint: np.ndarray | None = None
    Nr: np.ndarray | None = None

    def n_states(self) -> int:
        return int(self.has_i) + int(self.has_d)


@dataclass
class Cascade:
    """Controllers of a spec for a batch of gain sets, plus the loop names."""

    loops: list[LoopCtl]
    batch: int
    names: list[str] = field(default_factory=list)

    @property
    def measured(self) -> tuple[int, ...] | None:
        """Measured output indices, or None when an LQ loop feeds back the full state."""
        if any(lp.kind == "lq" for lp in self.loops):
            return None
        return tuple(sorted({lp.out_idx for lp in self.loops}))

    @property
    def break_names(self) -> list[tuple[str, str]]:
        """(loop, break point) per row of :meth:`loop_responses`."""
        return [(lp.name, "controller_output") for lp in self.loops] + [("plant", "plant_input")]

    # ------------------------------------------------------------ frequency
    def controller_responses(self, s: np.ndarray, lin: LinearModel, X: np.ndarray, P: np.ndarray, ops=None):
        """Per loop (F_k, m_k), each (B, W), given X = u->x (W, n) and P = u->y (W, q) incl. delay.

        ``ops``: (integral operator, derivative operator Tf -> array) at the frequencies; default
        the continuous 1/s and s/(Tf s + 1); :func:`gaintune.verify.sampled.discrete_ops` for the
        simulator's discrete laws.
        """
        out = []
        if ops is None:
            inv_s = 1.0 / s

            def deriv(tf):
                return s / (tf * s + 1.0)
        else:
            inv_s, deriv = ops
        for lp in self.loops:
            if lp.kind == "pid":
                Kp, Ki, Kd, Tf = (a[:, None] for a in (lp.Kp, lp.Ki, lp.Kd, lp.Tf))
                I = Ki * inv_s if lp.has_i else 0.0
                Dd = Kd * deriv(Tf) if lp.has_d else 0.0
                C = Kp + I + Dd
                F = lp.b * Kp + I + lp.c * Dd
                m = -C * P[None, :, lp.out_idx]
            else:
                KX = lp.K @ X.T  # (B, W)
                I = lp.Kint[:, None] * inv_s if lp.has_i else 0.0
                m = -(KX + I * P[None, :, lp.out_idx])
                F = lp.Nr[:, None] + I
            out.append((np.broadcast_to(F, (self.batch, s.size)), m))
        return out

    def loop_responses(self, s: np.ndarray, lin: LinearModel, delay: np.ndarray | complex = 1.0,
                       sampled: SampledPlant | None = None) -> np.ndarray:
        """Open-loop responses at complex frequencies ``s``: (n_loops + 1, B, W).

        ``delay`` is the delay factor at ``s`` (e^{-sT} or its Padé approximant), shape (W,).
        ``sampled``: evaluate the sampled loop instead (plant as the simulator steps it, the
        controllers' discrete laws) at z = e^{s dt}; ``delay`` is then unused (the sampled
        plant holds its delays). Rows: each loop broken at its controller output, then the plant input.
        """
        s = np.asarray(s)
        if sampled is not None:
            with np.errstate(all="ignore"):
                z = np.exp(s * sampled.dt)
                X, P = sampled.responses(z)
                _, integ, deriv = discrete_ops(z, sampled.dt)
            resp = self.controller_responses(s, lin, X, P, (integ, deriv))
        else:
            X = plant_state_response(lin, s) * np.asarray(delay)[:, None]  # (W, n)
            P = X @ lin.C.T + (lin.D[:, 0][None, :] * np.asarray(delay)[:, None])  # (W, q)
            resp = self.controller_responses(s, lin, X, P)
        return self.cascade(resp, s.size)

    def cascade(self, resp, W: int) -> np.ndarray:
        """The break-point loops (n_loops + 1, B, W) from the per-loop (F_k, m_k)."""
        n = len(self.loops)
        g = []
        prev = np.zeros((self.batch, W), dtype=complex)
        for F, m in resp:
            prev = F * prev + m
            g.append(prev)
        H = [None] * (n + 1)
        H[n] = np.ones((self.batch, W), dtype=complex)
        with np.errstate(divide="ignore", invalid="ignore"):
            for k in range(n - 1, -1, -1):
                F, m = resp[k]
                H[k] = H[k + 1] * F / (1.0 - H[k + 1] * m)
            L = np.empty((n + 1, self.batch, W), dtype=complex)
            for i in range(n):
                L[i] = -g[i] * H[i + 1]
        L[n] = -g[n - 1]
        return L

    # -------------------------------------------------------- state space
    def open_loop_poles(self, lin: LinearModel, pade: tuple[float, int] | None) -> np.ndarray:
        """Poles of the system cut at the plant input (same for every batch member): plant,
        Padé, controller integrators (0) and derivative filters (-1/Tf, per batch)."""
        base = list(plant_eigvals(lin))
        if pade is not None:
            base += list(pade_poles(*pade))
        poles = np.tile(np.array(base, dtype=complex), (self.batch, 1))
        extra = []
        for lp in self.loops:
            if lp.has_i:
                extra.append(np.zeros(self.batch, dtype=complex))
            if lp.kind == "pid" and lp.has_d:
                extra.append(-1.0 / lp.Tf + 0j)
        if extra:
            poles = np.concatenate([poles, np.stack(extra, axis=1)], axis=1)
        return poles

    def closed_loop_A(self, lin: LinearModel, pade: tuple[float, int] | None) -> np.ndarray:
        """Closed-loop state matrices (B, N, N): plant, Padé delay states, controller states.

        Signals are rows over [states, u]; the algebraic loop through u is solved at the end.
        """
        Bsz = self.batch
        n = lin.A.shape[0]
        if pade is not None and pade[0] > 0:
            Ad, Bd, Cd, Dd = pade_ss(*pade)
        else:
            Ad = np.zeros((0, 0))
            Bd = np.zeros((0, 1))
            Cd = np.zeros((1, 0))
            Dd = 1.0
        npd = Ad.shape[0]
        ctl_idx, N = controller_state_index(self.loops, n + npd)

        def zero():
            return np.zeros((Bsz, N)), np.zeros(Bsz)

        def unit(j):
            r = np.zeros((Bsz, N))
            r[:, j] = 1.0
            return r, np.zeros(Bsz)

        # Delayed plant input u_p = Cd x_pade + Dd u
        up_x = np.zeros((Bsz, N))
        up_x[:, n : n + npd] = Cd[0]
        up = (up_x, np.full(Bsz, Dd))

        def output(j):
            rx = np.zeros((Bsz, N))
            rx[:, :n] = lin.C[j]
            d = lin.D[j, 0]
            return rx + d * up[0], d * up[1]

        def lin_comb(*terms):
            rx, ru = zero()
            for coef, (tx, tu) in terms:
                coef = np.asarray(coef, dtype=float)
                cx = coef[:, None] if coef.ndim else coef
                rx = rx + cx * tx
                ru = ru + coef * tu
            return rx, ru

        derivs: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        r = zero()
        for lp, (ii, di) in zip(self.loops, ctl_idx):
            if lp.kind == "pid":
                y = output(lp.out_idx)
                e = lin_comb((1.0, r), (-1.0, y))
                terms = [(lp.Kp * lp.b, r), (-lp.Kp, y)]
                if ii is not None:
                    derivs[ii] = e
                    terms.append((lp.Ki, unit(ii)))
                if di is not None:
                    ed = lin_comb((lp.c, r), (-1.0, y), (-1.0, unit(di)))  # c r - y - xd
                    derivs[di] = lin_comb((1.0 / lp.Tf, ed))
                    terms.append((lp.Kd / lp.Tf, ed))
                v = lin_comb(*terms)
            else:
                y = output(lp.out_idx)
                fx = np.zeros((Bsz, N))
                fx[:, :n] = -lp.K
                terms = [(1.0, (fx, np.zeros(Bsz))), (lp.Nr, r)]
                if ii is not None:
                    derivs[ii] = lin_comb((1.0, r), (-1.0, y))
                    terms.append((lp.Kint, unit(ii)))
                v = lin_comb(*terms)
            r = v
        ux, uu = r
        with np.errstate(divide="ignore", invalid="ignore"):
            u_row = ux / (1.0 - uu)[:, None]  # u = u_row @ X

        def resolve(sig):
            sx, su = sig
            return sx + su[:, None] * u_row

        Acl = np.zeros((Bsz, N, N))
        upr = resolve(up)
        Acl[:, :n, :n] += lin.A
        Acl[:, :n, :] += lin.B[:, 0][None, :, None] * upr[:, None, :]
        if npd:
            Acl[:, n : n + npd, n : n + npd] += Ad
            Acl[:, n : n + npd, :] += Bd[:, 0][None, :, None] * u_row[:, None, :]
        for j, sig in derivs.items():
            Acl[:, j, :] = resolve(sig)
        return Acl


    # ------------------------------------------------------- sampled loop
    def open_loop_poles_sampled(self, sp: SampledPlant) -> np.ndarray:
        """z-plane poles of the sampled system cut at the plant input (B, P): plant (Ad), the
        input buffer (z = 0), integrators (z = 1) and derivative filters (z = Tf/(Tf + dt))."""
        base = list(sp.eigvals()) + [0.0] * sp.buffer_len
        poles = np.tile(np.array(base, dtype=complex), (self.batch, 1))
        extra = []
        for lp in self.loops:
            if lp.has_i:
                extra.append(np.ones(self.batch, dtype=complex))
            if lp.kind == "pid" and lp.has_d:
                extra.append(lp.Tf / (lp.Tf + sp.dt) + 0j)
        if extra:
            poles = np.concatenate([poles, np.stack(extra, axis=1)], axis=1)
        return poles

    def closed_loop_sampled(self, sp: SampledPlant) -> np.ndarray:
        """Closed-loop transition matrices (B, N, N) of the sampled loop, as the simulator steps it.

        States: plant x[k], past inputs u[k-1] .. u[k-m], integrator sums and derivative-filter
        states. Signals are rows over the states plus a coefficient of u[k] (only feedthrough
        without delay gives one), solved for at the end as in :meth:`closed_loop_A`.
        """
        Bsz, dt = self.batch, sp.dt
        n, m = sp.n, sp.buffer_len
        ctl_idx, N = controller_state_index(self.loops, n + m)
        z0 = np.zeros((Bsz, N))

        def unit(j):
            r = np.zeros((Bsz, N))
            r[:, j] = 1.0
            return r, np.zeros(Bsz)

        def past(j):  # u[k-j]
            return (z0, np.ones(Bsz)) if j == 0 else unit(n + j - 1)

        def comb(*terms):
            rx, ru = np.zeros((Bsz, N)), np.zeros(Bsz)
            for coef, (tx, tu) in terms:
                coef = np.asarray(coef, dtype=float)
                rx = rx + (coef[:, None] if coef.ndim else coef) * tx
                ru = ru + coef * tu
            return rx, ru

        def output(j):
            rx = np.zeros((Bsz, N))
            rx[:, :n] = sp.C[j]
            if sp.D[j] != 0.0:
                return comb((1.0, (rx, np.zeros(Bsz))), (sp.D[j], past(sp.dD)))
            return rx, np.zeros(Bsz)

        nxt: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        r = (z0, np.zeros(Bsz))
        for lp, (ii, di) in zip(self.loops, ctl_idx):
            y = output(lp.out_idx)
            e = comb((1.0, r), (-1.0, y))
            if lp.kind == "pid":
                terms = [(lp.Kp * lp.b, r), (-lp.Kp, y)]
                if ii is not None:
                    nxt[ii] = comb((1.0, unit(ii)), (1.0, e))  # sum of e up to k
                    terms.append((lp.Ki * dt, nxt[ii]))
                if di is not None:
                    al = lp.Tf / (lp.Tf + dt)
                    be = lp.Kd / (lp.Tf + dt)
                    ed = comb((lp.c, r), (-1.0, y))
                    nxt[di] = comb((al, unit(di)), (1.0, ed))
                    terms += [(be, ed), (be * (al - 1.0), unit(di))]
            else:
                fx = np.zeros((Bsz, N))
                fx[:, :n] = -lp.K
                terms = [(1.0, (fx, np.zeros(Bsz))), (lp.Nr, r)]
                if ii is not None:
                    nxt[ii] = comb((1.0, unit(ii)), (1.0, e))
                    terms.append((lp.Kint * dt, nxt[ii]))
            r = comb(*terms)
        ux, uu = r
        with np.errstate(divide="ignore", invalid="ignore"):
            u_row = ux / (1.0 - uu)[:, None]  # u[k] = u_row @ state

        def resolve(sig):
            sx, su = sig
            return sx + su[:, None] * u_row

        Acl = np.zeros((Bsz, N, N))
        Acl[:, :n, :n] += sp.Ad
        Acl[:, :n, :] += sp.G0[None, :, None] * resolve(past(sp.d))[:, None, :]
        if sp.has_G1:
            Acl[:, :n, :] += sp.G1[None, :, None] * resolve(past(sp.d + 1))[:, None, :]
        if m:
            Acl[:, n, :] = u_row
            for j in range(1, m):
                Acl[:, n + j, n + j - 1] = 1.0
        for j, sig in nxt.items():
            Acl[:, j, :] = resolve(sig)
        return Acl


_EIGVALS_CACHE: dict[int, tuple[LinearModel, np.ndarray]] = {}


def plant_eigvals(lin: LinearModel) -> np.ndarray:
    """Eigenvalues of ``lin.A``, remembered per model object (only the gains change between verifications)."""
    hit = _EIGVALS_CACHE.get(id(lin))
    if hit is not None and hit[0] is lin:
        return hit[1]
    v = np.linalg.eigvals(lin.A) if lin.A.size else np.zeros(0, dtype=complex)
    if len(_EIGVALS_CACHE) > 512:
        _EIGVALS_CACHE.clear()
    _EIGVALS_CACHE[id(lin)] = (lin, v)
    return v


_SCHUR_CACHE: dict[int, tuple[LinearModel, np.ndarray, np.ndarray, np.ndarray]] = {}


def _schur(lin: LinearModel):
    hit = _SCHUR_CACHE.get(id(lin))
    if hit is not None and hit[0] is lin:
        return hit[1:]
    import scipy.linalg

    T, Z = scipy.linalg.schur(lin.A.astype(complex), output="complex")
    zb = Z.conj().T @ lin.B[:, 0].astype(complex)
    if len(_SCHUR_CACHE) > 512:
        _SCHUR_CACHE.clear()
    _SCHUR_CACHE[id(lin)] = (lin, T, Z, zb)
    return T, Z, zb


def plant_state_response(lin: LinearModel, s: np.ndarray) -> np.ndarray:
    """X(s) = (sI - A)^-1 B for each s: (W, n).

    Uses the complex Schur form A = Z T Z^H (unitary, so robust for defective A):
    a vectorised back-substitution over the frequencies, O(n^2) numpy operations.
    """
    T, Z, zb = _schur(lin)
    n = T.shape[0]
    x = np.empty((n, s.size), dtype=complex)
    with np.errstate(all="ignore"):
        for i in range(n - 1, -1, -1):
            acc = np.full(s.size, zb[i])
            if i + 1 < n:
                acc = acc + T[i, i + 1 :] @ x[i + 1 :]
            x[i] = acc / (s - T[i, i])
    return (Z @ x).T
#: Batched eigenvalue problems of the sampled closed loop are solved up to this many states;
#: longer input buffers (long delays) use the batched discrete Nyquist count, which is cheaper
#: there (B = 64, PID on a lag: 46 ms by eigenvalues vs 20 ms at 53 states) and agrees.
QUICK_EIG_MAX = 32


def sampled_grid(w: np.ndarray, sp: SampledPlant) -> np.ndarray:
    """A log grid like ``w`` (same size, same lower end or lower) ending exactly at the Nyquist frequency pi/dt."""
    wn = sp.nyquist
    lo = min(float(w[0]), wn * 1e-4)
    g = np.logspace(np.log10(lo), np.log10(wn), w.size)
    g[0], g[-1] = lo, wn
    return g


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
    parts = [[0.0], np.logspace(np.log10(eps / 100), np.log10(wn), 400), np.linspace(0.0, wn, int(wn * spin / 0.3) + 2)]
    pz = np.unique(ol[np.abs(ol) > 0.5].ravel())
    if pz.size:
        s_p = np.log(pz.astype(complex)) / dt
        up = s_p[s_p.imag > 0]
        dist = np.maximum(np.abs(up.real + eps), eps)
        parts.append((up.imag[:, None] + dist[:, None] * np.concatenate([-(2.0 ** np.arange(9, -4, -1)), [0.0],
                                                                        2.0 ** np.arange(-3, 10)])[None, :]).ravel())
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


_OBS_CACHE: dict[tuple, tuple[LinearModel, LinearModel, np.ndarray]] = {}


def _orth(M: np.ndarray, tol: float) -> np.ndarray:
    if M.size == 0:
        return M
    U, sv, _ = np.linalg.svd(M, full_matrices=False)
    r = int(np.sum(sv > tol * max(1.0, sv[0] if sv.size else 1.0)))
    return U[:, :r]


def observable_part(lin: LinearModel, measured: tuple[int, ...], tol: float = 1e-9) -> tuple[LinearModel, np.ndarray]:
    """Restrict ``lin`` to the modes observable from the measured outputs.

    Modes no loop measures are not moved by feedback: they are open-loop poles of
    the closed loop too. Returns (reduced model, eigenvalues of the unobservable part).
    Only valid for PID cascades (LQ state feedback sees every state).
    """
    key = (id(lin), measured)
    hit = _OBS_CACHE.get(key)
    if hit is not None and hit[0] is lin:
        return hit[1], hit[2]
    A = lin.A
    n = A.shape[0]
    scale = max(np.linalg.norm(A), 1e-300)
    Ah = A / scale
    V = _orth(lin.C[list(measured)].T, tol)
    for _ in range(n):
        W = _orth(np.hstack([V, Ah.T @ V]), tol)
        if W.shape[1] == V.shape[1]:
            break
        V = W
    r = V.shape[1]
    if r == n:
        red, un = lin, np.zeros(0, dtype=complex)
    else:
        U, _, _ = np.linalg.svd(V, full_matrices=True)
        V1, V2 = U[:, :r], U[:, r:]
        red = LinearModel(V1.T @ A @ V1, V1.T @ lin.B, lin.C @ V1, lin.D, lin.delay, [f"z{i}" for i in range(r)],
                          lin.outputs, np.zeros(r), lin.u0, lin.y0)
        un = np.linalg.eigvals(V2.T @ A @ V2)
    if len(_OBS_CACHE) > 256:
        _OBS_CACHE.clear()
    _OBS_CACHE[key] = (lin, red, un)
    return red, un


def _out_index(spec: TuningSpec, lin: LinearModel, i: int) -> int:
    loop = spec.loops[i]
    name = loop.measure or lin.outputs[0]
    if name not in lin.outputs:
        raise SpecError(f"loops[{i}].measure", f"unknown output {name!r}; plant outputs are {lin.outputs}")
    return lin.outputs.index(name)


def pid_arrays(loop, G: np.ndarray, names: list[str]) -> dict[str, np.ndarray]:
    """:func:`gaintune.controllers.pid.pid_params` over a batch (G: (B, n_loop_gains)), as a dict."""
    p = pid_params(loop, {nm: G[:, j] for j, nm in enumerate(names)})
    return {"Kp": p.Kp, "Ki": p.Ki, "Kd": p.Kd, "Tf": p.Tf}


def build_cascade(
    spec: TuningSpec, layout: GainLayout, full: np.ndarray, lin: LinearModel, lq_cache: dict | None = None
) -> Cascade:
    """Controllers for a batch of full gain vectors ``full`` (B, n_gains) on the linear model ``lin``.

    LQ gains in ``weights`` mode are computed once per gain set with :func:`control.lqr` on
    ``lin`` (pass the nominal model: gains are frozen for robustness analysis).
    """
    from gaintune.controllers.lq import lq_gains

    full = np.atleast_2d(np.asarray(full, dtype=float))
    Bsz = full.shape[0]
    loops: list[LoopCtl] = []
    for i, loop in enumerate(spec.loops):
        cols = [k for k, sl in enumerate(layout.slots) if sl.loop == i]
        names = [layout.slots[k].name for k in cols]
        G = full[:, cols]
        out_idx = _out_index(spec, lin, i)
        name = loop.name or f"loop{i}"
        if loop.is_lq:
            Ks, Kis, Nrs = [], [], []
            for b in range(Bsz):
                gd = dict(zip(names, G[b]))
                lg = lq_gains(loop, gd, lin, out_idx)
                Ks.append(lg.K)
                Kis.append(lg.Kint)
                Nrs.append(lg.Nr)
            loops.append(
                LoopCtl(name, "lq", out_idx, has_i=loop.type == "lqi", K=np.array(Ks, dtype=float).reshape(Bsz, -1),
                        Kint=np.array(Kis, dtype=float), Nr=np.array(Nrs, dtype=float))
            )
        else:
            pa = pid_arrays(loop, G, names)
            has_d = "d" in loop.type[1:]
            if has_d and np.any(pa["Tf"] <= 0):
                raise GainError(f"gains.{name}", "derivative filter time constant is zero; give Kp > 0")
            loops.append(
                LoopCtl(name, "pid", out_idx, has_i="i" in loop.type[1:], has_d=has_d, Kp=pa["Kp"], Ki=pa["Ki"],
                        Kd=pa["Kd"], Tf=pa["Tf"], b=loop.b, c=loop.c)
            )
    return Cascade(loops, Bsz, [lp.name for lp in loops])
