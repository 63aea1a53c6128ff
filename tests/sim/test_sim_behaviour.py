"""Simulator behaviour against hand-derived cases: saturation, anti-windup, rate limit, cascade limits,
batching, divergence, the safety monitor, noise, disturbances and reference profiles."""

from __future__ import annotations

import warnings
from typing import Any

import control as ct
import numpy as np
import pytest

from gaintune.bench.sim import numpy_rollout
from gaintune.sim import Simulator
from gaintune.sim import draws as draws_mod
from gaintune.spec import Gains, load_spec

LAG3 = {"tf": {"num": [1], "den": "(s+1)^3"}}
INTEGRATOR = {"tf": {"num": [1], "den": [1, 0]}}
LAG1 = {"tf": {"num": [1], "den": [1, 1]}}


def make(spec: dict[str, Any]) -> Simulator:
    return Simulator(load_spec(spec))


def run1(spec: dict[str, Any], gains: Gains, **kw):
    sim = make(spec)
    return sim.run(sim.layout.from_dict(gains)[None, :], traces=True, **kw)


# ------------------------------------------------------- saturation, anti-windup


def test_p_loop_on_integrator_with_saturation_gives_the_exact_saturated_ramp() -> None:
    dt, Kp, umax = 0.01, 50.0, 1.0
    spec = {"plant": INTEGRATOR, "loops": [{"type": "p"}], "actuator": {"limits": [-umax, umax]},
            "scenario": {"dt": dt, "horizon": 2.0}}
    res = run1(spec, {"loop0": {"Kp": Kp}})
    y, u = res.traces["y.loop0"][0], res.traces["u"][0]
    # hand derivation: y[k+1] = y[k] + dt*u[k]; u = min(Kp*(1 - y), umax)
    yy, uu = np.zeros_like(y), np.zeros_like(u)
    for k in range(len(y)):
        uu[k] = min(Kp * (1.0 - yy[k]), umax)
        if k + 1 < len(y):
            yy[k + 1] = yy[k] + dt * uu[k]
    n_sat = int(np.sum(uu == umax))
    assert n_sat in (98, 99)  # saturated while 1 - y >= umax/Kp = 0.02, i.e. up to y = 0.98
    np.testing.assert_allclose(y[: n_sat + 1], np.arange(n_sat + 1) * dt * umax, rtol=0, atol=1e-13)
    assert np.all(u[:n_sat] == umax)
    np.testing.assert_allclose(y, yy, rtol=0, atol=1e-13)
    np.testing.assert_allclose(u, uu, rtol=0, atol=1e-12)
    # after saturation the error decays geometrically by (1 - Kp*dt) per sample
    e = 1.0 - y[n_sat:n_sat + 20]
    np.testing.assert_allclose(e[1:] / e[:-1], 1.0 - Kp * dt, rtol=1e-9)
    assert res.metrics["sat_frac"][0] == pytest.approx(n_sat / len(y))
    assert res.metrics["peak_u"][0] == umax


def _aw_spec(mode: str, tt: float | None = None) -> dict[str, Any]:
    loop: dict[str, Any] = {"type": "pi", "anti_windup": mode}
    if tt is not None:
        loop["tracking_time"] = tt
    return {"plant": LAG1, "loops": [loop], "actuator": {"limits": [-1.5, 1.5]}, "scenario": {"dt": 0.01, "horizon": 15.0}}


AW_GAINS = {"loop0": {"Kp": 2.0, "Ki": 4.0}}


@pytest.mark.parametrize("mode, tt", [("none", None), ("clamping", None), ("back_calculation", 0.05), ("back_calculation", 2.0)])
def test_anti_windup_modes_match_the_documented_law(mode: str, tt: float | None) -> None:
    """Traces equal an independent NumPy implementation of the law in gaintune.controllers.pid."""
    spec = _aw_spec(mode, tt)
    sim = make(spec)
    full = sim.layout.from_dict(AW_GAINS)[None, :]
    res = sim.run(full, traces=True)
    m, tr = numpy_rollout(sim, full, traces=True)
    np.testing.assert_allclose(res.traces["u"], tr["u"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.traces["y.loop0"], tr["y.loop0"], rtol=0, atol=1e-12)
    for k in ("iae", "overshoot", "settling_time", "rise_time", "sat_frac", "tv", "effort"):
        np.testing.assert_allclose(res.metrics[k], m[k], rtol=1e-11, atol=1e-12)


def test_windup_overshoot_ordering_and_the_integrator_during_saturation() -> None:
    over = {}
    for key, (mode, tt) in {"none": ("none", None), "clamp": ("clamping", None), "bc_fast": ("back_calculation", 0.05),
                            "bc_slow": ("back_calculation", 5.0)}.items():
        over[key] = run1(_aw_spec(mode, tt), AW_GAINS)
    os_ = {k: r.metrics["overshoot"][0] for k, r in over.items()}
    # a saturating step: windup is visible without anti-windup, clamping removes most of it,
    # and a shorter tracking time means less windup
    assert os_["none"] > 2 * os_["clamp"]
    assert os_["none"] > os_["bc_slow"] > os_["bc_fast"]
    assert over["none"].metrics["sat_frac"][0] > over["clamp"].metrics["sat_frac"][0]
    # without anti-windup the integrator keeps integrating the error while saturated:
    # I[k] = Ki*dt*sum(e[0..k]), so u_unsat = Kp*e + I and u = clip(u_unsat)
    r = over["none"]
    y, u = r.traces["y.loop0"][0], r.traces["u"][0]
    e = 1.0 - y
    I = 4.0 * 0.01 * np.cumsum(e)
    np.testing.assert_allclose(u, np.clip(2.0 * e + I, -1.5, 1.5), rtol=0, atol=1e-12)
    # with clamping the integrator is frozen while saturated with the error driving further
    rc = over["clamp"]
    yc, uc = rc.traces["y.loop0"][0], rc.traces["u"][0]
    ec = 1.0 - yc
    Ic = np.zeros_like(ec)
    prev = 0.0
    for k in range(len(ec)):
        it = prev + 4.0 * 0.01 * ec[k]
        vu = 2.0 * ec[k] + it
        if np.clip(vu, -1.5, 1.5) != vu and ec[k] * (vu - np.clip(vu, -1.5, 1.5)) > 0:
            it = prev
        Ic[k] = prev = it
    np.testing.assert_allclose(uc, np.clip(2.0 * ec + Ic, -1.5, 1.5), rtol=0, atol=1e-12)


def test_back_calculation_tracking_gain_effect() -> None:
    """Back-calculation adds dt/Tt*(u_applied - v) to I: recover Tt from the traces."""
    Tt, dt = 0.3, 0.01
    r = run1(_aw_spec("back_calculation", Tt), AW_GAINS)
    y, u = r.traces["y.loop0"][0], r.traces["u"][0]
    e = 1.0 - y
    I = 0.0
    awe = 0.0
    for k in range(len(e)):
        I = I + 4.0 * dt * e[k] + dt / Tt * awe
        v = 2.0 * e[k] + I
        assert u[k] == pytest.approx(np.clip(v, -1.5, 1.5), abs=1e-12)
        awe = u[k] - v


def test_rate_limit_gives_exact_slopes() -> None:
    rate, dt = 0.5, 0.01
    spec = {"plant": LAG1, "loops": [{"type": "p"}], "actuator": {"rate_limit": rate}, "scenario": {"dt": dt, "horizon": 5.0}}
    res = run1(spec, {"loop0": {"Kp": 10.0}})
    u = res.traces["u"][0]
    du = np.diff(np.concatenate([[0.0], u]))
    assert np.all(np.abs(du) <= rate * dt * (1 + 1e-12))
    # while far from the target the actuator ramps at exactly the limit
    np.testing.assert_allclose(u[:100], rate * dt * np.arange(1, 101), rtol=0, atol=1e-13)
    assert res.metrics["tv"][0] == pytest.approx(np.sum(np.abs(du)))


MOTOR2 = {
    "ss": {"A": [[-2.0, 0.0], [1.0, 0.0]], "B": [[4.0], [0.0]], "C": [[1.0, 0.0], [0.0, 1.0]],
           "states": ["w", "th"], "outputs": ["speed", "position"]}
}


def test_outer_loop_output_limits_cap_the_inner_setpoint() -> None:
    spec = {
        "plant": MOTOR2,
        "loops": [
            {"name": "pos", "measure": "position", "type": "p", "output_limits": [-0.5, 0.5]},
            {"name": "spd", "measure": "speed", "type": "pi"},
        ],
        "scenario": {"dt": 0.005, "horizon": 8.0},
    }
    res = run1(spec, {"pos": {"Kp": 20.0}, "spd": {"Kp": 2.0, "Ki": 10.0}})
    sp = res.traces["sp.spd"][0]
    y_pos = res.traces["y.pos"][0]
    assert sp.max() == 0.5 and sp.min() >= -0.5
    capped = sp == 0.5
    assert capped.sum() > 100  # the speed setpoint sits on the cap for a while
    # where it is not capped it is the P law of the outer loop
    np.testing.assert_allclose(sp[~capped], np.clip(20.0 * (1.0 - y_pos[~capped]), -0.5, 0.5), atol=1e-12)
    # while capped, the position ramps at the capped speed (the inner loop tracks 0.5 rad/s)
    slope = np.diff(y_pos[capped][200:300]) / 0.005
    np.testing.assert_allclose(slope, 0.5, rtol=3e-3)


# ------------------------------------------------------------- batching


RANDOM_SPEC: dict[str, Any] = {
    "plant": {"tf": {"num": ["K"], "den": "(T*s + 1)^3"}, "params": {"K": 1.0, "T": 1.0}, "delay": 0.1},
    "loops": [{"type": "pid"}],
    "actuator": {"limits": [-3, 3]},
    "scenario": {"dt": 0.02, "horizon": 10.0, "noise_std": 0.01,
                 "disturbance": {"kind": "step", "entry": "input", "amplitude": 0.3, "time": 5.0}},
    "randomize": {"params": {"K": [0.7, 1.3], "T": [0.8, 1.2]}, "delay": [0.0, 0.33],
                  "reference_kinds": ["step", "ramp", "impulse"], "reference_amplitude": [0.5, 2.0],
                  "actuator_scale": [0.8, 1.2], "disturbance_size": [0.1, 0.5], "disturbance_time": [3.0, 6.0]},
}


@pytest.mark.parametrize("B", [7, 150])  # one chunk (serial kernel) and several chunks (parallel kernel)
def test_batch_equals_loop_of_single_runs_with_random_draws(B: int) -> None:
    sim = make(RANDOM_SPEC)
    rng = np.random.default_rng(1)
    d = draws_mod.sample(sim.spec, sim.plant, rng, B)
    assert len(np.unique(d.ref_kind)) == 3 and len(np.unique(d.delay)) == B
    tuned = np.exp(rng.uniform(np.log([0.5, 0.2, 0.2]), np.log([3.0, 1.5, 1.5]), (B, 3)))
    full = sim.layout.full(tuned)
    batch = sim.run(full, d, traces=True)
    rows = range(B) if B < 20 else rng.choice(B, 12, replace=False)
    for i in rows:
        one = make(RANDOM_SPEC).run(full[i : i + 1], draws_mod.take(d, np.array([i])), traces=True)
        for k, v in batch.metrics.items():
            np.testing.assert_allclose(one.metrics[k][0], v[i], rtol=1e-12, atol=1e-14, err_msg=k)
        np.testing.assert_allclose(one.traces["u"][0], batch.traces["u"][i], rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("model", ["water_tank", "dc_motor", "random"])
def test_kernel_variants_agree_bit_for_bit(model: str) -> None:
    """Parallel chunks, one serial pass over chunks, and the single-lane variant: same numbers.

    Bit for bit on a plant shared by the chunk; with per-candidate plants a single lane takes the
    shared-plant path (zero entries skipped), so sums may differ in the last bits.
    """
    from gaintune.plants.library import load_model
    from gaintune.sim.kernel import run_kernel

    spec = RANDOM_SPEC if model == "random" else load_model(model).example_spec()
    sim = make(spec)
    rng = np.random.default_rng(3)
    B = 70  # two chunks, the second partial
    d = draws_mod.sample(sim.spec, sim.plant, rng, B)
    tuned = sim.layout.initial_tuned()[None, :] * np.exp(rng.uniform(-0.3, 0.3, (B, sim.layout.log_lo.size)))
    args = sim.kernel_args(sim.layout.full(tuned), d)
    outs = [run_kernel(args, variant) for variant in ("parallel", "serial", "single")]
    for o in outs[1:]:
        if model == "random":
            np.testing.assert_allclose(o, outs[0], rtol=1e-12, atol=1e-13)
        else:
            np.testing.assert_array_equal(np.nan_to_num(o, nan=-7.0), np.nan_to_num(outs[0], nan=-7.0))


HELD_SIGNAL_SCENARIOS = [
    {"reference": {"kind": "sequence", "points": [[0, 0], [1, 1], [2.5, 0.3], [4, -0.5]]},
     "disturbance": {"kind": "ramp", "slope": 0.2, "time": 3.0, "entry": "output"}},
    {"reference": {"kind": "ramp", "slope": 0.5, "time": 0.5},
     "disturbance": {"kind": "step", "amplitude": -0.4, "time": 2.0, "entry": "input"}},
    {"reference": {"kind": "impulse", "amplitude": 0.2, "width": 0.05, "time": 0.3},
     "disturbance": {"kind": "sequence", "points": [[1, 0.1], [2, -0.2], [3, 0.0]], "entry": "input"}},
]


@pytest.mark.parametrize("scenario", HELD_SIGNAL_SCENARIOS)
def test_held_shared_signals_equal_per_step_evaluation(scenario: dict[str, Any]) -> None:
    """A chunk-shared signal is re-evaluated only when a piece starts or ends (or under a ramp).

    Breaking the sharing (one inactive extra piece that differs between lanes) forces the
    per-lane evaluation at every step; traces and metrics must agree bit for bit.
    """
    from gaintune.sim.kernel import METRICS, run_kernel

    spec = {"plant": LAG3, "loops": [{"type": "pid"}], "scenario": {"dt": 0.01, "horizon": 5.0, **scenario}}
    sim = make(spec)
    full = np.tile(sim.layout.from_dict({"loop0": {"Kp": 2.0, "Ki": 1.0, "Kd": 0.5}}), (2, 1))
    held = sim.run(full, traces=True)
    args = sim.kernel_args(full)
    T = args.n_steps
    extra = np.full((3, 1, 2), T + 1, dtype=np.int64)
    extra[:, :, 1] = T + 2  # never active, but differs between the two lanes
    args = args._replace(
        sk0=np.concatenate([args.sk0, extra], axis=1),
        sk1=np.concatenate([args.sk1, np.full((3, 1, 2), T + 1, dtype=np.int64)], axis=1),
        soff=np.concatenate([args.soff, np.zeros((3, 1, 2))], axis=1),
        sslope=np.concatenate([args.sslope, np.zeros((3, 1, 2))], axis=1),
    ).with_traces()
    per_step = run_kernel(args, "serial")
    np.testing.assert_array_equal(args.tr_sp[0].T, held.traces["sp.loop0"])
    np.testing.assert_array_equal(args.tr_y[0].T, held.traces["y.loop0"])
    np.testing.assert_array_equal(args.tr_u.T, held.traces["u"])
    held_out = np.stack([held.metrics[m].astype(float) for m in METRICS])
    np.testing.assert_array_equal(np.nan_to_num(per_step, nan=-7.0), np.nan_to_num(held_out, nan=-7.0))


def test_identical_rows_in_a_batch_give_identical_results() -> None:
    spec = {"plant": LAG3, "loops": [{"type": "pid"}], "scenario": {"dt": 0.01, "horizon": 5.0}}
    sim = make(spec)
    full = np.tile(sim.layout.from_dict({"loop0": {"Kp": 2.0, "Ki": 1.0, "Kd": 1.0}}), (200, 1))
    res = sim.run(full)
    for k, v in res.metrics.items():
        assert np.all((v == v[0]) | (np.isnan(v) & np.isnan(v[0]))), k


# ------------------------------------------------------------ divergence


def test_unstable_gains_are_flagged_not_raised() -> None:
    spec = {"plant": LAG3, "loops": [{"type": "p"}], "scenario": {"dt": 0.01, "horizon": 60.0}}
    sim = make(spec)
    full = sim.layout.full(np.array([[2.0], [20.0], [1e150], [1e300]]))  # 8 is the ultimate gain
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = sim.run(full)
    m = res.metrics
    assert m["diverged"].tolist() == [False, True, True, True]
    for k in ("iae", "ise", "itae", "effort", "tv", "sse"):
        assert np.isfinite(m[k][0]) and np.all(np.isinf(m[k][1:])), k
    assert np.all(np.isnan(m["y_final"][1:]))
    # a diverging neighbour does not change a stable row
    alone = sim.run(full[:1])
    assert alone.metrics["iae"][0] == m["iae"][0]


def test_nan_producing_plant_is_flagged_as_diverged() -> None:
    """sqrt of a negative state gives NaN in a nonlinear plant: flagged, never raised."""
    spec = {
        "plant": {"ode": {"states": ["h"], "rhs": {"h": "u - sqrt(h)"}, "outputs": {"y": "h"}, "x0": {"h": 1.0}}},
        "loops": [{"type": "p"}],
        "scenario": {"dt": 0.1, "horizon": 10.0, "reference": {"amplitude": -5.0}},
    }
    sim = make(spec)
    res = sim.run(sim.layout.full(np.array([[5.0]])))
    assert bool(res.metrics["diverged"][0])


# ---------------------------------------------------------------- safety


def test_safety_hold_trips_and_applies_the_safe_value() -> None:
    spec = {"plant": LAG3, "loops": [{"type": "p"}], "scenario": {"dt": 0.01, "horizon": 30.0},
            "actuator": {"safe_value": 0.25}, "safety": {"max_abs_output": 3.0, "action": "hold"}}
    res = run1(spec, {"loop0": {"Kp": 20.0}})
    m = res.metrics
    y, u = res.traces["y.loop0"][0], res.traces["u"][0]
    k_trip = int(np.argmax(np.abs(y) > 3.0))
    assert bool(m["tripped"][0]) and not bool(m["diverged"][0])
    assert m["trip_time"][0] == pytest.approx(k_trip * 0.01)
    np.testing.assert_allclose(u[:k_trip], 20.0 * (1.0 - y[:k_trip]), atol=1e-10)
    assert np.all(u[k_trip:] == 0.25)
    assert abs(y[-1] - 0.25) < 1e-3  # the plant settles at the safe input (static gain 1)


def test_safety_fallback_switches_gains_at_the_trip() -> None:
    spec = {"plant": LAG3, "loops": [{"type": "p"}], "scenario": {"dt": 0.01, "horizon": 30.0},
            "safety": {"max_abs_error": 2.0, "action": "fallback", "fallback_gains": {"loop0": {"Kp": 1.0}}}}
    res = run1(spec, {"loop0": {"Kp": 20.0}})
    y, u = res.traces["y.loop0"][0], res.traces["u"][0]
    k_trip = int(np.argmax(np.abs(1.0 - y) > 2.0))
    assert bool(res.metrics["tripped"][0]) and not bool(res.metrics["diverged"][0])
    assert res.metrics["trip_time"][0] == pytest.approx(k_trip * 0.01)
    np.testing.assert_allclose(u[:k_trip], 20.0 * (1.0 - y[:k_trip]), atol=1e-10)
    np.testing.assert_allclose(u[k_trip:], 1.0 * (1.0 - y[k_trip:]), atol=1e-10)
    assert res.metrics["y_final"][0] == pytest.approx(0.5, abs=1e-3)  # P with K*Kp = 1


def test_safety_does_not_trip_within_bounds() -> None:
    spec = {"plant": LAG3, "loops": [{"type": "p"}], "scenario": {"dt": 0.01, "horizon": 10.0},
            "safety": {"max_abs_output": 3.0}}
    res = run1(spec, {"loop0": {"Kp": 1.0}})
    assert not bool(res.metrics["tripped"][0]) and np.isnan(res.metrics["trip_time"][0])


# ----------------------------------------------------------------- noise


def test_measurement_noise_is_reproducible_and_seeded() -> None:
    Kp, std = 0.5, 0.05
    spec = {"plant": LAG1, "loops": [{"type": "p"}], "scenario": {"dt": 0.01, "horizon": 20.0, "noise_std": std}}
    sim = make(spec)
    full = sim.layout.full(np.array([[Kp]]))
    d1 = draws_mod.sample(sim.spec, sim.plant, np.random.default_rng(3), 1)
    d2 = draws_mod.sample(sim.spec, sim.plant, np.random.default_rng(4), 1)
    a, b, c = sim.run(full, d1, traces=True), sim.run(full, d1, traces=True), sim.run(full, d2, traces=True)
    assert np.array_equal(a.traces["u"], b.traces["u"]) and a.metrics["iae"][0] == b.metrics["iae"][0]
    assert not np.allclose(a.traces["u"], c.traces["u"])
    # recover the noise from u = Kp*(r - y - n): white, zero mean, the requested std
    n = 1.0 - a.traces["y.loop0"][0] - a.traces["u"][0] / Kp
    assert abs(n.mean()) < 4 * std / np.sqrt(n.size)
    assert n.std() == pytest.approx(std, rel=0.08)
    assert abs(np.corrcoef(n[1:], n[:-1])[0, 1]) < 0.1


# ---------------------------------------------------------- disturbances


@pytest.mark.parametrize("entry", ["input", "output"])
def test_load_disturbance_matches_python_control(entry: str) -> None:
    dt, t_d, amp = 0.01, 5.0, 0.4
    spec = {"plant": LAG3, "loops": [{"type": "pi"}],
            "scenario": {"dt": dt, "horizon": 25.0, "reference": {"kind": "none"},
                         "disturbance": {"kind": "step", "entry": entry, "amplitude": amp, "time": t_d}}}
    sim = make(spec)
    res = sim.run(sim.layout.from_dict({"loop0": {"Kp": 1.14, "Ki": 0.454}})[None], traces=True)
    lin = sim.plant.linearize()
    P = ct.c2d(ct.ss(lin.A, lin.B, lin.C, 0), dt, "zoh")
    Cy = ct.ss(ct.tf([1.14 + 0.454 * dt, -1.14], [1.0, -1.0], dt))
    one = ct.ss([], [], [], [[1.0]], dt)
    G = ct.feedback(P, Cy) if entry == "input" else ct.feedback(one, Cy * P)
    dist = np.where(np.arange(len(res.t)) >= int(t_d / dt), amp, 0.0)
    y_ref = np.asarray(ct.forced_response(G, T=res.t, U=dist).outputs)
    y = res.traces["y.loop0"][0]
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-9 * np.abs(y_ref).max())
    m = res.metrics
    assert m["load_iae"][0] > 0
    assert m["load_iae"][0] == pytest.approx(m["iae"][0], rel=1e-12)  # nothing happens before the load
    assert m["load_iae"][0] == pytest.approx(np.sum(np.abs(y)) * dt, rel=1e-9)


def test_load_iae_counts_only_after_the_load() -> None:
    spec = {"plant": LAG3, "loops": [{"type": "pi"}],
            "scenario": {"dt": 0.01, "horizon": 40.0,
                         "disturbance": {"kind": "step", "entry": "input", "amplitude": -0.5, "time": 20.0}}}
    res = run1(spec, {"loop0": {"Kp": 1.14, "Ki": 0.454}})
    e = 1.0 - res.traces["y.loop0"][0]
    assert res.metrics["load_iae"][0] == pytest.approx(np.sum(np.abs(e[2000:])) * 0.01, rel=1e-9)
    assert res.metrics["iae"][0] == pytest.approx(np.sum(np.abs(e)) * 0.01, rel=1e-9)


# ------------------------------------------------------------ references


def _ref_run(reference: dict[str, Any], horizon: float = 10.0):
    spec = {"plant": LAG3, "loops": [{"type": "pi"}], "scenario": {"dt": 0.01, "horizon": horizon, "reference": reference}}
    return run1(spec, {"loop0": {"Kp": 1.14, "Ki": 0.454}})


def test_impulse_reference() -> None:
    res = _ref_run({"kind": "impulse", "amplitude": 2.0, "width": 0.05, "time": 1.0})
    r = res.traces["sp.loop0"][0]
    expect = np.zeros_like(r)
    expect[100:105] = 2.0 / 0.05  # area 2 over 5 samples
    np.testing.assert_allclose(r, expect, rtol=1e-12)
    assert res.metrics["iae"][0] == pytest.approx(np.sum(np.abs(r - res.traces["y.loop0"][0])) * 0.01, rel=1e-9)


def test_ramp_reference_and_final_value() -> None:
    res = _ref_run({"kind": "ramp", "slope": 0.3, "time": 2.0})
    r = res.traces["sp.loop0"][0]
    k = np.arange(len(r))
    np.testing.assert_allclose(r, np.where(k >= 200, 0.3 * (k - 200) * 0.01, 0.0), rtol=0, atol=1e-12)
    # sse is measured against the final reference value
    assert res.metrics["sse"][0] == pytest.approx(abs(r[-1] - res.traces["y.loop0"][0][-1]), rel=1e-9)


def test_sequence_reference() -> None:
    res = _ref_run({"kind": "sequence", "points": [[1.0, 1.0], [4.0, -0.5], [7.0, 0.25]]})
    r = res.traces["sp.loop0"][0]
    k = np.arange(len(r))
    expect = np.select([k >= 700, k >= 400, k >= 100], [0.25, -0.5, 1.0], 0.0)
    np.testing.assert_allclose(r, expect, rtol=0, atol=1e-12)
    assert res.metrics["sse"][0] == pytest.approx(abs(0.25 - res.traces["y.loop0"][0][-1]), rel=1e-9)


def test_shared_plant_chunk_and_per_candidate_plants_agree() -> None:
    """A chunk on one plant takes the scalar fast path; mixing in another plant must not change the others."""
    spec = dict(RANDOM_SPEC, scenario={"dt": 0.02, "horizon": 10.0})
    sim = make(spec)
    B = 10
    nom = sim.nominal_draws(B)
    params = nom.params.copy()
    params[-1] = [1.2, 0.9]
    mixed = draws_mod.Draws(params, nom.delay, nom.act_scale, nom.ref_kind, nom.ref_amp, nom.dist_size, nom.dist_time, nom.noise_seed)
    full = sim.layout.full(np.tile([1.5, 0.6, 0.8], (B, 1)))
    a = sim.run(full, nom, traces=True)
    b = sim.run(full, mixed, traces=True)
    np.testing.assert_array_equal(a.traces["u"][:-1], b.traces["u"][:-1])
    for k in ("iae", "ise", "overshoot", "settling_time", "y_final"):
        np.testing.assert_array_equal(a.metrics[k][:-1], b.metrics[k][:-1])
    assert a.metrics["iae"][-1] != b.metrics["iae"][-1]


def test_fallback_with_an_lq_loop_is_rejected_not_ignored() -> None:
    """Regression: the fallback switch only changed PID gains, so an LQR loop silently kept its K after a trip."""
    from gaintune.errors import SpecError

    spec = {"plant": {"ss": {"A": [[0, 1], [2, -0.5]], "B": [[0], [1]], "C": [[1, 0]], "states": ["p", "v"], "outputs": ["p"]}},
            "loops": [{"type": "lqr"}],
            "safety": {"max_abs_error": 0.5, "action": "fallback", "fallback_gains": {"loop0": {"q_p": 1000.0, "q_v": 1.0}}}}
    with pytest.raises(SpecError, match="fallback"):
        make(spec)
