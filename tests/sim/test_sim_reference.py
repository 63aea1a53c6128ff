"""The simulator against independent references: python-control discrete loops, continuous loops, step_info.

Every closed loop here is rebuilt from its documented discrete-time law
(:mod:`gaintune.controllers.pid`): the plant by ``control.c2d(..., 'zoh')``
(times z^-d), the backward-Euler PID as discrete transfer functions

    Ci = Ki*dt*z/(z-1),  Cd = Kd*(z-1)/((Tf+dt)*z - Tf),
    u = Cr*r - Cy*y,     Cr = Kp*b + Ci + c*Cd,  Cy = Kp + Ci + Cd,

interconnected in state space, and simulated with ``control.forced_response``.
Without saturation the traces must agree to ~1e-9 (relative to the peak).
"""

from __future__ import annotations

from typing import Any

import control as ct
import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from gaintune.sim import Simulator
from gaintune.spec import Gains, load_spec

RTOL = 1e-9


# ------------------------------------------------------------------ helpers


def run(spec: dict[str, Any], gains: Gains):
    """One simulation of ``spec`` at ``gains`` with traces."""
    sim = Simulator(load_spec(spec))
    full = sim.layout.from_dict(gains)
    return sim, sim.run(full[None, :], traces=True)


def dss(sys: ct.LTI, dt: float) -> ct.StateSpace:
    """A discrete state-space system (python-control object with timebase dt)."""
    s = ct.ss(sys)
    return ct.ss(s.A, s.B, s.C, s.D, dt)


def pid_tfs(dt: float, Kp: float, Ki: float, Kd: float, Tf: float, b: float = 1.0, c: float = 0.0):
    """Reference (Cr, Cy) of the backward-Euler 2-DOF PID, as discrete state-space systems."""
    z = ct.tf([1, 0], [1], dt)
    Ci = ct.tf([Ki * dt, 0.0], [1.0, -1.0], dt)
    Cd = ct.tf([Kd, -Kd], [Tf + dt, -Tf], dt) if Kd != 0 else 0 * z
    Cr = dss(Kp * b + Ci + c * Cd, dt) if Ki != 0 else dss(Kp * b + c * Cd, dt)
    Cy = dss(Kp + Ci + Cd, dt) if Ki != 0 else dss(Kp + Cd, dt)
    return Cr, Cy


def delay_ss(d: int, dt: float) -> ct.StateSpace:
    return dss(ct.tf([1.0], [1.0] + [0.0] * d, dt), dt)


def c2d_plant(A, B, C, dt: float, d: int = 0) -> ct.StateSpace:
    P = ct.c2d(ct.ss(A, B, C, np.zeros((np.shape(C)[0], 1))), dt, "zoh")
    return P * delay_ss(d, dt) if d else P


def one_loop_ref(P: ct.StateSpace, Cr, Cy, t: np.ndarray, r: np.ndarray):
    """(y, u) of u = Cr*r - Cy*y around P (SISO), via state-space interconnection."""
    T = ct.feedback(P, Cy) * Cr
    y = ct.forced_response(T, T=t, U=r).outputs
    u = ct.forced_response(Cr, T=t, U=r).outputs - ct.forced_response(Cy, T=t, U=y).outputs
    return np.asarray(y), np.asarray(u)


def assert_close(a: np.ndarray, b: np.ndarray, rtol: float = RTOL) -> None:
    """Agreement relative to the peak of the reference trace."""
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * max(np.max(np.abs(b)), 1e-12))


def step(t0: float, n: int, dt: float, amp: float = 1.0) -> np.ndarray:
    k = np.arange(n)
    return np.where(k >= int(round(t0 / dt)), amp, 0.0)


LAG3 = {"tf": {"num": [1], "den": "(s+1)^3"}}


# ------------------------------------------------------- single PID loops


@pytest.mark.parametrize(
    "loop, gains, t_step",
    [
        ({"type": "pid"}, {"Kp": 2.0, "Ki": 1.0, "Kd": 1.0}, 0.0),
        ({"type": "pid", "filter": {"N": 4}}, {"Kp": 1.2, "Ki": 0.5, "Kd": 0.8}, 0.0),
        ({"type": "pid", "filter": {"Tf": 0.05}}, {"Kp": 1.0, "Ki": 0.4, "Kd": 0.6}, 0.0),
        ({"type": "pi"}, {"Kp": 1.14, "Ki": 0.454}, 0.0),
        ({"type": "pd"}, {"Kp": 3.0, "Kd": 1.5}, 0.0),
        ({"type": "p"}, {"Kp": 2.5}, 0.0),
        # 2-DOF weights (the step comes after t = 0: the kernel starts without a derivative kick)
        ({"type": "pid", "b": 0.4, "c": 0.7}, {"Kp": 2.0, "Ki": 1.0, "Kd": 1.0}, 0.5),
        ({"type": "pid", "b": 0.0, "c": 1.0}, {"Kp": 2.0, "Ki": 1.0, "Kd": 1.0}, 0.5),
    ],
)
def test_pid_on_lag3_matches_python_control(loop, gains, t_step) -> None:
    dt, horizon = 0.01, 20.0
    spec = {"plant": LAG3, "loops": [loop], "scenario": {"dt": dt, "horizon": horizon, "reference": {"time": t_step}}}
    sim, res = run(spec, {"loop0": gains})
    lin = sim.plant.linearize()
    from gaintune.controllers.pid import pid_params

    p = pid_params(sim.spec.loops[0], gains)
    Cr, Cy = pid_tfs(dt, p.Kp, p.Ki, p.Kd, p.Tf, loop.get("b", 1.0), loop.get("c", 0.0))
    t = res.t
    y, u = one_loop_ref(c2d_plant(lin.A, lin.B, lin.C, dt), Cr, Cy, t, step(t_step, len(t), dt))
    assert_close(res.traces["y.loop0"][0], y)
    assert_close(res.traces["u"][0], u)
    assert res.metrics["iae"][0] == pytest.approx(np.sum(np.abs(step(t_step, len(t), dt) - y)) * dt, rel=1e-9)


def test_ideal_form_equals_parallel_conversion() -> None:
    dt = 0.01
    Kp, Ti, Td, N = 1.5, 2.0, 0.4, 8.0
    spec = {"plant": LAG3, "loops": [{"type": "pid", "form": "ideal", "filter": {"N": N}}], "scenario": {"dt": dt}}
    sim, res = run(spec, {"loop0": {"Kp": Kp, "Ti": Ti, "Td": Td}})
    lin = sim.plant.linearize()
    Cr, Cy = pid_tfs(dt, Kp, Kp / Ti, Kp * Td, Td / N)
    y, u = one_loop_ref(c2d_plant(lin.A, lin.B, lin.C, dt), Cr, Cy, res.t, step(0, len(res.t), dt))
    assert_close(res.traces["y.loop0"][0], y)
    assert_close(res.traces["u"][0], u)


def test_pi_with_integer_delay() -> None:
    dt, delay = 0.05, 0.6  # 12 whole samples
    spec = {
        "plant": {"tf": {"num": [2.0], "den": [3.0, 1.0]}, "delay": delay},
        "loops": [{"type": "pi"}],
        "scenario": {"dt": dt, "horizon": 30.0},
    }
    sim, res = run(spec, {"loop0": {"Kp": 0.8, "Ki": 0.25}})
    lin = sim.plant.linearize()
    Cr, Cy = pid_tfs(dt, 0.8, 0.25, 0.0, 0.0)
    P = c2d_plant(lin.A, lin.B, lin.C, dt, d=12)
    y, u = one_loop_ref(P, Cr, Cy, res.t, step(0, len(res.t), dt))
    assert np.all(res.traces["y.loop0"][0][:13] == 0.0)  # nothing reaches the output before the delay
    assert_close(res.traces["y.loop0"][0], y)
    assert_close(res.traces["u"][0], u)


def fractional_delay_model(A, B, C, dt: float, delay: float) -> ct.StateSpace:
    """Exact discrete model of x' = Ax + B u(t - delay) under ZOH, built by quadrature.

    With delay = d*dt + f, x[k+1] = Phi x[k] + G0 u[k-d] + G1 u[k-d-1],
    G0 = int_0^{dt-f} e^{As} B ds, G1 = e^{A(dt-f)} int_0^f e^{As} B ds; the
    inputs u[k-1] .. u[k-d-1] are kept in a shift register.
    """
    n = A.shape[0]
    d = int(np.floor(delay / dt + 1e-9))
    f = delay - d * dt

    def gamma(h: float) -> np.ndarray:
        val, _ = scipy.integrate.quad_vec(lambda s: (scipy.linalg.expm(A * s) @ B).ravel(), 0.0, h, epsabs=1e-15, epsrel=1e-13)
        return val

    Phi = scipy.linalg.expm(A * dt)
    G0 = gamma(dt - f)
    G1 = scipy.linalg.expm(A * (dt - f)) @ gamma(f)
    m = d + 1  # register: u[k-1], ..., u[k-d-1]
    N = n + m
    Aa = np.zeros((N, N))
    Ba = np.zeros((N, 1))
    Aa[:n, :n] = Phi
    Aa[:n, n + m - 1] += G1  # u[k-d-1]
    if d == 0:
        Ba[:n, 0] += G0
    else:
        Aa[:n, n + d - 1] += G0  # u[k-d]
    Ba[n, 0] = 1.0
    for i in range(1, m):
        Aa[n + i, n + i - 1] = 1.0
    Ca = np.hstack([C, np.zeros((C.shape[0], m))])
    return ct.ss(Aa, Ba, Ca, np.zeros((C.shape[0], 1)), dt)


@pytest.mark.parametrize("delay", [0.037, 0.25, 0.3 + 1e-3])
def test_pid_with_fractional_delay_matches_exact_discrete_model(delay: float) -> None:
    dt = 0.1
    spec = {
        "plant": {**LAG3, "delay": delay},
        "loops": [{"type": "pid"}],
        "scenario": {"dt": dt, "horizon": 30.0},
    }
    g = {"Kp": 1.2, "Ki": 0.5, "Kd": 0.8}
    sim, res = run(spec, {"loop0": g})
    lin = sim.plant.linearize()
    Cr, Cy = pid_tfs(dt, 1.2, 0.5, 0.8, 0.8 / 1.2 / 10)
    P = fractional_delay_model(lin.A, lin.B, lin.C, dt, delay)
    y, u = one_loop_ref(P, Cr, Cy, res.t, step(0, len(res.t), dt))
    assert_close(res.traces["y.loop0"][0], y)
    assert_close(res.traces["u"][0], u)


def test_fractional_delay_against_continuous_plant_with_the_applied_input() -> None:
    """The plant outputs equal a continuous integration of x' = Ax + B u(t - tau) driven by the ZOH trace u."""
    dt, delay = 0.1, 0.234
    spec = {"plant": {**LAG3, "delay": delay}, "loops": [{"type": "pi"}], "scenario": {"dt": dt, "horizon": 6.0}}
    sim, res = run(spec, {"loop0": {"Kp": 1.0, "Ki": 0.4}})
    lin = sim.plant.linearize()
    u = res.traces["u"][0]
    n_steps = len(u)

    def u_at(t: float) -> float:  # held input seen by the plant at time t (right-continuous)
        k = int(np.floor((t - delay) / dt + 1e-9))
        return u[k] if k >= 0 else 0.0

    # integrate piecewise between input switching instants, with tight tolerances
    edges = sorted({k * dt for k in range(n_steps + 1)} | {k * dt + delay for k in range(n_steps) if k * dt + delay < n_steps * dt})
    x = np.zeros(lin.A.shape[0])
    ys = {0: 0.0}
    for a, b in zip(edges[:-1], edges[1:]):
        uk = u_at(0.5 * (a + b))
        sol = scipy.integrate.solve_ivp(
            lambda t, x: lin.A @ x + lin.B[:, 0] * uk, (a, b), x, method="DOP853", rtol=1e-12, atol=1e-14
        )
        x = sol.y[:, -1]
        k = int(round(b / dt))
        if abs(b - k * dt) < 1e-12 and k < n_steps:
            ys[k] = float(lin.C[0] @ x)
    y_ref = np.array([ys[k] for k in range(n_steps)])
    assert_close(res.traces["y.loop0"][0], y_ref, rtol=1e-8)


# --------------------------------------------------------------- cascade


MOTOR2 = {
    "ss": {
        "A": [[-2.0, 0.0], [1.0, 0.0]],
        "B": [[4.0], [0.0]],
        "C": [[1.0, 0.0], [0.0, 1.0]],
        "states": ["w", "th"],
        "outputs": ["speed", "position"],
    }
}


@pytest.mark.parametrize("outer", [{"type": "p"}, {"type": "pi", "b": 0.5}])
def test_two_loop_cascade_matches_python_control(outer: dict[str, Any]) -> None:
    dt = 0.005
    spec = {
        "plant": MOTOR2,
        "loops": [{"name": "pos", "measure": "position", **outer}, {"name": "spd", "measure": "speed", "type": "pi"}],
        "scenario": {"dt": dt, "horizon": 10.0, "reference": {"time": 0.1}},
    }
    g_out = {"Kp": 3.0} if outer["type"] == "p" else {"Kp": 3.0, "Ki": 0.5}
    g_in = {"Kp": 0.8, "Ki": 4.0}
    sim, res = run(spec, {"pos": g_out, "spd": g_in})
    lin = sim.plant.linearize()
    P = c2d_plant(lin.A, lin.B, lin.C, dt)  # outputs [speed, position]
    Cr_in, Cy_in = pid_tfs(dt, 0.8, 4.0, 0.0, 0.0)
    Cr_out, Cy_out = pid_tfs(dt, g_out["Kp"], g_out.get("Ki", 0.0), 0.0, 0.0, b=outer.get("b", 1.0))
    sel_speed = dss(ct.ss([], [], [], [[1.0, 0.0]]), dt)
    sel_pos = dss(ct.ss([], [], [], [[0.0, 1.0]]), dt)
    inner = ct.feedback(P, Cy_in * sel_speed) * Cr_in  # inner PI closed first: v -> [speed, position]
    outer_cl = ct.feedback(inner, Cy_out * sel_pos) * Cr_out  # r -> [speed, position]
    t = res.t
    r = step(0.1, len(t), dt)
    Y = np.asarray(ct.forced_response(outer_cl, T=t, U=r).outputs)
    assert_close(res.traces["y.pos"][0], Y[1])
    assert_close(res.traces["y.spd"][0], Y[0])
    v = np.asarray(ct.forced_response(Cr_out, T=t, U=r).outputs) - np.asarray(ct.forced_response(Cy_out, T=t, U=Y[1]).outputs)
    assert_close(res.traces["sp.spd"][0], v)


# -------------------------------------------------------------------- LQ


def test_lqr_matches_control_lqr_closed_loop() -> None:
    dt = 0.01
    A = np.array([[0.0, 1.0], [2.0, -0.5]])  # unstable open loop
    B = np.array([[0.0], [1.0]])
    C = np.array([[1.0, 0.0]])
    spec = {
        "plant": {"ss": {"A": A.tolist(), "B": B.tolist(), "C": C.tolist(), "states": ["p", "v"], "outputs": ["p"]}},
        "loops": [{"type": "lqr"}],
        "scenario": {"dt": dt, "horizon": 8.0, "reference": {"time": 0.2, "amplitude": 0.5}},
    }
    q = {"q_p": 10.0, "q_v": 0.5, "r": 0.2}
    sim, res = run(spec, {"loop0": q})
    K, _, _ = ct.lqr(A, B, np.diag([q["q_p"], q["q_v"]]), np.array([[q["r"]]]))
    K = np.asarray(K)
    Nr = 1.0 / float(-(C @ np.linalg.solve(A - B @ K, B))[0, 0])
    P = ct.c2d(ct.ss(A, B, C, 0), dt, "zoh")
    cl = ct.ss(P.A - P.B @ K, P.B * Nr, C, 0, dt)
    t = res.t
    r = step(0.2, len(t), dt, 0.5)
    ref = ct.forced_response(cl, T=t, U=r, return_x=True)
    assert_close(res.traces["y.loop0"][0], np.asarray(ref.outputs))
    u_ref = Nr * r - (K @ np.asarray(ref.states))[0]
    assert_close(res.traces["u"][0], u_ref)
    assert res.metrics["sse"][0] < 1e-3  # Nr from the continuous model: near-zero discrete offset


def test_lqi_matches_hand_built_discrete_loop() -> None:
    dt = 0.01
    A = np.array([[0.0, 1.0], [-4.0, -0.5]])
    B = np.array([[0.0], [1.0]])
    C = np.array([[1.0, 0.0]])
    spec = {
        "plant": {"ss": {"A": A.tolist(), "B": B.tolist(), "C": C.tolist(), "states": ["p", "v"], "outputs": ["p"]}},
        "loops": [{"type": "lqi"}],
        "scenario": {"dt": dt, "horizon": 10.0},
    }
    q = {"q_p": 5.0, "q_v": 0.1, "q_int": 20.0, "r": 0.1}
    sim, res = run(spec, {"loop0": q})
    Aa = np.block([[A, np.zeros((2, 1))], [-C, np.zeros((1, 1))]])
    Ba = np.vstack([B, [[0.0]]])
    Ka, _, _ = ct.lqr(Aa, Ba, np.diag([5.0, 0.1, 20.0]), np.array([[0.1]]))
    Ka = np.asarray(Ka).ravel()
    K, kint = Ka[:2], -Ka[2]
    P = ct.c2d(ct.ss(A, B, C, 0), dt, "zoh")
    # z[k+1] = z[k] + dt*(r - Cx);  u[k] = -K x + kint*z[k+1]
    Acl = np.zeros((3, 3))
    Bcl = np.zeros((3, 1))
    uz_x = -K - kint * dt * C[0]
    Acl[:2, :2] = P.A + P.B @ uz_x[None, :]
    Acl[:2, 2] = P.B[:, 0] * kint
    Bcl[:2, 0] = P.B[:, 0] * kint * dt
    Acl[2, :2] = -dt * C[0]
    Acl[2, 2] = 1.0
    Bcl[2, 0] = dt
    cl = ct.ss(Acl, Bcl, np.hstack([C, [[0.0]]]), 0, dt)
    y = np.asarray(ct.forced_response(cl, T=res.t, U=np.ones(len(res.t))).outputs)
    assert_close(res.traces["y.loop0"][0], y)
    assert abs(res.metrics["y_final"][0] - 1.0) < 1e-3


# ------------------------------------------------------- continuous loop


@pytest.mark.parametrize(
    "loop, gains",
    [({"type": "pid"}, {"Kp": 2.0, "Ki": 1.0, "Kd": 1.0}), ({"type": "pi", "b": 0.6}, {"Kp": 1.14, "Ki": 0.454})],
)
def test_small_dt_approaches_the_continuous_loop(loop, gains) -> None:
    dt = 1e-3
    spec = {"plant": LAG3, "loops": [loop], "scenario": {"dt": dt, "horizon": 15.0}}
    sim, res = run(spec, {"loop0": gains})
    from gaintune.controllers.pid import pid_params

    p = pid_params(sim.spec.loops[0], gains)
    s = ct.tf("s")
    P = ct.tf([1.0], [1.0, 3.0, 3.0, 1.0])
    Cd = p.Kd * s / (p.Tf * s + 1) if p.Kd else 0 * s
    Cy = ct.ss(p.Kp + p.Ki / s + Cd)
    Cr = ct.ss(p.Kp * loop.get("b", 1.0) + p.Ki / s)
    T = ct.feedback(ct.ss(P), Cy) * Cr
    y = np.asarray(ct.forced_response(T, T=res.t, U=np.ones(len(res.t))).outputs)
    # backward Euler + ZOH sampling: O(dt) agreement
    assert_close(res.traces["y.loop0"][0], y, rtol=5e-3)


# ------------------------------------------------------------ step metrics


@pytest.mark.parametrize(
    "plant, loop, gains, dt",
    [
        (LAG3, {"type": "pid"}, {"Kp": 2.0, "Ki": 1.0, "Kd": 1.0}, 0.01),
        (LAG3, {"type": "pi"}, {"Kp": 1.14, "Ki": 0.454}, 0.01),
        (LAG3, {"type": "pi"}, {"Kp": 0.5, "Ki": 0.15}, 0.01),  # overdamped: zero overshoot
        ({"tf": {"num": [2.0], "den": [3.0, 1.0]}, "delay": 0.6}, {"type": "pi"}, {"Kp": 0.8, "Ki": 0.25}, 0.05),
        ({"ss": {"A": [[0, 1], [-4, -0.5]], "B": [[0], [1]], "C": [[1, 0]]}}, {"type": "pid"}, {"Kp": 6.0, "Ki": 8.0, "Kd": 1.0}, 0.01),
    ],
)
def test_step_metrics_match_step_info(plant, loop, gains, dt) -> None:
    spec = {"plant": plant, "loops": [loop], "scenario": {"dt": dt, "horizon": 30.0}}
    _, res = run(spec, {"loop0": gains})
    info = ct.step_info(res.traces["y.loop0"][0], T=res.t, yfinal=1.0)
    m = res.metrics
    assert m["rise_time"][0] == pytest.approx(info["RiseTime"], abs=1e-9)
    assert m["settling_time"][0] == pytest.approx(info["SettlingTime"], abs=1e-9)
    assert m["overshoot"][0] == pytest.approx(info["Overshoot"], abs=1e-9)


def test_step_metrics_are_relative_to_the_final_reference_and_step_time() -> None:
    """A delayed step of amplitude 2 (from a non-zero operating point) reports the same shape metrics."""
    base = {"plant": LAG3, "loops": [{"type": "pid"}], "scenario": {"dt": 0.01, "horizon": 30.0}}
    g = {"loop0": {"Kp": 2.0, "Ki": 1.0, "Kd": 1.0}}
    _, r1 = run(base, g)
    moved = {**base, "scenario": {"dt": 0.01, "horizon": 31.0, "reference": {"amplitude": 2.0, "time": 1.0}}}
    _, r2 = run(moved, g)
    for k in ("rise_time", "overshoot"):
        assert r2.metrics[k][0] == pytest.approx(r1.metrics[k][0], rel=1e-9, abs=1e-9)
    assert r2.metrics["settling_time"][0] == pytest.approx(r1.metrics["settling_time"][0], abs=1e-9)
    assert r2.metrics["iae"][0] == pytest.approx(2 * r1.metrics["iae"][0], rel=1e-6)
