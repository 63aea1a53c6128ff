"""The sampled-loop verification (verify.sampled, the default): the plant as the simulator steps it
(ZOH with the delay exact), the controllers' discrete laws, margins on z = e^{jw dt} up to pi/dt,
stability from the discrete closed-loop poles. Checked against python-control's discrete-time
analysis, hand derivations and the simulator itself."""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from plant_fixtures import MOTOR

from gaintune.controllers.layout import GainLayout
from gaintune.plants.plant import build_plant
from gaintune.spec import load_spec
from gaintune.verification import quick_margins, verify
from gaintune.verification.analysis import analyse
from gaintune.verification.cascade import build_cascade
from gaintune.verification.report import VerificationReport
from gaintune.verification.sampled import sample_plant, zoh_delay
from gaintune.verification.stability import observable_part

#: The API benchmark's DC-motor cascade (speed PI outside, current PI inside) at dt = 1 ms.
MOTOR2 = {
    "plant": {"ss": {"A": [[-100.0, -50.0], [50.0, -0.1]], "B": [[100.0], [0.0]], "C": [[1.0, 0.0], [0.0, 1.0]],
                     "states": ["i", "w"], "outputs": ["i", "w"]}},
    "loops": [{"name": "speed", "type": "pi", "measure": "w"}, {"name": "current", "type": "pi", "measure": "i"}],
    "scenario": {"dt": 1e-3, "horizon": 0.5},
}
MOTOR2_GAINS = {"speed": {"Kp": 2.0, "Ki": 40.0}, "current": {"Kp": 10.0, "Ki": 1000.0}}


def spec_of(plant, loops, dt, horizon=None, **kw):
    return load_spec({"plant": plant, "loops": loops, "scenario": {"dt": dt, "horizon": horizon or 200 * dt}, **kw})


def with_verify(d: dict, **v) -> object:
    return load_spec({**d, "verify": {**d.get("verify", {}), **v}})


def fig(rep, loop="loop0", brk="controller_output"):
    return next(f for f in rep.loops if f.loop == loop and f.break_point == brk)


def pid_z(kp, ki, kd, tf, dt):
    """The simulator's discrete PID law as a python-control transfer function (feedback path):
    Kp + Ki dt z/(z-1) (backward Euler) + Kd (z-1)/((Tf+dt) z - Tf) (backward-Euler filter)."""
    z = ct.tf([1, 0], [1], dt)
    c = kp + 0 * z
    if ki:
        c = c + ki * dt * z / (z - 1)
    if kd:
        c = c + kd * (z - 1) / ((tf + dt) * z - tf)
    return c


# ------------------------------------------------------- the sampled plant


def test_zoh_with_delay_is_the_simulators_discretisation():
    """Same matrices as gaintune.sim.build.discretize (integer and fractional delays)."""
    from gaintune.sim.build import discretize

    lin = build_plant(load_spec(MOTOR2).plant).linearize()
    for delay in (0.0, 1e-3, 2.3e-3, 0.4e-3, 7.999e-3):
        Ad, G0, G1, d, frac = zoh_delay(lin.A, lin.B, 1e-3, delay)
        Ad2, G02, G12, d2 = discretize(lin.A[None], lin.B[None], 1e-3, np.array([delay]))
        assert d == d2[0]
        np.testing.assert_allclose(Ad, Ad2[0], rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(G0, G02[0], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(G1, G12[0], rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("tau_samples", [0.0, 0.3, 1.0, 2.7])
def test_zoh_with_fractional_delay_matches_the_continuous_response(tau_samples):
    """1/(s+1) e^{-s tau} driven by a held unit step: y(k dt) = 1 - e^{-(k dt - tau)} for k dt >= tau."""
    dt = 0.1
    tau = tau_samples * dt
    spec = spec_of({"tf": {"num": [1], "den": [1, 1]}, "delay": tau}, [{"type": "p"}], dt)
    sp = sample_plant(build_plant(spec.plant).linearize(), dt)
    assert sp.d == int(math.floor(tau_samples + 1e-9)) and sp.frac == pytest.approx(tau - sp.d * dt, abs=1e-15)
    x, u = np.zeros(1), lambda k: 1.0 if k >= 0 else 0.0
    for k in range(40):
        t = k * dt
        assert (sp.C @ x)[0] == pytest.approx(1 - math.exp(-(t - tau)) if t >= tau else 0.0, abs=1e-12)
        x = sp.Ad @ x + sp.G0 * u(k - sp.d) + sp.G1 * u(k - sp.d - 1)
    # and its frequency response is the modified z-transform: z^-d (G0 + G1/z) through (zI - Ad)^-1
    z = np.exp(1j * np.array([0.1, 3.0, 20.0]) * dt)
    X = sp.state_response(z)[:, 0]
    want = (sp.G0[0] + sp.G1[0] / z) / (z - sp.Ad[0, 0]) * z ** (-sp.d)
    np.testing.assert_allclose(X, want, rtol=1e-12)


# ------------------------------------------------------- python-control


CASES = [
    # (plant den, loop type, gains, dt, delay in whole samples)
    ("(s+1)^3", "pi", {"Kp": 1.14, "Ki": 0.454}, 0.1, 0),
    ("(s+1)^3", "pid", {"Kp": 2.0, "Ki": 1.0, "Kd": 1.0}, 0.05, 0),
    ("(s+1)^3", "p", {"Kp": 2.0}, 0.2, 0),
    ("(s+1)^3", "pi", {"Kp": 1.0, "Ki": 0.4}, 0.1, 3),
    ("(s+1)*(0.2*s+1)*(0.04*s+1)", "pi", {"Kp": 3.0, "Ki": 2.0}, 0.02, 1),
    ([1, -1], "p", {"Kp": 2.0}, 0.1, 0),  # open-loop unstable: lower GM at w = 0
    ([1, 0], "p", {"Kp": 2.0}, 0.1, 2),  # integrator and 2 samples: GM at the Nyquist frequency
    ([1, 1, 0], "pd", {"Kp": 2.0, "Kd": 0.5}, 0.05, 0),
]


@pytest.mark.filterwarnings("ignore:stability_margins")
@pytest.mark.filterwarnings("ignore::scipy.signal.BadCoefficients")
@pytest.mark.parametrize("den, typ, gains, dt, d", CASES)
def test_matches_python_control_discrete_margins(den, typ, gains, dt, d):
    """control.c2d(G, dt, 'zoh') (times z^-d for a whole-sample delay) in series with the backward-Euler
    PID as a discrete transfer function: GM, PM, Ms (1/sm) and their frequencies to 1e-6."""
    plant = {"tf": {"num": [1], "den": den}, **({"delay": d * dt} if d else {})}
    spec = spec_of(plant, [{"type": typ}], dt)
    rep = verify(spec, {"loop0": gains}, nonlinear=False)
    f = fig(rep)
    lin = build_plant(spec.plant).linearize()
    G = ct.c2d(ct.ss(lin.A, lin.B, lin.C, lin.D), dt, "zoh")
    if d:
        G = ct.series(G, ct.tf2ss(ct.tf([1], [1] + [0] * d, dt)))
    kp, ki, kd = gains.get("Kp", 0.0), gains.get("Ki", 0.0), gains.get("Kd", 0.0)
    tf = kd / kp / 10 if kd else 0.0
    L = ct.series(G, ct.tf2ss(pid_z(kp, ki, kd, tf, dt))) if (ki or kd) else G * kp
    gm, pm, sm, wpc, wgc, _ = ct.stability_margins(L)
    assert rep.stability.stable == bool(np.all(np.abs(ct.feedback(L, 1).poles()) < 1))
    assert rep.stability.domain == "z" and rep.stability.method == "poles"
    assert rep.stability.spectral_radius == pytest.approx(np.abs(ct.feedback(L, 1).poles()).max(), rel=1e-9)
    assert f.gm_db == pytest.approx(abs(20 * np.log10(gm)), rel=1e-6)
    assert f.gm_freq == pytest.approx(wpc, rel=1e-6, abs=1e-12)
    assert f.pm_deg == pytest.approx(pm, rel=1e-6)
    assert f.pm_freq == pytest.approx(wgc, rel=1e-6)
    assert f.ms == pytest.approx(1.0 / sm, rel=1e-6)
    # the delay margin: PM (rad) / wc, in seconds and in samples
    assert f.delay_margin == pytest.approx(math.radians(pm) / wgc, rel=1e-6)
    assert f.delay_margin_samples == pytest.approx(f.delay_margin / dt, rel=1e-12)
    # Mt and the disk margin on a dense grid of the unit circle
    zz = np.exp(1j * np.linspace(1e-4, math.pi, 200001))
    Lz = L(zz).ravel()
    assert f.mt == pytest.approx(np.abs(Lz / (1 + Lz)).max(), rel=1e-6)
    assert f.disk_alpha == pytest.approx(1 / np.abs(1 / (1 + Lz) - 0.5).max(), rel=1e-6)
    assert rep.analysis_band[1] == pytest.approx(math.pi / dt, rel=1e-15)
    assert rep.sampled and rep.dt == dt and rep.sampling_delay == 0.0


def test_integrator_under_p_control_hand_derived():
    """L(z) = K dt / (z - 1): |L| = K dt / (2 sin(theta/2)), arg L = -(pi + theta)/2, L(-1) = -K dt/2.
    GM = 2/(K dt) at the Nyquist frequency; PM = 90 - theta_c/2 (deg) at theta_c = 2 asin(K dt/2)."""
    K, dt = 2.0, 0.1
    rep = verify(spec_of({"tf": {"num": [1], "den": [1, 0]}}, [{"type": "p"}], dt), {"loop0": {"Kp": K}},
                 nonlinear=False)
    f = fig(rep)
    th = 2 * math.asin(K * dt / 2)
    assert f.gm_db == pytest.approx(20 * math.log10(2 / (K * dt)), rel=1e-12)
    assert f.gm_freq == pytest.approx(math.pi / dt, rel=1e-15) and f.gm_binding == "increase"
    assert f.pm_freq == pytest.approx(th / dt, rel=1e-9)
    assert f.pm_deg == pytest.approx(90 - math.degrees(th) / 2, rel=1e-9)
    assert f.delay_margin_samples == pytest.approx(math.radians(90 - math.degrees(th) / 2) / th, rel=1e-9)
    # the single closed-loop pole z = 1 - K dt
    assert rep.stability.poles == [pytest.approx((1 - K * dt, 0.0))]


def test_gm_binding_labels_the_binding_margin():
    """Upper GM binds (increase), lower GM binds (reduction: conditionally stable), no GM (none)."""
    up = verify(spec_of({"tf": {"num": [1], "den": "(s+1)^3"}}, [{"type": "p"}], 0.01), {"loop0": {"Kp": 2.0}},
                nonlinear=False)
    assert fig(up).gm_binding == "increase" and fig(up).gm_db == fig(up).gm_upper_db
    den = np.polymul(np.polymul([1, 0], [1, 2, 1]), [1, 36]).tolist()
    cond = verify(spec_of({"tf": {"num": [1, 12, 36], "den": den}}, [{"type": "pi"}], 1e-3),
                  {"loop0": {"Kp": 200.0, "Ki": 20.0}}, nonlinear=False)
    f = fig(cond)
    assert cond.stability.stable and f.gm_binding == "reduction" and f.gm_db == f.gm_lower_db < f.gm_upper_db
    # a first-order lag has a GM at the Nyquist frequency once sampled (L(-1) < 0), and so has a lead
    # (s+2)/(s+1) = 1 + 1/(s+1): its feedthrough reaches the controller one sample late, L(-1) = -Kp (1 + tanh(dt/2))
    lead = verify(spec_of({"tf": {"num": [1, 2], "den": [1, 1]}}, [{"type": "p"}], 0.01), {"loop0": {"Kp": 0.5}},
                  nonlinear=False)
    assert fig(lead).gm_binding == "increase" and fig(lead).gm_freq == pytest.approx(math.pi / 0.01, rel=1e-12)
    assert fig(lead).gm_db == pytest.approx(20 * math.log10(1 / (0.5 * (1 + math.tanh(0.005)))), rel=1e-9)
    # the sampled double integrator dt^2/2 (z+1)/(z-1)^2 has L(-1) = 0 and phase -180 - theta/2: no crossing
    none = verify(spec_of({"tf": {"num": [1], "den": [1, 0, 0]}}, [{"type": "p"}], 0.01), {"loop0": {"Kp": 0.5}},
                  nonlinear=False)
    assert fig(none).gm_binding == "none" and math.isinf(fig(none).gm_db)


# --------------------------------------------------- the delay-margin bug


def test_delay_margin_below_one_sample_fails_in_sampled_verification():
    """Issue 12: the DC-motor current loop at dt = 1 ms. The continuous analysis plus dt/2 reports a
    delay margin of 0.96 ms and passes; the sampled loop tolerates 0.85 samples, so one sample of
    computation delay destabilises it, and the simulator agrees."""
    cont = verify(with_verify(MOTOR2, sampled=False), MOTOR2_GAINS, nonlinear=False)
    assert cont.verdict == "pass" and not cont.sampled
    assert fig(cont, "current").delay_margin == pytest.approx(0.964e-3, rel=1e-3)
    assert fig(cont, "current").delay_margin_samples < 1.0  # shorter than one sample, yet a pass
    samp = verify(load_spec(MOTOR2), MOTOR2_GAINS, nonlinear=False)
    f = fig(samp, "current")
    assert samp.sampled and f.delay_margin_samples == pytest.approx(0.846, abs=0.002)
    assert f.delay_margin == pytest.approx(f.delay_margin_samples * 1e-3)
    assert samp.verdict == "fail"  # GM 5.6 dB < 6 dB and Ms 2.11 > 2 (the dt/2 model said 9.8 dB and 1.63)
    assert f.gm_db == pytest.approx(5.595, abs=1e-3) and f.gm_freq == pytest.approx(math.pi / 1e-3)
    assert f.ms == pytest.approx(2.106, abs=1e-3)
    # one sample of computation delay exceeds the delay margin: unstable, in the analysis and in simulation
    late = verify(with_verify(MOTOR2, compute_delay=1), MOTOR2_GAINS)
    assert not late.stability.stable and late.verdict == "fail" and late.compute_delay == 1
    assert late.reasons[0].startswith("closed loop unstable") and "|z| >= 1" in late.reasons[0]
    assert late.nonlinear.ran and late.nonlinear.diverged
    # the continuous analysis with one sample of extra delay agrees (its DM was below one sample too)
    continuous = with_verify(MOTOR2, sampled=False, compute_delay=1)
    assert not verify(continuous, MOTOR2_GAINS, nonlinear=False).stability.stable


def test_compute_delay_lowers_the_phase_margin_by_wc_dt():
    """z^-c has unit modulus: the crossover stays, the PM drops by c wc dt (deg), DM by c samples."""
    d = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
         "scenario": {"dt": 0.05, "horizon": 20}}
    g = {"loop0": {"Kp": 1.14, "Ki": 0.454}}
    r0 = verify(load_spec(d), g, nonlinear=False)
    for c in (1, 3):
        rc = verify(with_verify(d, compute_delay=c), g, nonlinear=False)
        f0, fc = fig(r0), fig(rc)
        assert fc.pm_freq == pytest.approx(f0.pm_freq, rel=1e-9)
        assert fc.pm_deg == pytest.approx(f0.pm_deg - math.degrees(c * f0.pm_freq * 0.05), abs=1e-6)
        assert fc.delay_margin_samples == pytest.approx(f0.delay_margin_samples - c, abs=1e-6)
        assert fc.ms > f0.ms and rc.compute_delay == c
    # the same z^-c as a plant delay of c samples
    rd = verify(load_spec({**d, "plant": {**d["plant"], "delay": 0.15}}), g, nonlinear=False)
    r3 = verify(with_verify(d, compute_delay=3), g, nonlinear=False)
    for a, b in zip(rd.loops, r3.loops, strict=True):
        assert a.pm_deg == pytest.approx(b.pm_deg, rel=1e-9) and a.ms == pytest.approx(b.ms, rel=1e-9)


# ----------------------------------------------------------- stability


def test_loop_unstable_at_coarse_dt_is_reported_and_diverges_in_simulation():
    """P = 2.5 on 1/s at dt = 1 s: the closed-loop pole is z = 1 - 2.5 = -1.5. The continuous
    analysis plus dt/2 (PM 18 deg) calls it stable; the sampled one does not, nor does the simulator."""
    d = {"plant": {"tf": {"num": [1], "den": [1, 0]}}, "loops": [{"type": "p"}],
         "scenario": {"dt": 1.0, "horizon": 200}}
    g = {"loop0": {"Kp": 2.5}}
    cont = verify(with_verify(d, sampled=False), g, nonlinear=False)
    assert cont.stability.stable
    rep = verify(load_spec(d), g)
    assert not rep.stability.stable and rep.stability.rhp_count == 1 and rep.stability.nyquist_rhp == 1
    assert rep.stability.poles == [pytest.approx((-1.5, 0.0))] and rep.stability.spectral_radius == pytest.approx(1.5)
    assert rep.stability.max_real_pole == pytest.approx(math.log(1.5))
    assert rep.verdict == "fail" and rep.nonlinear.diverged
    # a stable gain at the same dt: |1 - 1.5| < 1
    ok = verify(load_spec(d), {"loop0": {"Kp": 1.5}})
    assert ok.stability.stable and ok.nonlinear.passed


def test_third_order_pi_unstable_at_coarse_dt():
    d = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
         "scenario": {"dt": 0.05, "horizon": 60}}
    g = {"loop0": {"Kp": 2.0, "Ki": 0.8}}
    fine = verify(load_spec(d), g)
    assert fine.stability.stable and fine.nonlinear.passed
    coarse = load_spec({**d, "scenario": {"dt": 2.0, "horizon": 2000}})
    rep = verify(coarse, g)
    assert not rep.stability.stable and rep.stability.spectral_radius > 1 and rep.verdict == "fail"
    assert rep.nonlinear.diverged
    from gaintune.sim import Simulator

    res = Simulator(coarse).run(GainLayout(coarse, ["x0", "x1", "x2"]).from_dict(g)[None], traces=True)
    assert bool(res.metrics["diverged"][0])


def _annihilation(y: np.ndarray, A: np.ndarray, keep_above: float = 1e-9) -> float:
    """Largest relative residual of the closed-loop characteristic recurrence on the differenced output
    (samples whose terms are below ``keep_above`` of the largest are left out: round-off only)."""
    dy = np.diff(y)
    c = np.poly(A)
    N = c.size - 1
    H = np.stack([dy[i : dy.size - N + i] for i in range(N + 1)], axis=1)
    res = np.abs(H[:, ::-1] @ c)
    scale = np.abs(H[:, ::-1]) @ np.abs(c)
    keep = scale > keep_above * scale.max()
    return float(np.max(res[keep] / scale[keep]))


POLE_CASES = [
    ("pi_third_order", {"tf": {"num": [1], "den": "(s+1)^3"}}, [{"type": "pi"}], {"loop0": {"Kp": 1.14, "Ki": 0.454}},
     0.1),
    ("pid_fractional_delay", {"tf": {"num": [1], "den": "(s+1)^3"}, "delay": 0.23},
     [{"type": "pid", "c": 0.5, "b": 0.7}], {"loop0": {"Kp": 1.0, "Ki": 0.3, "Kd": 0.4}}, 0.1),
    ("motor_two_loops", MOTOR2["plant"], MOTOR2["loops"], MOTOR2_GAINS, 1e-3),
    ("motor_three_loops", MOTOR, [{"name": "position", "type": "p", "measure": "th"},
                                  {"name": "speed", "type": "pi", "measure": "w"},
                                  {"name": "current", "type": "pi", "measure": "i"}],
     {"position": {"Kp": 10.0}, "speed": {"Kp": 2.0, "Ki": 40.0}, "current": {"Kp": 5.0, "Ki": 500.0}}, 1e-3),
    ("lqi", {"tf": {"num": [1], "den": "(s+1)^2"}}, [{"type": "lqi"}], None, 0.05),
]


@pytest.mark.parametrize("name, plant, loops, gains, dt", POLE_CASES, ids=[c[0] for c in POLE_CASES])
def test_discrete_closed_loop_poles_match_the_simulator(name, plant, loops, gains, dt):
    """A step response of the simulator obeys the recurrence of the discrete closed-loop poles
    exactly: the characteristic polynomial of the closed-loop transition matrix annihilates the
    differenced output (every pole the output sees, not only the largest)."""
    from gaintune.sim import Simulator

    spec = spec_of(plant, loops, dt, 400 * dt)
    p = build_plant(spec.plant)
    lay = GainLayout(spec, p.states)
    gains = gains or lay.to_dict(lay.full(lay.initial_tuned()))
    full = lay.from_dict(gains)
    rep = verify(spec, gains, nonlinear=False)
    assert rep.stability.stable
    lin = p.linearize()
    cas = build_cascade(spec, lay, full[None], lin)
    lin_r = observable_part(lin, cas.measured)[0] if cas.measured else lin
    A = cas.closed_loop_sampled(sample_plant(lin_r, dt))[0]
    rho = np.abs(np.linalg.eigvals(A)).max()
    assert rho == pytest.approx(rep.stability.spectral_radius, rel=1e-12)
    y = Simulator(spec, p, lay).run(full[None], traces=True).traces[f"y.{spec.loops[-1].name}"][0]
    exact = _annihilation(y, A)
    assert exact < 1e-7
    # poles moved by 1 % do not annihilate it: the test has teeth
    assert _annihilation(y, A * 1.01) > max(5e-6, 100 * exact)


def test_step_response_decays_at_the_largest_pole():
    """A small step through the simulator: the error decays as rho^k, rho = the largest |z| of the
    sampled closed loop (0.984, real and well clear of the next, 0.845), not at the continuous
    analysis's rate."""
    from gaintune.sim import Simulator

    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)*(0.3*s+1)"}, "delay": 0.25}, "loops": [{"type": "pi"}],
                      "scenario": {"dt": 0.1, "horizon": 40, "reference": {"amplitude": 1e-3}}})
    g = {"loop0": {"Kp": 0.5, "Ki": 0.2}}
    rep = verify(spec, g, nonlinear=False)
    rho = rep.stability.spectral_radius
    assert rep.stability.poles[0] == pytest.approx((rho, 0.0))  # real and dominant
    y = Simulator(spec).run(GainLayout(spec, ["x0", "x1"]).from_dict(g)[None], traces=True).traces["y.loop0"][0]
    e = 1e-3 - y
    ratio = e[250:350] / e[249:349]  # (0.845/0.984)^250 = 3e-17: one mode left
    np.testing.assert_allclose(ratio, rho, rtol=1e-7)
    cont = verify(load_spec({**spec.model_dump(), "verify": {"sampled": False}}), g, nonlinear=False)
    assert abs(math.exp(cont.stability.max_real_pole * 0.1) - rho) > 1e-4  # the dt/2 model's rate differs


def test_nonlinear_plant_is_stepped_as_the_simulator_does():
    """A nonlinear plant is stepped by RK4 in the simulator: the sampled analysis uses the RK4
    matrices of its linearisation; a small step response obeys their recurrence."""
    from gaintune.sim import Simulator

    dt = 0.2
    spec = load_spec({
        "plant": {"ode": {"states": ["x"], "rhs": {"x": "-x^3 - x + u"}, "outputs": {"y": "x"}, "x0": {"x": 1.0}}},
        "loops": [{"type": "pi"}], "scenario": {"dt": dt, "horizon": 20.0, "reference": {"amplitude": 1e-5}}})
    g = {"loop0": {"Kp": 2.0, "Ki": 4.0}}
    rep = verify(spec, g, nonlinear=False)
    p = build_plant(spec.plant)
    lay = GainLayout(spec, p.states)
    lin = p.linearize()
    sp = sample_plant(lin, dt, nonlinear=True)
    assert sp.method == "rk4"
    x = -4.0 * dt  # 1/(s+4) stepped by RK4
    assert sp.Ad[0, 0] == pytest.approx(1 + x + x**2 / 2 + x**3 / 6 + x**4 / 24, rel=1e-14)
    cas = build_cascade(spec, lay, lay.from_dict(g)[None], lin)
    A = cas.closed_loop_sampled(sp)[0]
    assert rep.stability.spectral_radius == pytest.approx(np.abs(np.linalg.eigvals(A)).max(), rel=1e-12)
    y = Simulator(spec, p, lay).run(lay.from_dict(g)[None], traces=True).traces["y.loop0"][0]
    assert _annihilation(y, A, 1e-3) < 1e-5  # the linearisation error of a 1e-5 step
    zoh = cas.closed_loop_sampled(sample_plant(lin, dt))[0]  # exact ZOH of the linearisation: not what runs
    assert _annihilation(y, zoh, 1e-3) > 1e-3


def test_long_delay_nyquist_count_agrees_with_the_poles():
    """Closed loops beyond EIG_MAX states (a long input buffer) are decided by the discrete Nyquist
    count alone: it agrees with the eigenvalues, stable and unstable, also in the quick estimate."""
    import gaintune.verification.stability as stability_mod

    for gains, stable in (({"Kp": 0.3, "Ki": 0.3}, True), ({"Kp": 2.0, "Ki": 2.0}, False)):
        spec = spec_of({"tf": {"num": [1], "den": [1, 1]}, "delay": 0.8}, [{"type": "pi"}], 0.01, 20)
        rep = verify(spec, {"loop0": gains}, nonlinear=False)
        assert rep.stability.method == "nyquist" and rep.stability.poles == [] and rep.stability.stable is stable
        p = build_plant(spec.plant)
        lay = GainLayout(spec, p.states)
        lin = p.linearize()
        cas = build_cascade(spec, lay, lay.from_dict({"loop0": gains})[None], lin)
        ev = np.linalg.eigvals(cas.closed_loop_sampled(sample_plant(lin, 0.01))[0])
        assert rep.stability.rhp_count == int(np.sum(np.abs(ev) >= 1))
    # the quick estimate (batched Nyquist count beyond QUICK_EIG_MAX states) against batched eigenvalues
    spec = spec_of({"tf": {"num": [1], "den": "(s+1)^2"}, "delay": 0.4}, [{"type": "pid"}], 0.01, 20)
    p = build_plant(spec.plant)
    lay = GainLayout(spec, p.states)
    rng = np.random.default_rng(0)
    G = np.exp(rng.uniform(np.log([0.1, 0.05, 0.01]), np.log([3.0, 3.0, 1.0]), size=(48, 3)))
    q = quick_margins(spec, p, lay, G)
    old = stability_mod.QUICK_EIG_MAX
    try:
        stability_mod.QUICK_EIG_MAX = 10**6
        q_eig = quick_margins(spec, p, lay, G)
    finally:
        stability_mod.QUICK_EIG_MAX = old
    assert np.array_equal(q.stable, q_eig.stable) and q.stable.any() and (~q.stable).any()
    for b in range(0, 48, 6):  # and verify (eigenvalues: 45 states) agrees with both
        assert verify(spec, G[b], nonlinear=False).stability.stable == bool(q.stable[b])


def test_reverse_acting_loop_mirrors_the_direct_one():
    """Negative gains on the negated plant: the same sampled loop (L, margins, stability)."""
    dt = 0.05
    plants = [{"tf": {"num": [s], "den": "(s+1)^3"}, "delay": 0.12} for s in (1, -1)]
    out = []
    for plant, sign in zip(plants, (1, -1), strict=True):
        spec = spec_of(plant, [{"type": "pid"}], dt)
        p = build_plant(spec.plant)
        lay = GainLayout(spec, p.states)
        lin = p.linearize()
        full = sign * np.array([1.0, 0.4, 0.3])  # Kp, Ki, Kd (the layout order)
        cas = build_cascade(spec, lay, full[None], lin)
        out.append(analyse(cas, lin, None, 2000, sampled=sample_plant(lin, dt)))
    a, b = out
    assert a.stability.stable and b.stability.stable
    assert a.stability.spectral_radius == pytest.approx(b.stability.spectral_radius, rel=1e-12)
    for fa, fb in zip(a.figures, b.figures, strict=True):
        for k in ("gm_db", "pm_deg", "delay_margin", "ms", "mt", "disk_alpha"):
            assert getattr(fa, k) == pytest.approx(getattr(fb, k), rel=1e-9)


# --------------------------------------------------------------- report


def test_loop_frequency_responses_are_the_verified_loop():
    """The helper for plots gives the L that verify analysed: e.g. the GM at the Nyquist frequency."""
    from gaintune.verification.core import loop_frequency_responses

    for sampled in (True, False):
        spec = with_verify(MOTOR2, sampled=sampled)
        p = build_plant(spec.plant)
        lay = GainLayout(spec, p.states)
        rep = verify(spec, MOTOR2_GAINS, nonlinear=False)
        wc = np.array([f.pm_freq for f in rep.loops])
        L = loop_frequency_responses(spec, p, lay, lay.from_dict(MOTOR2_GAINS), wc)
        np.testing.assert_allclose(np.abs(np.diag(L)), 1.0, rtol=1e-8)  # each row's gain crossover
        np.testing.assert_allclose(180 + np.degrees(np.angle(np.diag(L))), [f.pm_deg for f in rep.loops], atol=1e-6)


def test_report_fields_and_json_round_trip():
    rep = verify(load_spec(MOTOR2), MOTOR2_GAINS, nonlinear=False)
    assert rep.sampled and rep.dt == 1e-3 and rep.sampling_delay == 0.0 and rep.compute_delay == 0
    assert rep.stability.domain == "z" and rep.stability.spectral_radius < 1
    back = VerificationReport.model_validate_json(rep.model_dump_json())
    assert back.loops[0].delay_margin_samples == pytest.approx(rep.loops[0].delay_margin_samples)
    assert back.loops[0].gm_binding == rep.loops[0].gm_binding and back.stability.domain == "z"
    # a report written before these fields existed still loads; gm_binding is derived
    old = rep.model_dump(mode="json")
    for k in ("sampled", "dt", "compute_delay"):
        old.pop(k)
    for f in old["loops"]:
        f.pop("gm_binding"), f.pop("delay_margin_samples")
    for k in ("domain", "spectral_radius"):
        old["stability"].pop(k)
    again = VerificationReport.model_validate(old)
    assert not again.sampled and [f.gm_binding for f in again.loops] == [f.gm_binding for f in rep.loops]
    from gaintune.verification import format_table

    text = format_table(rep)
    assert "DM smp" in text and "sampled loop at dt 0.001 s" in text


def test_robust_samples_use_the_sampled_loop():
    spec = load_spec({"plant": {"tf": {"num": ["K"], "den": "(T*s+1)^3"}, "params": {"K": 1.0, "T": 1.0}, "delay": 0.1},
                      "loops": [{"type": "pi"}], "scenario": {"dt": 0.1, "horizon": 30},
                      "randomize": {"params": {"K": [0.7, 1.4]}, "delay": [0.05, 0.33]},
                      "verify": {"robust_samples": 2}})
    g = {"loop0": {"Kp": 1.0, "Ki": 0.4}}
    rep = verify(spec, g, nonlinear=False)
    w = rep.robust.worst[0]
    assert w.where["pm_deg"] == {"K": 1.4, "delay": 0.33}
    # the worst PM is the sampled loop's at that corner (fractional delay 3.3 samples)
    corner = load_spec({"plant": {"tf": {"num": [1.4], "den": "(s+1)^3"}, "delay": 0.33}, "loops": [{"type": "pi"}],
                        "scenario": {"dt": 0.1, "horizon": 30}})
    ref = fig(verify(corner, g, nonlinear=False))
    assert w.pm_deg == pytest.approx(ref.pm_deg, rel=1e-9)
    assert w.delay_margin_samples == pytest.approx(ref.delay_margin_samples, rel=1e-9)


def test_pade_order_is_not_used_by_the_sampled_analysis():
    d = {"plant": {"tf": {"num": [1], "den": [1, 1]}, "delay": 1.0}, "loops": [{"type": "pi"}],
         "scenario": {"dt": 0.05, "horizon": 20}}
    g = {"loop0": {"Kp": 0.5, "Ki": 0.4}}
    a = verify(load_spec(d), g, nonlinear=False)
    b = verify(with_verify(d, pade_order=2), g, nonlinear=False)
    assert b.pade is None and any("pade_order" in n for n in b.notes)
    assert fig(a).pm_deg == fig(b).pm_deg and a.delay_method == b.delay_method == "exact"


def test_sampled_converges_to_continuous_as_dt_shrinks():
    """At small dt the sampled loop approaches the continuous one (whose dt/2 model then agrees too)."""
    d = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pid"}]}
    g = {"loop0": {"Kp": 2.0, "Ki": 1.0, "Kd": 1.0}}
    errs = []
    for dt in (0.1, 0.01, 0.001):
        s = fig(verify(load_spec({**d, "scenario": {"dt": dt, "horizon": 30}}), g, nonlinear=False))
        cspec = load_spec({**d, "scenario": {"dt": dt, "horizon": 30}, "verify": {"sampled": False}})
        c = fig(verify(cspec, g, nonlinear=False))
        errs.append(abs(s.pm_deg - c.pm_deg))
    assert errs[0] > errs[1] > errs[2] and errs[2] < 0.05


def test_a_sampled_plant_with_a_buffer_past_100_samples_has_the_exact_delay_factor() -> None:
    """NumPy's complex ``**`` leaves repeated multiplication at an exponent of 100; the sampled response
    squares instead (gaintune.lti.arrays.int_power), and the factor z^-d must still be e^{-s d dt}."""
    import dataclasses

    from gaintune.verification.sampled import sample_plant

    spec = load_spec({"plant": {"tf": {"num": [1.0], "den": [1.0, 1.0]}, "delay": 1.5},
                      "loops": [{"type": "pi"}], "scenario": {"dt": 0.01, "horizon": 20.0}})
    lin = build_plant(spec.plant).linearize()
    sp = sample_plant(lin, 0.01, 0, False)
    assert sp.d >= 100
    w = np.linspace(0.01, sp.nyquist, 997)
    z = np.exp(1j * w * sp.dt)
    shifted = sample_plant(dataclasses.replace(lin, delay=0.0), 0.01, 0, False)
    expect = shifted.state_response(z) * np.exp(-1j * w * sp.dt * sp.d)[:, None]
    assert np.allclose(sp.state_response(z), expect, rtol=1e-11, atol=1e-13)
