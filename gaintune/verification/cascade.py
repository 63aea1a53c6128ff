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
* loop broken at the plant input (every loop passes through u): ``L_u = -g_{n-1}``;
* noise at loop ``i``'s measurement to the plant input ``u`` (others closed):
  ``N_i = -C_i H_{i+1} / (1 + L_i)``; its peak is the noise sensitivity Mks (SISO: ``|C S|``).

The same structure gives the delay-free (or Padé) closed-loop state matrix whose
eigenvalues are the closed-loop poles, and the open-loop poles of the system cut
at the plant input (needed by the argument-principle stability test).

The algebra works on any response arrays: ``loop_responses(..., sampled=sp)`` feeds
it the sampled plant and the controllers' discrete laws at z = e^{s dt}
(:mod:`gaintune.verification.sampled`), and :meth:`Cascade.closed_loop_sampled` is the
sampled closed loop's transition matrix (plant, input buffer, controller states).

:func:`build_cascade` turns a spec's loops and a batch of gain vectors into a
:class:`Cascade`. The plant's responses and Padé delays come from :mod:`gaintune.lti`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.controllers.pid import pid_params
from gaintune.errors import GainError, SpecError
from gaintune.lti.modes import plant_eigvals, plant_state_response
from gaintune.lti.pade import pade_poles
from gaintune.plants.plant import LinearModel
from gaintune.spec import LoopSpec, TuningSpec
from gaintune.verification.laws import (
    LoopCtl,
    Signal,
    Signals,
    controller_state_index,
    lq_law,
    lq_law_sampled,
    pade_blocks,
    pid_law,
    pid_law_sampled,
    resolve,
    solve_u,
)
from gaintune.verification.sampled import SampledPlant, discrete_ops

__all__ = ["LoopCtl", "Cascade", "build_cascade", "controller_state_index", "pid_arrays"]

#: One loop's responses (F_k, m_k, C_k), each (B, W): setpoint path, feedback per unit u, feedback controller.
Resp = tuple[np.ndarray, np.ndarray, np.ndarray]



#: The sampled plant's side of recent responses at a shared frequency array: see :func:`_sampled_plant_side`.
_SAMPLED_SIDE: dict[tuple[int, int], tuple] = {}


def _sampled_plant_side(s: np.ndarray, sp: SampledPlant) -> tuple:
    """(X = u->x (W, n), P = u->y (W, q), integral operator, derivative operator) of ``sp`` at z = e^{s dt}.

    Gain-independent: remembered when ``s`` is read-only, as the requirement estimate's grid is (one
    array per plant, :func:`gaintune.verification.quick.quick_margins`; a boundary move estimates a plant
    ~5 times per answer). The remembered arrays are read-only too.
    """
    shared = not s.flags.writeable
    key = (id(s), id(sp))
    hit = _SAMPLED_SIDE.get(key) if shared else None
    if hit is not None and hit[0] is s and hit[1] is sp:
        return hit[2]
    with np.errstate(all="ignore"):
        z = np.exp(s * sp.dt)
        X, P = sp.responses(z)
        _, integ, deriv = discrete_ops(z, sp.dt)
    out = (X, P, integ, deriv)
    if shared:
        for a in (X, P, integ):
            a.setflags(write=False)
        if len(_SAMPLED_SIDE) > 512:
            _SAMPLED_SIDE.clear()
        _SAMPLED_SIDE[key] = (s, sp, out)
    return out

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
    def controller_responses(self, s: np.ndarray, lin: LinearModel, X: np.ndarray, P: np.ndarray,
                             ops: tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]] | None = None
                             ) -> list[Resp]:
        """Per loop (F_k, m_k, C_k), each (B, W), given X = u->x (W, n) and P = u->y (W, q) incl. delay.

        ``C_k`` is the feedback controller (measurement -> loop output); NaN for an LQ loop,
        whose feedback is the whole state (no single measurement to put noise on).

        ``ops``: (integral operator, derivative operator Tf -> array) at the frequencies; default
        the continuous 1/s and s/(Tf s + 1); :func:`gaintune.verification.sampled.discrete_ops` for the
        simulator's discrete laws.
        """
        out = []
        inv_s, deriv = ops if ops is not None else (1.0 / s, _continuous_deriv(s))
        for lp in self.loops:
            C: np.ndarray | float  # NaN for an LQ loop
            if lp.kind == "pid":
                Kp, Ki, Kd, Tf = (a[:, None] for a in (lp.Kp, lp.Ki, lp.Kd, lp.Tf))
                C, F = Kp, lp.b * Kp  # absent terms are skipped, not added as zeros: each is a (B, W) op
                if lp.has_i:
                    integ = Ki * inv_s
                    C, F = C + integ, F + integ
                if lp.has_d:
                    Dd = Kd * deriv(Tf)
                    C, F = C + Dd, F + lp.c * Dd
                m = C * -P[None, :, lp.out_idx]  # = -C * P, negating the (W,) factor
            else:
                KX = lp.K @ X.T  # (B, W)
                integ_lq: np.ndarray | float = lp.Kint[:, None] * inv_s if lp.has_i else 0.0
                m = -(KX + integ_lq * P[None, :, lp.out_idx])
                F = lp.Nr[:, None] + integ_lq
                C = np.nan
            shape = (self.batch, s.size)
            out.append((np.broadcast_to(F, shape), m, np.broadcast_to(C, shape)))
        return out

    def _responses(self, s: np.ndarray, lin: LinearModel, delay: np.ndarray | complex,
                   sampled: SampledPlant | None) -> list[Resp]:
        """Per loop (F_k, m_k, C_k) at ``s``: the continuous loop with the delay factor, or the sampled one."""
        if sampled is not None:
            X, P, integ, deriv = _sampled_plant_side(s, sampled)
            return self.controller_responses(s, lin, X, P, (integ, deriv))
        X = plant_state_response(lin, s) * np.asarray(delay)[:, None]  # (W, n)
        P = X @ lin.C.T + (lin.D[:, 0][None, :] * np.asarray(delay)[:, None])  # (W, q)
        return self.controller_responses(s, lin, X, P)

    def loop_responses(self, s: np.ndarray, lin: LinearModel, delay: np.ndarray | complex = 1.0,
                       sampled: SampledPlant | None = None) -> np.ndarray:
        """Open-loop responses at complex frequencies ``s``: (n_loops + 1, B, W).

        ``delay`` is the delay factor at ``s`` (e^{-sT} or its Padé approximant), shape (W,).
        ``sampled``: evaluate the sampled loop instead (plant as the simulator steps it, the
        controllers' discrete laws) at z = e^{s dt}; ``delay`` is then unused (the sampled
        plant holds its delays). Rows: each loop broken at its controller output, then the plant input.
        """
        s = np.asarray(s)
        return self.cascade(self._responses(s, lin, delay, sampled), s.size)

    def noise_responses(self, s: np.ndarray, lin: LinearModel, delay: np.ndarray | complex = 1.0,
                        sampled: SampledPlant | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(L, N)``: the open-loop responses of :meth:`loop_responses` and the noise responses
        ``N`` (n_loops, B, W): measurement noise of each loop to the plant input ``u`` (see the
        module docstring)."""
        s = np.asarray(s)
        resp = self._responses(s, lin, delay, sampled)
        L, H = self._chain(resp, s.size)
        with np.errstate(all="ignore"):
            N = np.stack([-resp[i][2] * H[i] / (1.0 + L[i]) for i in range(len(self.loops))])
        return L, N

    def cascade(self, resp: list[Resp], W: int) -> np.ndarray:
        """The break-point loops (n_loops + 1, B, W) from the per-loop (F_k, m_k, C_k)."""
        return self._chain(resp, W)[0]

    def _chain(self, resp: list[Resp], W: int) -> tuple[np.ndarray, list[np.ndarray]]:
        """``(L, H)``: the break-point loops, and ``H[k - 1]`` = H_k (r_k -> u, loops k..n-1 closed;
        H_n = 1) for k = 1..n (H_0, all loops closed, is no break point's: not computed)."""
        n = len(self.loops)
        # nothing is outside the outermost loop: its setpoint path F would multiply zero
        # (skipped: an F that overflowed, e.g. a huge setpoint weight, made inf * 0 = NaN)
        prev = resp[0][1]
        g = [prev]
        for F, m, _ in resp[1:]:
            prev = F * prev  # then in place: saves a (B, W) temporary
            prev += m
            g.append(prev)
        H = [np.ones((self.batch, W), dtype=complex)]  # built inner first: H_n, H_{n-1}, ..., H_1
        with np.errstate(divide="ignore", invalid="ignore"):
            for k in range(n - 1, 0, -1):
                F, m, _ = resp[k]
                H.append(H[-1] * F / (1.0 - H[-1] * m))
            H.reverse()
            L = np.empty((n + 1, self.batch, W), dtype=complex)
            for i in range(n):
                np.negative(g[i], out=L[i])
                L[i] *= H[i]
        np.negative(g[n - 1], out=L[n])
        return L, H

    # -------------------------------------------------------- state space
    def open_loop_poles(self, lin: LinearModel, pade: tuple[float, int] | None) -> np.ndarray:
        """Poles of the system cut at the plant input (same for every batch member): plant,
        Padé, controller integrators (0) and derivative filters (-1/Tf, per batch)."""
        base = list(plant_eigvals(lin))
        if pade is not None:
            base += list(pade_poles(*pade))
        poles = np.tile(np.array(base, dtype=complex), (self.batch, 1))
        extra: list[np.ndarray] = []
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
        Ad, Bd, Cd, Dd = pade_blocks(pade)
        npd = Ad.shape[0]
        ctl_idx, N = controller_state_index(self.loops, n + npd)
        sig = Signals(Bsz, N)
        # Delayed plant input u_p = Cd x_pade + Dd u
        up_x = np.zeros((Bsz, N))
        up_x[:, n : n + npd] = Cd[0]
        up = (up_x, np.full(Bsz, Dd))

        def output(j: int) -> Signal:
            rx = np.zeros((Bsz, N))
            rx[:, :n] = lin.C[j]
            d = lin.D[j, 0]
            return rx + d * up[0], d * up[1]

        derivs: dict[int, Signal] = {}
        r = sig.zero()
        for lp, (ii, di) in zip(self.loops, ctl_idx, strict=True):
            y = output(lp.out_idx)
            if lp.kind == "pid":
                r = pid_law(sig, lp, r, y, ii, di, derivs)
            else:
                r = lq_law(sig, lp, r, y, ii, n, derivs)
        u_row = solve_u(r)  # u = u_row @ X
        Acl = np.zeros((Bsz, N, N))
        upr = resolve(up, u_row)
        Acl[:, :n, :n] += lin.A
        Acl[:, :n, :] += lin.B[:, 0][None, :, None] * upr[:, None, :]
        if npd:
            Acl[:, n : n + npd, n : n + npd] += Ad
            Acl[:, n : n + npd, :] += Bd[:, 0][None, :, None] * u_row[:, None, :]
        for j, sg in derivs.items():
            Acl[:, j, :] = resolve(sg, u_row)
        return Acl

    # ------------------------------------------------------- sampled loop
    def open_loop_poles_sampled(self, sp: SampledPlant) -> np.ndarray:
        """z-plane poles of the sampled system cut at the plant input (B, P): plant (Ad), the
        input buffer (z = 0), integrators (z = 1) and derivative filters (z = Tf/(Tf + dt))."""
        base = list(sp.eigvals()) + [0.0] * sp.buffer_len
        poles = np.tile(np.array(base, dtype=complex), (self.batch, 1))
        extra: list[np.ndarray] = []
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
        states. Signals are rows over the states plus a coefficient of u[k], solved for at the
        end as in :meth:`closed_loop_A` (the sampled plant gives none: its feedthrough sees
        u[k-1-d], the input held before the update).
        """
        Bsz = self.batch
        n, m = sp.n, sp.buffer_len
        ctl_idx, N = controller_state_index(self.loops, n + m)
        sig = Signals(Bsz, N)

        def past(j: int) -> Signal:  # u[k-j]
            return (np.zeros((Bsz, N)), np.ones(Bsz)) if j == 0 else sig.unit(n + j - 1)

        def output(j: int) -> Signal:
            rx = np.zeros((Bsz, N))
            rx[:, :n] = sp.C[j]
            if sp.D[j] != 0.0:
                return sig.comb((1.0, (rx, np.zeros(Bsz))), (sp.D[j], past(sp.dD)))
            return rx, np.zeros(Bsz)

        nxt: dict[int, Signal] = {}
        r = sig.zero()
        for lp, (ii, di) in zip(self.loops, ctl_idx, strict=True):
            y = output(lp.out_idx)
            if lp.kind == "pid":
                r = pid_law_sampled(sig, lp, r, y, ii, di, sp.dt, nxt)
            else:
                r = lq_law_sampled(sig, lp, r, y, ii, n, sp.dt, nxt)
        u_row = solve_u(r)  # u[k] = u_row @ state
        Acl = np.zeros((Bsz, N, N))
        Acl[:, :n, :n] += sp.Ad
        Acl[:, :n, :] += sp.G0[None, :, None] * resolve(past(sp.d), u_row)[:, None, :]
        if sp.has_G1:
            Acl[:, :n, :] += sp.G1[None, :, None] * resolve(past(sp.d + 1), u_row)[:, None, :]
        if m:
            Acl[:, n, :] = u_row
            for j in range(1, m):
                Acl[:, n + j, n + j - 1] = 1.0
        for j, sg in nxt.items():
            Acl[:, j, :] = resolve(sg, u_row)
        return Acl


def _continuous_deriv(s: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """The filtered derivative s/(Tf s + 1) at ``s``, as a function of Tf."""

    def deriv(tf: np.ndarray) -> np.ndarray:
        return s / (tf * s + 1.0)

    return deriv


def _out_index(spec: TuningSpec, lin: LinearModel, i: int) -> int:
    loop = spec.loops[i]
    name = loop.measure or lin.outputs[0]
    if name not in lin.outputs:
        raise SpecError(f"loops[{i}].measure", f"unknown output {name!r}; plant outputs are {lin.outputs}")
    return lin.outputs.index(name)


def pid_arrays(loop: LoopSpec, G: np.ndarray, names: list[str]) -> dict[str, np.ndarray]:
    """:func:`gaintune.controllers.pid.pid_params` over a batch (G: (B, n_loop_gains)), as a dict."""
    p = pid_params(loop, {nm: G[:, j] for j, nm in enumerate(names)})
    return {"Kp": p.Kp, "Ki": p.Ki, "Kd": p.Kd, "Tf": p.Tf}


def _lq_ctl(loop: LoopSpec, name: str, out_idx: int, G: np.ndarray, names: list[str], lin: LinearModel) -> LoopCtl:
    """An LQ loop's controller: its gains computed per gain set (:func:`gaintune.controllers.lq.lq_gains`)."""
    from gaintune.controllers.lq import lq_gains

    Bsz = G.shape[0]
    Ks, Kis, Nrs = [], [], []
    for b in range(Bsz):
        lg = lq_gains(loop, dict(zip(names, G[b], strict=True)), lin, out_idx)
        Ks.append(lg.K)
        Kis.append(lg.Kint)
        Nrs.append(lg.Nr)
    return LoopCtl(name, "lq", out_idx, has_i=loop.type == "lqi", K=np.array(Ks, dtype=float).reshape(Bsz, -1),
                   Kint=np.array(Kis, dtype=float), Nr=np.array(Nrs, dtype=float))


def _pid_ctl(loop: LoopSpec, name: str, out_idx: int, G: np.ndarray, names: list[str]) -> LoopCtl:
    """A PID loop's controller. Raises GainError for a derivative without a filter time constant."""
    pa = pid_arrays(loop, G, names)
    has_d = "d" in loop.type[1:]
    if has_d and np.any((pa["Tf"] <= 0) & (pa["Kd"] != 0)):  # Kd = 0: no derivative, no filter needed
        raise GainError(f"gains.{name}", "derivative filter time constant is zero; give Kp > 0")
    # Ki = 0 turns integral action off: no integrator state, whose pole at s = 0 would count as unstable
    has_i = "i" in loop.type[1:] and bool(np.any(pa["Ki"] != 0))
    return LoopCtl(name, "pid", out_idx, has_i=has_i, has_d=has_d, Kp=pa["Kp"], Ki=pa["Ki"], Kd=pa["Kd"], Tf=pa["Tf"],
                   b=loop.b, c=loop.c)


def build_cascade(
    spec: TuningSpec, layout: GainLayout, full: np.ndarray, lin: LinearModel, lq_cache: dict | None = None
) -> Cascade:
    """Controllers for a batch of full gain vectors ``full`` (B, n_gains) on the linear model ``lin``.

    LQ gains in ``weights`` mode are computed once per gain set with :func:`control.lqr` on
    ``lin`` (pass the nominal model: gains are frozen for robustness analysis). ``lq_cache`` is not used.
    """
    full = np.atleast_2d(np.asarray(full, dtype=float))
    loops: list[LoopCtl] = []
    for i, loop in enumerate(spec.loops):
        cols = [k for k, sl in enumerate(layout.slots) if sl.loop == i]
        names = [layout.slots[k].name for k in cols]
        G = full[:, cols]
        out_idx = _out_index(spec, lin, i)
        name = loop.name or f"loop{i}"
        ctl = _lq_ctl(loop, name, out_idx, G, names, lin) if loop.is_lq else _pid_ctl(loop, name, out_idx, G, names)
        loops.append(ctl)
    return Cascade(loops, full.shape[0], [lp.name for lp in loops])
