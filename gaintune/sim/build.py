"""Assemble kernel arrays from a spec, a batch of full gain vectors and episode draws."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from gaintune.controllers.direction import measured_indices
from gaintune.controllers.layout import GainLayout
from gaintune.controllers.lq import lq_gains
from gaintune.controllers.pid import pid_params
from gaintune.errors import GainError, SpecError
from gaintune.plants.plant import LinearModel, Plant
from gaintune.sim.draws import REF_KINDS, Draws
from gaintune.sim.tape import Tape, make_tape
from gaintune.spec import ProfileSpec, ScenarioSpec, TuningSpec, check_delay_samples

__all__ = ["SimSetup", "discretize", "profile_pieces"]

AW_CODES = {"none": 0, "clamping": 1, "back_calculation": 2}


def discretize(A: np.ndarray, B: np.ndarray, dt: float, delay: np.ndarray):
    """Exact ZOH discretisation with a fractional input delay, batched over the leading axis.

    With delay = d*dt + frac (0 <= frac < dt), the input held over one sample is
    u[k-d-1] for the first ``frac`` seconds and u[k-d] for the rest, so
    ``x[k+1] = Ad x[k] + G0 u[k-d] + G1 u[k-d-1]`` exactly.

    Parameters
    ----------
    A, B : (N, n, n), (N, n, 1)
    delay : (N,) seconds

    Returns
    -------
    Ad (N, n, n), G0 (N, n), G1 (N, n), d (N,) int
    """
    import scipy.linalg  # deferred: ~0.1 s to import, and only discretisation needs it

    N, n, _ = A.shape
    d = np.floor(delay / dt + 1e-9).astype(np.int64)
    frac = np.clip(delay - d * dt, 0.0, dt)
    frac[frac < 1e-12 * dt] = 0.0

    def phi_gamma(h: np.ndarray):
        M = np.zeros((N, n + 1, n + 1))
        M[:, :n, :n] = A * h[:, None, None]
        M[:, :n, n:] = B * h[:, None, None]
        E = scipy.linalg.expm(M)
        return E[:, :n, :n], E[:, :n, n]

    Ad, _ = phi_gamma(np.full(N, dt))
    phi_a, gam_a = phi_gamma(dt - frac)
    _, gam_b = phi_gamma(frac)
    G0 = gam_a
    G1 = np.einsum("nij,nj->ni", phi_a, gam_b)
    return Ad, G0, G1, d


def profile_pieces(
    p: ProfileSpec, dt: float, n_steps: int, kind: str | None = None
) -> list[tuple[int, int, float, float]]:
    """Additive pieces (k_start, k_end, offset, slope) of a profile, at unit scale for step/ramp/impulse."""
    kind = kind or p.kind
    k0 = int(round(p.time / dt))
    if kind == "none":
        return []
    if kind == "step":
        return [(k0, n_steps + 1, p.amplitude, 0.0)]
    if kind == "ramp":
        return [(k0, n_steps + 1, 0.0, p.slope)]
    if kind == "impulse":
        width = max(int(round((p.width or dt) / dt)), 1)
        return [(k0, k0 + width, p.amplitude / (width * dt), 0.0)]
    pieces = []
    prev = 0.0
    for t, v in p.points:
        pieces.append((int(round(t / dt)), n_steps + 1, v - prev, 0.0))
        prev = v
    return pieces


def _dt(sc: ScenarioSpec) -> float:
    """The scenario's sample time: the simulator is only given resolved scenarios (dt derived from the plant
    where the spec left it out, :func:`gaintune.classical.timescale.resolve_scenarios`)."""
    if sc.dt is None:
        raise ValueError(f"scenario {sc.name!r} has no dt yet: resolve the spec's scenarios first")
    return sc.dt


@dataclass
class SimSetup:
    """Everything about a spec that does not depend on the gains: built once, reused per batch."""

    spec: TuningSpec
    plant: Plant
    layout: GainLayout
    meas: list[int]
    f_tape: Tape | None
    h_tape: Tape | None
    #: Per loop: (column in the full gain vector, gain name) of its gains.
    loop_columns: list[list[tuple[int, str]]]

    @classmethod
    def build(cls, spec: TuningSpec, plant: Plant, layout: GainLayout) -> SimSetup:
        meas = measured_indices(spec, plant.outputs)
        f_tape = h_tape = None
        if plant.kind == "nonlinear":
            if plant.f is None or plant.h is None:  # a nonlinear plant always has both (plants.plant)
                raise ValueError("a nonlinear plant without its casadi functions f and h")
            f_tape, h_tape = make_tape(plant.f), make_tape(plant.h)
        if spec.safety.action == "fallback" and any(loop.is_lq for loop in spec.loops):
            # the kernel switches PID gains only: an LQ loop would silently keep its tuned K after a trip
            raise SpecError("safety.action", "'fallback' is not supported with LQR/LQI loops; use 'hold'")
        for name in spec.safety.state_bounds:
            if name not in plant.states:
                raise SpecError(f"safety.state_bounds.{name}", f"unknown state; the plant has {plant.states}")
        columns: list[list[tuple[int, str]]] = [[] for _ in spec.loops]
        for k, slot in enumerate(layout.slots):
            columns[slot.loop].append((k, slot.name))
        return cls(spec, plant, layout, meas, f_tape, h_tape, columns)

    # ------------------------------------------------------------- plant
    def _linear_models(self, draws: Draws) -> tuple[list[LinearModel], np.ndarray]:
        """Linear models for the distinct parameter rows, and each row's index into them."""
        rows, inverse = np.unique(draws.params, axis=0, return_inverse=True)
        names = self.plant.param_names
        lins = [self.plant.linearize(dict(zip(names, row, strict=True))) for row in rows]
        return lins, inverse.ravel()

    def plant_arrays(self, draws: Draws, sc: ScenarioSpec) -> dict[str, Any]:
        lins, inv = self._linear_models(draws)
        out: dict[str, Any] = {"lins": lins, "lin_index": inv}
        x_op = np.stack([lin.x0 for lin in lins])[inv].T.copy()
        u_op = np.array([lin.u0 for lin in lins])[inv]
        y_all = np.stack([lin.y0 for lin in lins])[inv]  # (B, q)
        y_op = y_all[:, self.meas].T.copy()
        if np.any(draws.delay + 1e-12 < 0):
            raise SpecError("randomize.delay", "delays must be >= 0")
        check_delay_samples(float(np.max(draws.delay, initial=0.0)), _dt(sc))
        # Distinct (parameter row, delay) pairs are discretised once.
        keys = np.stack([inv.astype(float), draws.delay], axis=1)
        ukeys, kinv = np.unique(keys, axis=0, return_inverse=True)
        kinv = kinv.ravel()
        A = np.stack([lins[int(k)].A for k in ukeys[:, 0]])
        Bm = np.stack([lins[int(k)].B for k in ukeys[:, 0]])
        if self.plant.kind == "lti":
            Ad, G0, G1, d = self._discretize_cached(A, Bm, _dt(sc), ukeys[:, 1])
            Cm = np.stack([lins[int(k)].C[self.meas] for k in ukeys[:, 0]])  # (U, L, n)
            Dm = np.stack([lins[int(k)].D[self.meas, 0] for k in ukeys[:, 0]])  # (U, L)
            out.update(
                Ad=np.ascontiguousarray(np.moveaxis(Ad[kinv], 0, -1)),
                G0=np.ascontiguousarray(G0[kinv].T),
                G1=np.ascontiguousarray(G1[kinv].T),
                Cm=np.ascontiguousarray(np.moveaxis(Cm[kinv], 0, -1)),
                Dm=np.ascontiguousarray(Dm[kinv].T),
                dsteps=d[kinv],
            )
        else:
            z = np.zeros((1, 1, 1))
            out.update(Ad=z, G0=np.zeros((1, 1)), G1=np.zeros((1, 1)), Cm=z, Dm=np.zeros((1, 1)))
            # Nonlinear plants use whole-sample delays (rounded), documented in docs/simulation.md.
            out["dsteps"] = np.round(draws.delay / sc.dt).astype(np.int64)
        out.update(x_op=x_op, u_op=u_op, y_op=y_op)
        return out

    def _discretize_cached(self, A: np.ndarray, Bm: np.ndarray, dt: float, delay: np.ndarray):
        """:func:`discretize`, memoised per (A, B, dt, delay): repeated batches skip the matrix exponentials."""
        cache = self.__dict__.setdefault("_disc_cache", {})
        keys = [(A[i].tobytes(), Bm[i].tobytes(), dt, float(delay[i])) for i in range(A.shape[0])]
        missing = [i for i, key in enumerate(keys) if key not in cache]
        if missing:
            if len(cache) > 20000:
                cache.clear()
            Ad, G0, G1, d = discretize(A[missing], Bm[missing], dt, delay[missing])
            for r, i in enumerate(missing):
                cache[keys[i]] = (Ad[r], G0[r], G1[r], d[r])
        parts = [cache[key] for key in keys]
        return (np.stack([p[0] for p in parts]), np.stack([p[1] for p in parts]),
                np.stack([p[2] for p in parts]), np.array([p[3] for p in parts], dtype=np.int64))

    # ------------------------------------------------------- controllers
    def _controller_template(self, B: int) -> dict[str, Any]:
        """The gain-independent controller arrays for batch size B, built once per size.

        The kernel only reads them, so every call with this B shares them. Only
        the gain rows are computed per call, which keeps a single simulation cheap.
        """
        cache = self.__dict__.setdefault("_ctrl_templates", {})
        tpl = cache.get(B)
        if tpl is None:
            spec = self.spec
            L = len(spec.loops)
            bw, cw = np.ones((L, B)), np.ones((L, B))
            lo, hi = np.full((L, B), -np.inf), np.full((L, B), np.inf)
            aw = np.zeros(L, dtype=np.int64)
            for li, loop in enumerate(spec.loops):
                if loop.is_lq:
                    aw[li] = AW_CODES["clamping"]
                    continue
                bw[li], cw[li] = loop.b, loop.c
                aw[li] = AW_CODES[loop.anti_windup]
                if loop.output_limits is not None:
                    lo[li], hi[li] = loop.output_limits
            n = self.plant.order
            tpl = dict(bw=bw, cw=cw, lo=lo, hi=hi, aw=aw, sf=any(lp.is_lq for lp in spec.loops),
                       K=np.zeros((n, B)), kint=np.zeros(B), nr=np.zeros(B))
            if len(cache) > 16:
                cache.clear()
            cache[B] = tpl
        return tpl

    def controller_arrays(self, full: np.ndarray, plant_arr: dict[str, Any]) -> dict[str, np.ndarray]:
        """Kernel controller arrays for B full gain vectors (B, n_gains): PID rows per loop, LQ gains."""
        B = full.shape[0]
        # (a NaN or inf gives a non-finite sum; only then is the element-wise check needed)
        if not math.isfinite(float(full.sum())) and not np.isfinite(full).all():
            raise GainError("gains", "gains must be finite numbers")
        arrs = dict(self._controller_template(B))
        gain_rows = np.zeros((5, len(self.spec.loops), B))  # fresh per call: kp, ki, kd, tf, kb
        kp, ki, kd, tf, kb = gain_rows
        arrs.update(kp=kp, ki=ki, kd=kd, tf=tf, kb=kb)
        for li, loop in enumerate(self.spec.loops):
            cols = {nm: full[:, k] for k, nm in self.loop_columns[li]}
            if loop.is_lq:
                lins, inv = plant_arr["lins"], plant_arr["lin_index"]
                keys = np.concatenate([np.stack(list(cols.values()), 1), inv[:, None].astype(float)], 1)
                ukeys, kinv = np.unique(keys, axis=0, return_inverse=True)
                sols = [
                    lq_gains(loop, dict(zip(cols, row[:-1], strict=True)), lins[int(row[-1])], self.meas[li])
                    for row in ukeys
                ]
                arrs.update(
                    K=np.stack([s.K for s in sols])[kinv.ravel()].T,
                    kint=np.array([s.Kint for s in sols])[kinv.ravel()],
                    nr=np.array([s.Nr for s in sols])[kinv.ravel()],
                )
                continue
            p = pid_params(loop, cols)
            kp[li], ki[li], kd[li], tf[li] = p.Kp, p.Ki, p.Kd, p.Tf
            if loop.anti_windup == "back_calculation":
                kb[li] = 1.0 / np.asarray(p.Tt)  # Tt = inf (no integral action) gives 0
        return arrs

    def fallback_arrays(self, B: int, ctrl: dict[str, np.ndarray], plant_arr: dict[str, Any]) -> dict[str, np.ndarray]:
        sf = self.spec.safety
        if sf.action != "fallback":
            return {f"fb_{k}": ctrl[k] for k in ("kp", "ki", "kd", "tf", "kb")}
        if not sf.fallback_gains:
            raise SpecError("safety.fallback_gains", "action 'fallback' needs fallback_gains {loop: {gain: value}}")
        vec = self.layout.from_dict(sf.fallback_gains, field="safety.fallback_gains")
        fb = self.controller_arrays(np.tile(vec, (B, 1)), plant_arr)
        return {f"fb_{k}": fb[k] for k in ("kp", "ki", "kd", "tf", "kb")}

    # ----------------------------------------------------------- signals
    def signal_arrays(self, draws: Draws, sc: ScenarioSpec) -> dict[str, np.ndarray]:
        B = len(draws)
        T = sc.n_steps
        dt = _dt(sc)
        base_ref = profile_pieces(sc.reference, dt, T)
        per_kind = [profile_pieces(sc.reference, dt, T, kind) for kind in REF_KINDS]
        dist = profile_pieces(sc.disturbance, dt, T)
        S = max([len(base_ref), len(dist), 1] + [len(p) for p in per_kind])
        k0 = np.full((3, S, B), T + 1, dtype=np.int64)
        k1 = np.full((3, S, B), T + 1, dtype=np.int64)
        off = np.zeros((3, S, B))
        slope = np.zeros((3, S, B))

        def fill(sig: int, pieces, mask: np.ndarray, scale: np.ndarray, shift: np.ndarray | None = None):
            for i, (a, e, o, s) in enumerate(pieces):
                sh = shift[mask] if shift is not None else 0
                k0[sig, i, mask] = a + sh
                k1[sig, i, mask] = np.minimum(e + sh, T + 1) if e <= T else T + 1
                off[sig, i, mask] = o * scale[mask]
                slope[sig, i, mask] = s * scale[mask]

        # Reference: the scenario's own profile, or a drawn kind; a drawn amplitude rescales it.
        ref_amp = sc.reference.amplitude if sc.reference.kind != "ramp" else sc.reference.slope
        scale = np.where(np.isnan(draws.ref_amp), 1.0, draws.ref_amp / (ref_amp if ref_amp != 0 else 1.0))
        own = draws.ref_kind < 0
        fill(0, base_ref, own, scale)
        for i, pieces in enumerate(per_kind):
            fill(0, pieces, draws.ref_kind == i, scale)
        dsize = sc.disturbance.amplitude if sc.disturbance.kind != "ramp" else sc.disturbance.slope
        dscale = np.where(np.isnan(draws.dist_size), 1.0, draws.dist_size / (dsize if dsize != 0 else 1.0))
        late = np.round((draws.dist_time - sc.disturbance.time) / dt)
        shift = np.where(np.isnan(draws.dist_time), 0, late).astype(np.int64)
        sig = 1 if sc.disturbance.entry == "input" else 2
        fill(sig, dist, np.ones(B, dtype=bool), dscale, shift)
        # Metric anchors: final reference value, step start, load start.
        kk = T - 1
        active = (k0[0] <= kk) & (kk < k1[0])
        target = (active * (off[0] + slope[0] * (kk - k0[0]) * dt)).sum(axis=0)
        k_step = np.where(k0[0, 0] <= T, k0[0, 0], 0)
        k_load = np.where(k0[sig, 0] <= T, k0[sig, 0], T + 1) if dist else np.full(B, T + 1)
        return dict(sk0=k0, sk1=k1, soff=off, sslope=slope, target=target, k_step=k_step, k_load=k_load)
