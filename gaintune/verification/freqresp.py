"""The frequency-response engine: the open-loop responses L at every break point, and root zooming.

:class:`Evaluator` evaluates, for one gain set, L at arbitrary frequencies for every row of
:meth:`gaintune.verification.cascade.Cascade.loop_responses` (each loop broken at its controller
output, then the plant input): L(jw) of the continuous loop with its delay
(:class:`DelayModel`: exact e^{-sT} or a Padé approximant), or L(e^{jw dt}) of the sampled
loop (:mod:`gaintune.verification.sampled`). Everything is numpy (no python-control objects in
the hot path). :func:`zoom_roots` refines sign changes of a function of L located on a
grid, vectorised over all brackets at once; :func:`char_freqs` gives the loop's
characteristic frequencies, from which the analysis grids are sized.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gaintune.lti.modes import complex_schur, plant_eigvals
from gaintune.lti.pade import pade_response
from gaintune.plants.plant import LinearModel
from gaintune.verification.cascade import Cascade
from gaintune.verification.sampled import SampledPlant

__all__ = ["DelayModel", "Evaluator", "char_freqs", "zoom_roots"]


@dataclass(frozen=True)
class DelayModel:
    """Total input delay and how it enters frequency responses."""

    T: float
    pade_order: int | None = None

    def factor(self, s: np.ndarray) -> np.ndarray:
        """The delay factor at complex frequencies ``s``: e^{-sT}, or its Padé approximant."""
        if self.T <= 0:
            return np.ones_like(s)
        if self.pade_order is None:
            return np.exp(-s * self.T)
        return pade_response(s, self.T, self.pade_order)

    def pade(self, default_order: int = 6) -> tuple[float, int] | None:
        """(T, order) for pole computations: the stated order, else ``default_order``."""
        if self.T <= 0:
            return None
        return (self.T, self.pade_order or default_order)


def _plant_eig_abs(lin: LinearModel) -> list[float]:
    return list(np.abs(plant_eigvals(lin)))


def char_freqs(cas: Cascade, lin: LinearModel, delay: DelayModel) -> np.ndarray:
    """Characteristic frequencies (rad/s) of the loop, member 0 of ``cas``.

    The plant's eigenvalue magnitudes, each PID loop's corners |Ki/Kp|, |Kp/Kd| and 1/Tf, and
    1/T of the delay; those not finite and positive are left out ([1.0] when none is left).
    """
    f = _plant_eig_abs(lin)
    for lp in cas.loops:
        if lp.kind == "pid":
            kp, ki, kd, tf = float(lp.Kp[0]), float(lp.Ki[0]), float(lp.Kd[0]), float(lp.Tf[0])
            # magnitudes: a reverse-acting loop has Kp, Ki, Kd all negative
            if lp.has_i and kp != 0:
                f.append(abs(ki / kp))
            if lp.has_d and kd != 0:
                f += [abs(kp / kd), 1.0 / tf]
    if delay.T > 0:
        f.append(1.0 / delay.T)
    kept = np.array([x for x in f if np.isfinite(x) and x > 1e-12])
    return kept if kept.size else np.array([1.0])


#: Frequencies evaluated per block (see :meth:`Evaluator.__call__`).
_CHUNK = 4096


def _dot(c: np.ndarray, X: np.ndarray) -> np.ndarray:
    """c @ X for a short coefficient vector, without BLAS (whose threads only add latency here)."""
    if c.size > 8:
        return c @ X
    out = c[0] * X[0]
    for i in range(1, c.size):
        out = out + c[i] * X[i]
    return out


#: A response over the frequencies, or a constant one.
_Val = np.ndarray | complex


@dataclass(frozen=True)
class _PidScalars:
    """A PID loop's gains as Python scalars (member 0 of the cascade)."""

    out_idx: int
    has_i: bool
    has_d: bool
    kp: float
    ki: float
    kd: float
    tf: float
    b: float
    c: float


@dataclass(frozen=True)
class _LqScalars:
    """An LQ loop's gains: the state feedback in Schur coordinates K Z, the integral and reference gains."""

    out_idx: int
    has_i: bool
    KZ: np.ndarray
    kint: float
    nr: float


@dataclass
class _Point:
    """Per-frequency factors of one evaluation: the continuous loop at s, or the sampled one at z = e^{s dt}."""

    s: np.ndarray
    x_at: np.ndarray  # where the resolvent is evaluated: s, or z (the back-substitution runs in z)
    d: _Val  # input delay factor: e^{-sT} (or Padé), or z^-d
    dD: _Val  # feedthrough delay factor: as d, or z^-dD
    zi: np.ndarray | None = None  # z^-1 (sampled)
    one_m: np.ndarray | None = None  # 1 - z^-1 (sampled)
    dt: float = 0.0


class Evaluator:
    """L at arbitrary frequencies for one gain set (rows: break points).

    Same algebra as :meth:`Cascade.loop_responses` (the reference, used for batches > 1),
    specialised for one gain set: controller gains as Python scalars, the plant's complex
    Schur form and the output rows C Z precomputed, and only the measured outputs formed,
    so one call is a few dozen numpy operations over the frequency vector.

    ``sampled``: evaluate the sampled loop (:mod:`gaintune.verification.sampled`) at z = e^{s dt}
    instead of the continuous one (``delay`` is then unused; without ``sampled`` it is required).
    """

    def __init__(self, cas: Cascade, lin: LinearModel, delay: DelayModel | None, sampled: SampledPlant | None = None):
        if sampled is None and delay is None:
            raise ValueError("Evaluator: the continuous loop needs its delay model")
        self.cas, self.lin, self.sampled = cas, lin, sampled
        self.delay = delay if delay is not None else DelayModel(0.0)  # unused by the sampled loop
        #: delay (s) whose phase spin e^{-jwT} the grids must resolve
        self.spin_T = sampled.total_delay if sampled is not None else max(self.delay.T, 0.0)
        self.calls = 0
        self.points = 0
        self.fast = cas.batch == 1
        if self.fast:
            self._prepare(cas, lin, sampled)

    def _prepare(self, cas: Cascade, lin: LinearModel, sampled: SampledPlant | None) -> None:
        """The Schur form of the plant (continuous, or the sampled plant's), C Z and the scalar gains."""
        self._zb1: np.ndarray | None = None
        C = sampled.C if sampled is not None else lin.C
        n = sampled.n if sampled is not None else lin.A.shape[0]
        Z = np.zeros((0, 0), dtype=complex)
        self._T, self._zb, self._diag = Z, np.zeros(0, dtype=complex), np.zeros(0, dtype=complex)
        if n and sampled is not None:
            T, Z, zb0, zb1, diag = sampled.schur()
            self._T, self._zb, self._zb1, self._diag = T, zb0, (zb1 if sampled.has_G1 else None), diag
        elif n:
            T, Z, zb = complex_schur(lin)
            self._T, self._zb = T, zb
            self._diag = np.diag(T).copy()
        CZ = C.astype(complex) @ Z if n else np.zeros((C.shape[0], 0), dtype=complex)
        self._n = n
        outs = sorted({lp.out_idx for lp in cas.loops})
        self._outs = {j: (CZ[j], complex(lin.D[j, 0])) for j in outs}
        self._ctl: list[_PidScalars | _LqScalars] = []
        for lp in cas.loops:
            if lp.kind == "pid":
                self._ctl.append(_PidScalars(lp.out_idx, lp.has_i, lp.has_d, float(lp.Kp[0]), float(lp.Ki[0]),
                                             float(lp.Kd[0]), float(lp.Tf[0]), float(lp.b), float(lp.c)))
            else:
                KZ = (np.asarray(lp.K[0], dtype=float) @ Z) if n else np.zeros(0, dtype=complex)
                self._ctl.append(_LqScalars(lp.out_idx, lp.has_i, KZ, float(lp.Kint[0]) if lp.has_i else 0.0,
                                            float(lp.Nr[0])))

    def __call__(self, w: np.ndarray, shift: float = 0.0) -> np.ndarray:
        """L (n_loops + 1, W) at s = -shift + jw (rows as :meth:`Cascade.loop_responses`)."""
        self.calls += 1
        w = np.asarray(w, dtype=float)
        self.points += w.size
        s = -shift + 1j * w
        with np.errstate(all="ignore"):
            if not self.fast:
                if self.sampled is not None:
                    return self.cas.loop_responses(s, self.lin, sampled=self.sampled)[:, 0, :]
                return self.cas.loop_responses(s, self.lin, self.delay.factor(s))[:, 0, :]
            if s.size <= _CHUNK:
                return self._eval(s)
            # chunks keep every temporary below glibc's mmap threshold (128 KiB): large
            # temporaries are fresh mappings, and their page faults cost more than the arithmetic
            out = np.empty((len(self.cas.loops) + 1, s.size), dtype=complex)
            for i in range(0, s.size, _CHUNK):
                out[:, i : i + _CHUNK] = self._eval(s[i : i + _CHUNK])
            return out

    def rows_at(self, w: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """L of row ``rows[i]`` at ``w[i]``, (len(w),): what a zoom asks, each bracket for its own row.
        Here every row is formed and the asked one kept; an evaluator whose rows cost separately (the
        MIMO loop-at-a-time rows) forms only the asked one."""
        return self(w)[rows, np.arange(np.size(w))]

    def _point(self, s: np.ndarray) -> _Point:
        """The per-frequency factors at ``s``."""
        sp = self.sampled
        if sp is None:
            d = self.delay.factor(s)
            return _Point(s, s, d, d)
        dt = sp.dt
        z = np.exp(s * dt)
        zi = 1.0 / z
        zd = np.exp(-s * (dt * sp.d)) if sp.d else 1.0  # z^-d
        zdD = np.exp(-s * (dt * sp.dD)) if sp.dD else 1.0  # z^-dD (feedthrough)
        return _Point(s, z, zd, zdD, zi, 1.0 - zi, dt)

    def _states(self, pt: _Point) -> np.ndarray:
        """The plant's state response in Schur coordinates (n, W), by back-substitution."""
        n = self._n
        T, zb, zb1, diag = self._T, self._zb, self._zb1, self._diag
        xs = np.empty((n, pt.s.size), dtype=complex)
        for i in range(n - 1, -1, -1):
            acc = zb[i] if zb1 is None or pt.zi is None else zb[i] + zb1[i] * pt.zi
            if i + 1 < n:
                acc = acc + _dot(T[i, i + 1 :], xs[i + 1 :])
            xs[i] = acc / (pt.x_at - diag[i])
        return xs

    def _outputs(self, pt: _Point, xs: np.ndarray) -> dict[int, _Val]:
        """The measured outputs per unit plant input, delays included."""
        n = self._n
        P: dict[int, _Val] = {}
        for j, (cz, dj) in self._outs.items():
            if self.sampled is None:
                P[j] = (_dot(cz, xs) + dj) * pt.d if n else dj * pt.d
            else:
                P[j] = (_dot(cz, xs) * pt.d + dj * pt.dD) if n else dj * pt.dD
        return P

    def _controllers(self, pt: _Point, xs: np.ndarray, P: dict[int, _Val]) -> list[tuple[_Val, _Val]]:
        """Per loop (F_k, m_k): setpoint path and feedback per unit u (as :meth:`Cascade.controller_responses`)."""
        s = pt.s
        # the integrator's response: backward Euler dt/(1 - z^-1) in the sampled loop, else 1/s
        inv_s: _Val = 0.0
        if any(c.has_i for c in self._ctl):
            inv_s = pt.dt / pt.one_m if pt.one_m is not None else 1.0 / s
        resp = []
        for c in self._ctl:
            integ: _Val
            if isinstance(c, _PidScalars):
                integ = c.ki * inv_s if c.has_i else 0.0
                Dd: _Val = 0.0
                if c.has_d and pt.one_m is not None and pt.zi is not None:
                    Dd = c.kd * pt.one_m / (c.tf + pt.dt - c.tf * pt.zi)
                elif c.has_d:  # the continuous loop
                    Dd = c.kd * s / (c.tf * s + 1.0)
                C = c.kp + integ + Dd
                F = c.b * c.kp + integ + c.c * Dd
                m = -C * P[c.out_idx]
            else:
                KX = (_dot(c.KZ, xs) * pt.d) if self._n else np.zeros(s.size, dtype=complex)
                integ = c.kint * inv_s if c.has_i else 0.0
                m = -(KX + integ * P[c.out_idx])
                F = c.nr + integ
            resp.append((F, m))
        return resp

    def _eval(self, s: np.ndarray) -> np.ndarray:
        """L at ``s`` (the fast path for one gain set)."""
        pt = self._point(s)
        xs = self._states(pt) if self._n else np.zeros((0, s.size), dtype=complex)
        return _break_loops(self._controllers(pt, xs, self._outputs(pt, xs)), s.size)


def _break_loops(resp: list[tuple[_Val, _Val]], size: int) -> np.ndarray:
    """The break-point loops (n_loops + 1, W) from the per-loop (F_k, m_k), as :meth:`Cascade.cascade`."""
    nl = len(resp)
    g = []
    prev: _Val = 0.0
    for k, (F, m) in enumerate(resp):
        prev = F * prev + m if k else m  # the outermost loop's F would multiply zero (see Cascade.cascade)
        g.append(prev)
    L = np.empty((nl + 1, size), dtype=complex)
    H: _Val = 1.0
    for k in range(nl - 1, -1, -1):
        L[k] = -g[k] * H
        F, m = resp[k]
        H = H * F / (1.0 - H * m)
    L[nl] = -g[nl - 1]
    return L


#: Convergence of the crossing refinement, in log w.
_ROOT_TOL = 1e-10


def zoom_roots(ev: Evaluator, lo: np.ndarray, hi: np.ndarray, rows: np.ndarray, fn, iters: int = 12,
               La: np.ndarray | None = None, Lb: np.ndarray | None = None):
    """Refine brackets [lo, hi] (per row) of a sign change of fn(L): vectorised modified regula
    falsi (Anderson-Bjorck) in log w, one evaluation of the unconverged brackets per iteration.

    ``La``/``Lb``: L at the bracket ends when known (grid values), else evaluated.
    ``fn`` maps (L values, bracket indices) to the function values. Returns (w, L at w).
    """
    if lo.size == 0:
        return lo, np.zeros(0, dtype=complex)
    a, b = np.log(lo), np.log(hi)
    k = np.arange(lo.size)
    if La is None or Lb is None:
        Lab = ev.rows_at(np.concatenate([lo, hi]), np.concatenate([rows, rows]))
        La, Lb = Lab[: lo.size], Lab[lo.size :]
    fa = fn(La, k)
    fb = fn(Lb, k)
    side = np.zeros(lo.size)
    c = 0.5 * (a + b)
    Lc = np.where(np.abs(fa) <= np.abs(fb), La, Lb)  # only used if no iteration runs
    act = np.arange(lo.size)
    for _ in range(iters):
        A, Bv, FA, FB = a[act], b[act], fa[act], fb[act]
        c_prev = c[act]
        with np.errstate(invalid="ignore", divide="ignore"):
            cc = np.where(FA != FB, (A * FB - Bv * FA) / (FB - FA), 0.5 * (A + Bv))
        bad = ~np.isfinite(cc) | (cc <= np.minimum(A, Bv)) | (cc >= np.maximum(A, Bv))
        cc = np.where(bad, 0.5 * (A + Bv), cc)
        Lcc = ev.rows_at(np.exp(cc), rows[act])
        fc = fn(Lcc, act)
        c[act] = cc
        Lc[act] = Lcc
        left = np.sign(fc) == np.sign(FA)  # root in [c, b]
        sd = side[act]
        # Anderson-Bjorck: when the same end is kept twice, scale its value by 1 - f(c)/f(replaced
        # end) (by 1/2, as Illinois, when that is not positive); converges faster than halving
        with np.errstate(invalid="ignore", divide="ignore"):
            mb = np.where(FA != 0, 1.0 - fc / FA, 0.5)
            ma = np.where(FB != 0, 1.0 - fc / FB, 0.5)
        FB = np.where(left & (sd == 1), FB * np.where(mb > 0, mb, 0.5), FB)
        FA = np.where(~left & (sd == -1), FA * np.where(ma > 0, ma, 0.5), FA)
        a[act], fa[act] = np.where(left, cc, A), np.where(left, fc, FA)
        b[act], fb[act] = np.where(left, Bv, cc), np.where(left, FB, fc)
        side[act] = np.where(left, 1, -1)
        # 1e-10 in log w: frequencies to 1e-10 relative; tighter only chases round-off
        # or a residual at round-off level (both functions are O(1): log|L| and sin(arg L))
        done = (np.abs(cc - c_prev) < _ROOT_TOL) | (np.abs(b[act] - a[act]) < _ROOT_TOL) | (np.abs(fc) < 1e-13)
        act = act[~done]
        if act.size == 0:
            break
    return np.exp(c), Lc
