"""The exact sampled-data MIMO loop at a sample time dt: what the MIMO simulator and the exports run.

* **Plant**: the plant's linear form ZOH-discretised at ``dt`` exactly as the MIMO simulator steps
  it (:func:`gaintune.sim.mimo.plant_channels`): per input channel ``x[k+1] = Ad x[k] +
  G0 u[k-d] + G1 u[k-d-1]`` with the channel's delay (plant entry or input delay plus the
  actuator's) ``d dt + f``, 0 <= f < dt, split exactly by the modified z-transform
  (:func:`gaintune.verification.sampled.zoh_delay`); ``y[k] = C x[k]`` (strictly proper).
  ``verify.compute_delay`` = c samples add ``z^-c`` at every driven input.
* **Controller**: every loop's discrete PID law (module docstring of
  :mod:`gaintune.controllers.pid`; :func:`gaintune.export.coefficients.discrete_pid_tf`, the export's),
  ``Kp + Ki dt z/(z-1) + Kd (z-1)/((Tf+dt) z - Tf)``: the continuous law with
  ``s = (1 - z^-1)/dt`` substituted. Sums and products (cascades, the decoupler) commute with
  that substitution, so the controller matrix of :func:`gaintune.verification.mimo_spec.spec_loop`
  (its wiring: cascades, pairing, decoupler) evaluated at ``s = (1 - z^-1)/dt`` is the discrete
  controller, and its state-space form maps by ``Ad = (I - dt A)^-1`` (:func:`euler_controller`).
* **Stability**: eigenvalues of the discrete closed-loop transition matrix (plant, input buffers
  for the whole-sample delays, controller), stable when every |z| < 1. Modes the loop channels
  do not see are left out of the closed loop (hidden plant modes with |z| > 1 fail it,
  marginal ones are noted), as in :mod:`.mimo_stability`.
* **Figures**: the loop gains at ``z = e^{j w dt}``, ``0 < w <= pi/dt`` (:class:`SampledLoop`,
  a :class:`~gaintune.verification.mimo_loop.MimoLoop` whose responses are the sampled ones), so
  the loop-at-a-time margins, the multiloop disk margins and the MIMO Ms and Mt are those of
  :mod:`.mimo_margins` on the discrete frequency grid. A plant of independent entries (a train of
  units) is evaluated from its nonzero first-order terms (:mod:`.mimo_sampled_terms`) and the loop
  gains from the nonzero entries: the same values, to rounding, at a fraction of the dense products.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gaintune.lti.arrays import int_power
from gaintune.lti.mimo import TfMatrix
from gaintune.verification.mimo_loop import MimoLoop, closed_loop_matrix, response, solve_points
from gaintune.verification.mimo_products import BLOCK_MIN, block_eigvals, divergence_rate
from gaintune.verification.mimo_sampled_terms import SampledTerms
from gaintune.verification.mimo_stability import MimoStability, hidden_notes, trim_hidden, trim_hidden_by_parts
from gaintune.verification.mimo_tf import _tf_values

__all__ = ["SampledCore", "SampledLoop", "sampled_core", "euler_controller", "sampled_stability_mimo"]

#: |z| above this counts as on or outside the unit circle (a marginal or unstable mode).
_UNIT = 1.0 - 1e-9


@dataclass
class SampledCore:
    """The sampled plant's channels from the driven inputs to the measured outputs.

    ``x[k+1] = Ad x[k] + sum_c (G0[:, c] u_src(c)[k - d(c)] + G1[:, c] u_src(c)[k - d(c) - 1])``,
    ``y = C x``; ``src`` indexes the loop's driven inputs (``MimoLoop.ins``), ``d`` whole samples
    (computation delay included), ``frac`` the fractional delay of each channel (s)."""

    Ad: np.ndarray
    C: np.ndarray
    G0: np.ndarray  # (N, channels)
    G1: np.ndarray
    src: np.ndarray
    d: np.ndarray
    dt: float
    hidden: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=complex))
    _modal: tuple | None = field(default=None, repr=False)
    _terms: SampledTerms | None = field(default=None, repr=False)

    def _inputs(self, z: np.ndarray, G0: np.ndarray, G1: np.ndarray, n_in: int) -> np.ndarray:
        """sum_c (G0[:, c] + G1[:, c] z^-1) z^-d(c) per driven input: (len(z), rows of G0, n_in)."""
        one_hot = np.zeros((self.src.size, n_in))
        one_hot[np.arange(self.src.size), self.src] = 1.0
        f = int_power((1.0 / z)[:, None], self.d[None, :])  # (W, channels)
        out = (G0[None] * f[:, None, :]) @ one_hot
        if np.any(G1):
            out = out + (G1[None] * (f / z[:, None])[:, None, :]) @ one_hot
        return out

    def _modal_form(self) -> tuple:
        """(lambda, C V, V^-1 G0, V^-1 G1) of Ad = V diag(lambda) V^-1, or () when V is ill conditioned."""
        if self._modal is None:
            lam, V = np.linalg.eig(self.Ad)
            if np.linalg.cond(V) < 1e8:
                Vi = np.linalg.inv(V)
                self._modal = (lam, self.C @ V, Vi @ self.G0, Vi @ self.G1)
            else:
                self._modal = ()
        return self._modal

    def terms(self, n_in: int) -> SampledTerms:
        """The plant's channels as first-order terms (:class:`SampledTerms`), built once per core."""
        if self._terms is None or self._terms.n_in != n_in:
            self._terms = SampledTerms.of(self, n_in)
        return self._terms

    def sparse(self, n_in: int) -> bool:
        """Whether :meth:`terms` cost less than the dense modal product (a plant of independent entries,
        a train of units): the terms (and solved blocks) against ``p N n_in`` products per point."""
        t = self.terms(n_in)
        work = 4 * t.mode.size + sum(4 * b.A.shape[0] ** 2 * b.G0.shape[1] for b in t.solved)
        return work < self.C.shape[0] * self.Ad.shape[0] * n_in

    def entries(self, z: np.ndarray, n_in: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, columns, values (len(z), entries)) of Gs(z): the entries the plant's structure lets be
        nonzero (:class:`SampledTerms`) when that is cheaper, else every entry."""
        z = np.asarray(z, dtype=complex).ravel()
        if self.sparse(n_in):
            t = self.terms(n_in)
            return t.rows, t.cols, t.values(z)
        rows, cols = np.divmod(np.arange(self.C.shape[0] * n_in), n_in)
        return rows, cols, self.response_dense(z, n_in).reshape(z.size, -1)

    def response(self, z: np.ndarray, n_in: int) -> np.ndarray:
        """Gs(z) = C (zI - Ad)^-1 B(z): (len(z), p, n_in), by :meth:`entries` (zero elsewhere) or dense."""
        z = np.asarray(z, dtype=complex).ravel()
        if not self.sparse(n_in):
            return self.response_dense(z, n_in)
        out = np.zeros((z.size, self.C.shape[0], n_in), dtype=complex)
        rows, cols, v = self.entries(z, n_in)
        out[:, rows, cols] = v
        return out

    def response_dense(self, z: np.ndarray, n_in: int) -> np.ndarray:
        """Gs(z) from the whole Ad at once (the reference :meth:`response` is pinned to): modal when Ad's
        eigenvectors are well conditioned, else a solve per point."""
        z = np.asarray(z, dtype=complex).ravel()
        N = self.Ad.shape[0]
        if N == 0:
            return np.zeros((z.size, self.C.shape[0], n_in), dtype=complex)
        modal = self._modal_form()
        with np.errstate(all="ignore"):
            if modal:
                lam, CV, G0m, G1m = modal
                X = self._inputs(z, G0m, G1m, n_in) / (z[:, None] - lam[None, :])[:, :, None]
                return CV[None] @ X
            Bz = self._inputs(z, self.G0, self.G1, n_in)
            return self.C[None] @ solve_points(z[:, None, None] * np.eye(N) - self.Ad[None], Bz)

    def realisation(self, n_in: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(A, B, C, D) of the sampled plant channels with the delayed inputs as buffer states
        (``b_i = u[k - i]`` per driven input, i = 1 .. its longest delay)."""
        N = self.Ad.shape[0]
        need = [int(max([dc + (1 if np.any(self.G1[:, c]) else 0)
                         for c, dc in enumerate(self.d) if self.src[c] == j], default=0)) for j in range(n_in)]
        start = np.concatenate([[N], N + np.cumsum(need)]).astype(int)
        n = int(start[-1])
        A, B = np.zeros((n, n)), np.zeros((n, n_in))
        A[:N, :N] = self.Ad

        def feed(col: np.ndarray, j: int, lag: int) -> None:  # col u_j[k - lag] into x[k+1]
            if lag == 0:
                B[:N, j] += col
            else:
                A[:N, start[j] + lag - 1] += col

        for c, (j, dc) in enumerate(zip(self.src, self.d, strict=True)):
            feed(self.G0[:, c], int(j), int(dc))
            if np.any(self.G1[:, c]):
                feed(self.G1[:, c], int(j), int(dc) + 1)
        for j in range(n_in):
            if need[j]:
                B[start[j], j] = 1.0
                for i in range(1, need[j]):
                    A[start[j] + i, start[j] + i - 1] = 1.0
        C = np.hstack([self.C, np.zeros((self.C.shape[0], n - N))])
        return A, B, C, np.zeros((self.C.shape[0], n_in))


def sampled_core(lti, ins: list[int], outs: list[int], dt: float, act_delay: np.ndarray,
                 compute_delay: int = 0) -> SampledCore:
    """The sampled plant of ``lti`` (a :mod:`gaintune.lti.mimo` form) from the driven inputs ``ins`` to
    the measured outputs ``outs``, as the MIMO simulator steps it (:func:`gaintune.sim.mimo.plant_channels`).

    Modes those channels cannot move are removed (:func:`~.mimo_stability.trim_hidden`, |z| >= 1 only);
    ``hidden`` lists the marginal or unstable ones removed."""
    from gaintune.sim.mimo import plant_channels

    ch = plant_channels(lti, dt, act_delay)
    pos = {j: k for k, j in enumerate(ins)}
    keep = np.array([int(j) in pos for j in ch["ch_src"]], dtype=bool)
    src = np.array([pos[int(j)] for j in ch["ch_src"][keep]], dtype=int)
    G0, G1 = ch["G0u"][keep].T, ch["G1u"][keep].T
    C = ch["Cm"][outs]
    Ad, Bt, Ct, hidden = trim_hidden(ch["Ad"], np.hstack([G0, G1]), C, discrete=True)
    k = G0.shape[1]
    return SampledCore(Ad, Ct, Bt[:, :k], Bt[:, k:], src, ch["ch_du"][keep].astype(int) + int(compute_delay),
                       float(dt), hidden)


def euler_controller(Ak: np.ndarray, Bk: np.ndarray, Ck: np.ndarray, Dk: np.ndarray,
                     dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The discrete controller ``K((1 - z^-1)/dt)`` of the continuous realisation (Ak, Bk, Ck, Dk):
    with ``M = (I - dt Ak)^-1``, ``(M, M Bk, dt Ck M, Dk + dt Ck M Bk)``."""
    if Ak.size == 0:
        return Ak, Bk, Ck, Dk
    M = np.linalg.inv(np.eye(Ak.shape[0]) - dt * Ak)
    return M, M @ Bk, dt * Ck @ M, Dk + dt * Ck @ M @ Bk


@dataclass
class SampledLoop(MimoLoop):
    """A :class:`~gaintune.verification.mimo_loop.MimoLoop` whose loop gains are the sampled loop's:
    ``s`` maps to ``z = e^{s dt}``, the plant channels to :meth:`SampledCore.response`, the
    controller to its discrete law (``s = (1 - z^-1)/dt``). Frequencies up to pi/dt only."""

    core: SampledCore | None = None
    dt: float = 0.0
    delay_s: float = 0.0  # the longest channel delay (s), samples included: the phase spin of the margins

    @classmethod
    def of(cls, base: MimoLoop, core: SampledCore) -> SampledLoop:
        """The sampled form of the continuous loop ``base`` (same controller, pairing and names)."""
        loop = cls(base.plant, base.controller, base.names, base.loop_outs, base.loop_ins, base.outs, base.ins,
                   core=core, dt=core.dt)
        loop.delay_s = float(np.max(core.d, initial=0) + 1) * core.dt
        return loop

    def channels(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Gs, Ks) of the sampled loop at z = e^{s dt}."""
        assert self.core is not None
        s = np.asarray(s, dtype=complex).ravel()
        z = np.exp(s * self.dt)
        with np.errstate(all="ignore"):
            s_be = (1.0 - 1.0 / z) / self.dt
        return self.core.response(z, self.n_in), response(self.controller, s_be, self.ins, self.outs)

    def _entries(self, s: np.ndarray) -> tuple[np.ndarray, ...]:
        """(controller rows, columns, values; plant rows, columns, values) of the nonzero entries at z = e^{s dt}."""
        assert self.core is not None and isinstance(self.controller, TfMatrix)
        z = np.exp(s * self.dt)
        with np.errstate(all="ignore"):
            s_be = (1.0 - 1.0 / z) / self.dt
        return (*_tf_values(self.controller, s_be, tuple(self.ins), tuple(self.outs)), *self.core.entries(z, self.n_in))

    def _sparse(self) -> bool:
        """Whether the loop gains are taken from the nonzero entries (a transfer-matrix controller and a
        plant of few nonzero entries, :meth:`SampledCore.sparse`)."""
        assert self.core is not None
        return isinstance(self.controller, TfMatrix) and self.core.sparse(self.n_in)

    def loop_gains(self, s: np.ndarray, side: str) -> np.ndarray:
        """L at z = e^{s dt}: ``Ks Gs`` (side "input") or ``Gs Ks`` ("output"); from the nonzero entries alone
        (:meth:`~.mimo_loop.MimoLoop._sparse_loop_gains`) when :meth:`_sparse`."""
        if self._sparse():
            s = np.asarray(s, dtype=complex).ravel()
            return self._sparse_loop_gains(s, side, self._entries(s))
        Gs, Ks = self.channels(s)
        with np.errstate(all="ignore"):
            return Ks @ Gs if side == "input" else Gs @ Ks

    def outputs_by_inputs(self) -> bool:
        """Output-side rows from the smaller input side (:meth:`input_side`, the sampled entries): fewer
        inputs than outputs (a cascade) and :meth:`_sparse`."""
        return self.n_in < self.n_out and self._sparse()

    def input_side(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(L_i = Ks Gs, Gs, Ks) of the sampled loop at ``s`` from one evaluation of the entries."""
        s = np.asarray(s, dtype=complex).ravel()
        if not self.outputs_by_inputs():
            Gs, Ks = self.channels(s)
            return self.loop_gains(s, "input"), Gs, Ks
        entries = self._entries(s)
        return self._sparse_loop_gains(s, "input", entries), *self._dense_channels(s, entries)

    def input_side_rows(self, s: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`~.mimo_loop.MimoLoop.input_side_rows` of the sampled loop."""
        s = np.asarray(s, dtype=complex).ravel()
        if not self.outputs_by_inputs():
            return self._rows_of_dense(s, k)
        entries = self._entries(s)
        return self._sparse_loop_gains(s, "input", entries), *self._channel_rows(k, entries)

    def max_delay(self) -> float:
        """The longest delay of the sampled channels (s), whole samples and the hold's sample included."""
        return self.delay_s


def sampled_stability_mimo(loop: SampledLoop, base: MimoLoop, screen: bool = False) -> MimoStability:
    """Closed-loop stability of the sampled loop from the eigenvalues of its transition matrix: the
    plant channels with their input buffers, and the controller of ``base`` (its continuous
    realisation, modes it cannot show trimmed, mapped by :func:`euler_controller`).

    ``screen`` (a search's check only, never a verdict): a loop that
    :func:`~gaintune.verification.mimo_products.divergence_rate` finds diverging is reported unstable
    without its eigenvalues (method ``growth``, one unstable pole counted, the growth rate as the
    spectral radius). A random search's candidates are mostly such loops, and on the 110-gain train the
    eigenvalues were 86 % of CMA-ES's time."""
    assert loop.core is not None
    notes: list[str] = []
    plant = loop.core.realisation(loop.n_in)
    Ak, Bk, Ck, Dk = base.realisations(0)[1]
    Ak, Bk, Ck = trim_hidden_by_parts(Ak, Bk, Ck)  # many chains: a chain at a time (trim_hidden's cost)
    ctrl = euler_controller(Ak, Bk, Ck, Dk, loop.dt)
    A = closed_loop_matrix(plant, ctrl)
    rate = divergence_rate(A) if screen and A.shape[0] >= BLOCK_MIN and np.all(np.isfinite(A)) else None
    if rate is not None:
        return MimoStability(False, "growth", 1, None, True, np.zeros(0, dtype=complex), 0, math.log(rate) / loop.dt,
                             loop.core.hidden, [f"the closed loop grows {rate:.4g}-fold a sample: unstable "
                                                "(screened, poles not computed)"])
    with np.errstate(all="ignore"):
        poles = block_eigvals(A) if A.size and np.all(np.isfinite(A)) else np.zeros(0, dtype=complex)
    hid = loop.core.hidden
    # a hidden chain on the unit circle comes out spread by rounding, as in the continuous count
    bad, marginal = hid[np.abs(hid) > 1.0 + 1e-6], hid[np.abs(hid) <= 1.0 + 1e-6]
    hidden_notes(bad, marginal, notes, "sampled ")
    n_rhp = int(np.sum(np.abs(poles) >= _UNIT)) + int(bad.size)
    rho = float(np.max(np.abs(poles))) if poles.size else 0.0
    max_re = math.log(rho) / loop.dt if rho > 0 else -math.inf
    poles = poles[np.argsort(-np.abs(poles), kind="stable")]
    return MimoStability(n_rhp == 0, "poles", n_rhp, None, True, poles, 0, max_re, hid, notes)
