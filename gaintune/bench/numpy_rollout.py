"""The closed loop as a plain NumPy loop over time steps: the benchmark's baseline and the kernel's twin.

:func:`numpy_rollout` implements the numba kernel's discrete-time law and streaming metrics again
in NumPy, batched over candidates (:mod:`gaintune.bench.sim` times the kernel against it; the tests
compare the two). :data:`NUMPY_PLANTS` holds the hand-written right-hand sides of the nonlinear
models it supports.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["NUMPY_PLANTS", "numpy_rollout", "prepare_numpy"]


def _water_tank_numpy(params: dict[str, float]) -> tuple[Callable, Callable]:
    A, a, b = params["A"], params["a"], params["b"]

    def rhs(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return ((b * u - a * np.sqrt(np.maximum(x[0], 0.0))) / A)[None, :]

    return rhs, lambda x: x[:1]


#: Hand-written NumPy right-hand sides (and output maps) of nonlinear benchmark plants.
NUMPY_PLANTS: dict[str, Callable[[dict[str, float]], tuple[Callable, Callable]]] = {"water_tank": _water_tank_numpy}


class _Rollout:
    """One NumPy rollout's state (controllers, streaming metrics, plant), advanced a sample at a time.

    The steps are the kernel's, in its order: measure, control (cascade, anti-windup, rate limit,
    safety hold), record the metrics, update the plant over the sample.
    """

    def __init__(self, p: dict[str, Any], traces: bool) -> None:
        self.p, self.traces = p, traces
        T, L, B = p["T"], p["L"], p["B"]
        self.x = p["x0"].copy()
        self.integ = p["I0"].copy()
        self.D, self.edp, self.awe = (np.zeros((L, B)) for _ in range(3))
        self.uprev = np.full(B, p["u_op"])
        self.y0 = np.zeros(B)
        self.inv = np.zeros(B)
        self.iae, self.ise, self.itae, self.effort, self.tv, self.peak_u, self.sat, self.peak = (
            np.zeros(B) for _ in range(8))
        self.t10, self.t90, self.last = (np.full(B, -1.0) for _ in range(3))
        self.tripped = np.zeros(B, dtype=bool)
        self.tr_u = np.zeros((T, B) if traces else (0, B))
        self.tr_y = np.zeros((L, T, B) if traces else (L, 0, B))

    def outputs(self) -> np.ndarray:
        p = self.p
        return p["Cm"] @ self.x if p["rhs"] is None else p["out"](self.x)

    def control(self, k: int, Y: np.ndarray) -> np.ndarray:
        """The actuator command of sample ``k``: the cascade outer to inner, then rate limit and safety hold."""
        p = self.p
        dt, meas, sp = p["dt"], p["meas"], p["r"][k]
        if p["monitor"]:  # safety monitor, hold action: the actuator goes to the safe value for good
            self.tripped |= (np.abs(sp - Y[meas[0]]) > p["max_err"]) | np.any(np.abs(Y) > p["max_out"], axis=0)
            self.tripped |= np.any(np.abs(self.x) > p["xb"], axis=0)
        for li in range(p["L"]):
            sp = self._loop(li, k, Y[meas[li]], sp)
        u = sp
        if np.isfinite(p["rate"]):
            u = np.clip(u, self.uprev - p["rate"] * dt, self.uprev + p["rate"] * dt)
        if p["monitor"]:
            u = np.where(self.tripped, p["u_safe"], u)
        if p["aw"][p["L"] - 1] == 2:
            self.awe[p["L"] - 1] += u - sp
        return u

    def _loop(self, li: int, k: int, y: np.ndarray, sp: np.ndarray) -> np.ndarray:
        """One PID loop of the cascade: its saturated output, the next loop's setpoint."""
        p = self.p
        dt, kp, ki, kb, lo, hi = p["dt"], p["kp"][li], p["ki"][li], p["kb"][li], p["lo"][li], p["hi"][li]
        e = sp - y
        ed = p["cw"][li] * sp - y
        if k == 0:
            self.edp[li] = ed
        self.D[li] = p["al"][li] * self.D[li] + p["be"][li] * (ed - self.edp[li])
        self.edp[li] = ed
        pt = kp * (p["bw"][li] * sp - y)
        it = self.integ[li] + ki * dt * e
        if p["aw"][li] == 2:
            it = it + kb * dt * self.awe[li]
        vu = pt + it + self.D[li]
        vs = np.clip(vu, lo, hi)
        if p["aw"][li] == 1:
            hold = (vs != vu) & (e * (vu - vs) * ki > 0)
            it = np.where(hold, self.integ[li], it)
            vu = pt + it + self.D[li]
            vs = np.clip(vu, lo, hi)
        self.integ[li] = it
        self.awe[li] = vs - vu
        return vs

    def record(self, k: int, Y: np.ndarray, u: np.ndarray) -> None:
        """The streaming metrics on the outer loop's output (and the traces)."""
        p = self.p
        dt, meas, u_op = p["dt"], p["meas"], p["u_op"]
        t = k * dt
        yo = Y[meas[0]]
        e0 = p["r"][k] - yo
        ae = np.abs(e0)
        du = u - u_op
        self.iae += ae * dt
        self.ise += e0 * e0 * dt
        self.itae += t * ae * dt
        self.effort += du * du * dt
        self.tv += np.abs(u - self.uprev)
        np.maximum(self.peak_u, np.abs(du), out=self.peak_u)
        self.sat += (u <= p["u_lo"]) | (u >= p["u_hi"])
        if k == 0:
            self.y0 = yo.copy()
            span = p["target"] - self.y0
            self.inv = np.where(span != 0, 1.0 / np.where(span != 0, span, 1.0), 0.0)
        dev = (yo - self.y0) * self.inv
        if k >= p["k_step"]:
            np.maximum(self.peak, dev, out=self.peak)
            self.t10 = np.where((self.t10 < 0) & (dev >= 0.1), t, self.t10)
            self.t90 = np.where((self.t90 < 0) & (dev >= 0.9), t, self.t90)
            self.last = np.where(np.abs(dev - 1.0) >= 0.02, k, self.last)
        self.uprev = u
        if self.traces:
            self.tr_u[k] = u
            for li in range(p["L"]):
                self.tr_y[li, k] = Y[meas[li]]

    def advance(self, u: np.ndarray) -> None:
        """The plant over one sample: the exact ZOH step (LTI) or RK4 (nonlinear)."""
        p = self.p
        rhs, dt, x = p["rhs"], p["dt"], self.x
        if rhs is None:
            self.x = p["Ad"] @ x + p["G0"] * u
            return
        k1 = rhs(x, u)
        k2 = rhs(x + 0.5 * dt * k1, u)
        k3 = rhs(x + 0.5 * dt * k2, u)
        k4 = rhs(x + dt * k3, u)
        self.x = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    def result(self, Y: np.ndarray, loop_names: list[str]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        p = self.p
        T, dt, k_step = p["T"], p["dt"], p["k_step"]
        with np.errstate(all="ignore"):
            y_fin = Y[p["meas"][0]]
            div = ~np.all(np.isfinite(self.x) & (np.abs(self.x) <= p["bound"]), axis=0)
        last = self.last
        settle = np.where(last < T - 1, np.where(last >= 0, (last + 1) * dt - k_step * dt, 0.0), np.nan)
        m = {
            "iae": self.iae, "ise": self.ise, "itae": self.itae, "effort": self.effort, "tv": self.tv,
            "peak_u": self.peak_u, "sat_frac": self.sat / T,
            "overshoot": np.maximum(0.0, self.peak - 1.0) * 100.0,
            "rise_time": np.where((self.t10 >= 0) & (self.t90 >= 0), self.t90 - self.t10, np.nan),
            "settling_time": settle, "y_final": y_fin, "diverged": div, "tripped": self.tripped,
        }
        for key in ("iae", "ise", "itae", "effort", "tv", "peak_u"):
            m[key] = np.where(div, np.inf, m[key])
        tr: dict[str, np.ndarray] = {}
        if self.traces:
            tr["u"] = self.tr_u.T
            for li, name in enumerate(loop_names):
                tr[f"y.{name}"] = self.tr_y[li].T
        return m, tr


def numpy_rollout(
    sim: Any, full: np.ndarray, scenario: int = 0, traces: bool = False, prepared: dict | None = None
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """The closed loop as a plain NumPy loop over time steps, batched over the candidates.

    Implements the same discrete-time law as the kernel (see
    :mod:`gaintune.controllers.pid`: backward-Euler PID, 2-DOF weights,
    derivative filter, output limits, anti-windup, rate limit, cascades) and
    the same streaming metrics, for the nominal plant. Supported: LTI plants
    without delay, or nonlinear plants with a hand-written right-hand side in
    :data:`NUMPY_PLANTS` (RK4); no noise, disturbance, safety monitor or LQ
    loops. It is the benchmark's baseline and a second implementation the
    tests compare the kernel against.

    Returns
    -------
    metrics : dict of (B,) arrays (iae, ise, itae, effort, tv, peak_u, sat_frac,
        overshoot, rise_time, settling_time, y_final, diverged)
    traces : dict with ``u`` (B, T) and ``y.<loop>`` (B, T) when ``traces``
    """
    p = prepared if prepared is not None else prepare_numpy(sim, full, scenario)
    ro = _Rollout(p, traces)
    with np.errstate(all="ignore"):
        Y = ro.outputs()
        for k in range(p["T"]):
            Y = ro.outputs()
            u = ro.control(k, Y)
            ro.record(k, Y, u)
            ro.advance(u)
    return ro.result(Y, [lp.name for lp in sim.spec.loops])


def prepare_numpy(sim: Any, full: np.ndarray, scenario: int = 0) -> dict[str, Any]:
    """Arrays for :func:`numpy_rollout` (built once, outside the timed loop)."""
    spec = sim.spec
    sc = spec.scenarios[scenario]
    full = np.atleast_2d(np.asarray(full, dtype=float))
    B = full.shape[0]
    a = sim.kernel_args(full, scenario=scenario)  # the kernel's own arguments (nominal draws)
    if a.sf:
        raise NotImplementedError("numpy_rollout: LQ loops are not supported")
    if np.any(a.dsteps != 0) or (sim.plant.kind == "lti" and np.any(a.G1 != 0)):
        raise NotImplementedError("numpy_rollout: plant delays are not supported")
    if sc.noise_std > 0 or sc.disturbance.kind != "none":
        raise NotImplementedError("numpy_rollout: noise and disturbances are not supported")
    sf = spec.safety
    if sf.action != "hold":
        raise NotImplementedError("numpy_rollout: only the 'hold' safety action is supported")
    T, dt = sc.n_steps, sc.dt
    L = len(spec.loops)
    lo, hi = a.u_lo[0], a.u_hi[0]  # nominal draws: the spec's limits
    clo, chi = a.lo.copy(), a.hi.copy()
    clo[L - 1], chi[L - 1] = lo, hi
    k = np.arange(T)
    # reference, shared by the candidates (nominal draws): (T,) + operating point
    k0, k1, off, slope = a.sk0[0, :, 0], a.sk1[0, :, 0], a.soff[0, :, 0], a.sslope[0, :, 0]
    act = (k[:, None] >= k0[None, :]) & (k[:, None] < k1[None, :])
    r = (act * (off[None, :] + slope[None, :] * (k[:, None] - k0[None, :]) * dt)).sum(axis=1) + a.y_op[0, 0]
    y_op = a.y_op[:, 0]
    I0 = np.zeros((L, B))
    for li in range(L):
        I0[li] = y_op[li + 1] if li + 1 < L else a.u_op[0]
    tf = a.tf
    out: dict[str, Any] = dict(
        T=T, dt=dt, L=L, B=B, kp=a.kp, ki=a.ki, al=tf / (tf + dt), be=a.kd / (tf + dt),
        bw=a.bw, cw=a.cw, kb=a.kb, lo=clo, hi=chi, aw=a.aw, meas=np.array(sim.setup.meas),
        r=r, rate=a.rate, u_lo=lo, u_hi=hi, u_op=float(a.u_op[0]),
        target=float(a.target[0]), k_step=int(a.k_step[0]),
        x0=np.repeat(a.x_op[:, :1], B, axis=1), I0=I0, bound=a.div_bound,
        max_err=a.max_err, max_out=a.max_out, xb=a.xbound[:, None],
        monitor=bool(sf.max_abs_error or sf.max_abs_output or sf.state_bounds), u_safe=a.u_safe,
        rhs=None, out=None, Ad=None, G0=None, Cm=None,
    )
    if sim.plant.kind == "lti":
        lin = sim.plant.linearize()
        out.update(Ad=a.Ad[:, :, 0].copy(), G0=a.G0[:, :1].copy(), Cm=lin.C.copy())
    else:
        name = spec.plant.model.name if spec.plant.model is not None else None
        if name not in NUMPY_PLANTS:
            raise NotImplementedError(f"numpy_rollout: no NumPy right-hand side for plant {name!r}")
        out["rhs"], out["out"] = NUMPY_PLANTS[name](sim.plant.params)
    return out


