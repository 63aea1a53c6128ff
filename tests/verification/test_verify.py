"""Correctness of gaintune.verification: against python-control, hand derivations, published values and known traps."""

from __future__ import annotations

import json
import math

import control as ct
import numpy as np
import pytest
from plant_fixtures import MOTOR

from gaintune.errors import GainError
from gaintune.spec import load_spec
from gaintune.verification import format_table, verify
from gaintune.verification.report import VerificationReport

# dt = 1 us: the dt/2 sampling delay is negligible when comparing with delay-free python-control loops
FAST = {"dt": 1e-6, "horizon": 0.1}


def make_spec(plant: dict, loops: list[dict], **kw) -> object:
    """A spec for the *continuous* analysis (verify.sampled: false, dt/2 of sampling delay): this file
    checks it against continuous python-control loops. The sampled analysis: test_verify_discrete.py."""
    d = {"plant": plant, "loops": loops, "scenario": kw.pop("scenario", FAST)}
    d.update(kw)
    d["verify"] = {"sampled": False, **d.get("verify", {})}
    return load_spec(d)


def run(spec, gains, **kw):
    kw.setdefault("nonlinear", False)
    return verify(spec, gains, **kw)


def fig(report, loop="loop0", brk="controller_output"):
    return next(f for f in report.loops if f.loop == loop and f.break_point == brk)


def dense_ms(L, lo=-4, hi=5, n=200000):
    """Reference Ms on a dense grid (python-control's sm only looks at finite stationary points)."""
    w = np.logspace(lo, hi, n)
    return float(np.max(np.abs(1 / (1 + L(1j * w)))))


def pid_tf(kp, ki=0.0, kd=0.0, N=10.0):
    s = ct.tf("s")
    c = kp + (ki / s if ki else 0)
    if kd:
        c = c + kd * s / (kd / kp / N * s + 1)
    return c


# ------------------------------------------------------------ python-control


CASES = [
    # (den of plant, loop type, gains, python-control controller)
    ("(s+1)^3", "pi", {"Kp": 1.14, "Ki": 0.454}, pid_tf(1.14, 0.454)),
    ("(s+1)^3", "pid", {"Kp": 2.0, "Ki": 1.0, "Kd": 1.0}, pid_tf(2.0, 1.0, 1.0)),
    ("(s+1)^3", "p", {"Kp": 2.0}, pid_tf(2.0)),
    ("(s+1)*(0.2*s+1)*(0.04*s+1)", "pi", {"Kp": 3.0, "Ki": 2.0}, pid_tf(3.0, 2.0)),
    ("s*(s+1)*(0.1*s+1)", "pd", {"Kp": 2.0, "Kd": 0.5}, pid_tf(2.0, 0.0, 0.5)),
]


@pytest.mark.filterwarnings("ignore:Badly conditioned")
@pytest.mark.parametrize("den, typ, gains, C", CASES)
def test_matches_python_control_stability_and_disk_margins(den, typ, gains, C):
    spec = make_spec({"tf": {"num": [1], "den": den}}, [{"type": typ}])
    rep = run(spec, {"loop0": gains})
    f = fig(rep)
    from gaintune.plants.plant import build_plant

    lin = build_plant(spec.plant).linearize()
    P = ct.ss2tf(ct.ss(lin.A, lin.B, lin.C, lin.D))
    L = ct.minreal(C * P, verbose=False)
    gm, pm, sm, wpc, wgc, wms = ct.stability_margins(L)
    assert rep.stability.stable == bool(np.all(ct.feedback(L, 1).poles().real < 0))
    if np.isfinite(gm):
        assert f.gm_db == pytest.approx(abs(20 * np.log10(gm)), abs=0.02)
        assert f.gm_freq == pytest.approx(wpc, rel=1e-3)
    else:
        assert math.isinf(f.gm_db)
    assert f.pm_deg == pytest.approx(pm, abs=0.05)
    assert f.pm_freq == pytest.approx(wgc, rel=1e-3)
    assert f.ms == pytest.approx(1.0 / sm, rel=1e-3)
    w = np.logspace(-3, 3, 4000)
    dm, dgm, dpm = ct.disk_margins(L, w)
    assert f.disk_alpha == pytest.approx(dm, rel=2e-3)
    assert f.disk_gm_db == pytest.approx(dgm, rel=5e-3)
    assert f.disk_pm_deg == pytest.approx(dpm, rel=5e-3)
    # Mt from the closed loop
    T = ct.feedback(L, 1)
    mag = np.abs(T(1j * np.logspace(-3, 3, 20000)))
    assert f.mt == pytest.approx(mag.max(), rel=2e-3)
    # single loop: controller-output and plant-input breaks coincide
    g = fig(rep, "plant", "plant_input")
    assert g.pm_deg == pytest.approx(f.pm_deg) and g.ms == pytest.approx(f.ms)


# ------------------------------------------------------------ hand-derived


@pytest.mark.parametrize("k, Ld", [(2.0, 0.2), (0.5, 1.0), (5.0, 0.05)])
def test_integrator_with_delay_hand_derived(k, Ld):
    """k e^{-sL}/s: crossover w = k, PM = 90 - k L 180/pi, delay margin pi/(2k) - L."""
    spec = make_spec({"tf": {"num": [1], "den": [1, 0]}, "delay": Ld}, [{"type": "p"}])
    rep = run(spec, {"loop0": {"Kp": k}})
    f = fig(rep)
    Lt = Ld + rep.sampling_delay
    assert rep.sampling_delay == pytest.approx(0.5e-6)
    assert f.pm_freq == pytest.approx(k, rel=1e-6)
    assert f.pm_deg == pytest.approx(90 - k * Lt * 180 / math.pi, abs=1e-4)
    assert f.delay_margin == pytest.approx(math.pi / (2 * k) - Lt, rel=1e-5)
    # phase crossover where w L = pi/2: GM = w180 / k
    w180 = math.pi / (2 * Lt)
    assert f.gm_freq == pytest.approx(w180, rel=1e-5)
    assert f.gm_db == pytest.approx(20 * math.log10(w180 / k), abs=1e-3)
    assert rep.stability.stable and rep.stability.method == "nyquist"
    assert rep.delay_method == "exact"


def test_integrator_with_delay_beyond_delay_margin_is_unstable():
    spec = make_spec({"tf": {"num": [1], "den": [1, 0]}, "delay": 1.0}, [{"type": "p"}])
    rep = run(spec, {"loop0": {"Kp": 2.0}})  # DM = pi/4 - 1 < 0
    assert not rep.stability.stable
    assert rep.verdict == "fail"
    assert rep.accepted_gains is None
    assert any("unstable" in r for r in rep.reasons)


def test_published_pi_on_third_order_lag():
    """PI Kp=1.14, Ki=0.454 on 1/(s+1)^3: PM about 60 deg at about 0.52 rad/s."""
    spec = make_spec({"tf": {"num": [1], "den": "(s+1)^3"}}, [{"type": "pi"}])
    f = fig(run(spec, {"loop0": {"Kp": 1.14, "Ki": 0.454}}))
    assert f.pm_deg == pytest.approx(60.0, abs=0.5)
    assert f.pm_freq == pytest.approx(0.52, abs=0.01)


def test_gm_reported_in_db_not_ratio():
    """P = 2 on 1/(s+1)^3: phase -180 at sqrt(3) where |P| = 1/8, GM ratio 4 = 12.04 dB."""
    spec = make_spec({"tf": {"num": [1], "den": "(s+1)^3"}}, [{"type": "p"}])
    f = fig(run(spec, {"loop0": {"Kp": 2.0}}))
    assert f.gm_db == pytest.approx(20 * math.log10(4.0), abs=1e-3)
    assert f.gm_freq == pytest.approx(math.sqrt(3), rel=1e-5)


# ------------------------------------------------------------------ traps


@pytest.mark.parametrize(
    "den, typ, gains",
    [
        ([1, 1, 0], "p", {"Kp": 1.0}),  # 1/(s(s+1)): phase -> -180 only as w -> inf
        ([1, 10, 0, 0], "pi", {"Kp": 1.0, "Ki": 0.1}),  # double integrator with PI-lead: from -180 up
        ([1, 2, 1], "pi", {"Kp": 1.0, "Ki": 0.5}),  # PI on 1/(s+1)^2: phase -> -180 asymptotically
    ],
)
def test_gm_infinite_when_phase_only_approaches_minus_180_issue_784(den, typ, gains):
    spec = make_spec({"tf": {"num": [1], "den": den}}, [{"type": typ}])
    rep = run(spec, {"loop0": gains})
    f = fig(rep)
    assert math.isinf(f.gm_db) and f.gm_db > 0
    assert f.gm_freq is None
    assert not [c for c in f.crossings if c.kind == "phase"]
    # infinity serialises sanely and round-trips
    data = json.loads(rep.model_dump_json())
    assert data["loops"][0]["gm_db"] == "Infinity"
    back = VerificationReport.model_validate_json(rep.model_dump_json())
    assert math.isinf(back.loops[0].gm_db)


def test_conditionally_stable_loop_reports_every_crossing():
    """(s+6)^2/(s(s+1)^2(s+36)) under PI: two phase crossings, both lower margins."""
    den = np.polymul(np.polymul([1, 0], [1, 2, 1]), [1, 36]).tolist()
    spec = make_spec({"tf": {"num": [1, 12, 36], "den": den}}, [{"type": "pi"}])
    rep = run(spec, {"loop0": {"Kp": 200.0, "Ki": 20.0}})
    f = fig(rep)
    L = ct.tf([1, 12, 36], den) * pid_tf(200.0, 20.0)
    gms, pms, _, wpcs, wgcs, _ = ct.stability_margins(L, returnall=True)
    phase = [c for c in f.crossings if c.kind == "phase"]
    assert len(phase) == len(wpcs) == 2
    assert sorted(c.omega for c in phase) == pytest.approx(sorted(wpcs), rel=1e-4)
    assert sorted(c.value for c in phase) == pytest.approx(sorted(20 * np.log10(gms)), abs=0.01)
    assert rep.stability.stable
    assert math.isinf(f.gm_upper_db)
    assert f.gm_lower_db == pytest.approx(-20 * np.log10(gms).max(), abs=0.01)  # binding: 10.5 dB down
    assert f.gm_db == pytest.approx(f.gm_lower_db)
    assert [c for c in phase if c.binding][0].value == pytest.approx(20 * np.log10(gms).max(), abs=0.01)
    gm_pc = ct.stability_margins(L)[0]
    assert f.gm_db == pytest.approx(abs(20 * np.log10(gm_pc)), abs=0.01)
    # lower the gain below the binding lower margin: unstable
    rep2 = run(spec, {"loop0": {"Kp": 50.0, "Ki": 5.0}})
    assert not rep2.stability.stable


def test_open_loop_unstable_plant_lower_gain_margin_and_stability():
    """1/(s-1) under P=2: stable, L(0) = -2 gives a lower GM of 6.02 dB, no upper GM."""
    spec = make_spec({"tf": {"num": [1], "den": [1, -1]}}, [{"type": "p"}])
    rep = run(spec, {"loop0": {"Kp": 2.0}})
    f = fig(rep)
    assert rep.stability.stable
    assert f.gm_lower_db == pytest.approx(20 * math.log10(2.0), abs=1e-6)
    assert math.isinf(f.gm_upper_db)
    assert f.pm_deg == pytest.approx(60.0, abs=1e-3)
    # P = 0.5 leaves the pole in the RHP
    rep2 = run(spec, {"loop0": {"Kp": 0.5}})
    assert not rep2.stability.stable and rep2.stability.rhp_count == 1
    assert rep2.verdict == "fail"


@pytest.mark.parametrize("T, stable", [(0.1, True), (0.55, True), (0.66, False), (1.0, False)])
def test_open_loop_unstable_plant_with_delay_nyquist(T, stable):
    """1/(s-1) e^{-sT} under P=2: delay margin (pi/3)/sqrt(3) = 0.6046 s."""
    spec = make_spec({"tf": {"num": [1], "den": [1, -1]}, "delay": T}, [{"type": "p"}])
    rep = run(spec, {"loop0": {"Kp": 2.0}})
    assert rep.stability.method == "nyquist"
    assert rep.stability.stable is stable
    if stable:
        assert fig(rep).delay_margin == pytest.approx(math.pi / 3 / math.sqrt(3) - T - rep.sampling_delay, rel=1e-4)


def test_delay_dominant_loop_against_dense_grid_and_pade():
    """e^{-5s}/(s+1) under PI: Ms from a dense exact grid; stability agrees with a high-order Padé."""
    spec = make_spec({"tf": {"num": [1], "den": [1, 1]}, "delay": 5.0}, [{"type": "pi"}])
    for kp, ki in [(0.2, 0.15), (0.3, 0.2), (0.6, 0.4), (1.0, 0.5)]:
        rep = run(spec, {"loop0": {"Kp": kp, "Ki": ki}})
        f = fig(rep)
        w = np.logspace(-3, 2, 400000)
        s = 1j * w
        L = (kp + ki / s) * np.exp(-s * (5.0 + rep.sampling_delay)) / (s + 1)
        assert f.ms == pytest.approx(np.abs(1 / (1 + L)).max(), rel=1e-4)
        num, den = ct.pade(5.0 + rep.sampling_delay, 12)
        Lp = ct.tf([kp, ki], [1, 0]) * ct.tf([1], [1, 1]) * ct.tf(num, den)
        assert rep.stability.stable == bool(np.all(ct.feedback(Lp, 1).poles().real < 0))


# -------------------------------------------------------------- cascades




def test_two_loop_cascade_matches_hand_computation_with_feedback():
    spec = make_spec(MOTOR, [{"name": "speed", "type": "pi", "measure": "w"},
                             {"name": "current", "type": "pi", "measure": "i"}])
    gains = {"speed": {"Kp": 2.0, "Ki": 40.0}, "current": {"Kp": 10.0, "Ki": 1000.0}}
    rep = run(spec, gains)
    A, B = np.array(MOTOR["ss"]["A"]), np.array(MOTOR["ss"]["B"])
    Pi = ct.ss2tf(ct.ss(A, B, [[1, 0, 0]], 0))
    Pw = ct.ss2tf(ct.ss(A, B, [[0, 1, 0]], 0))
    Ci, Cw = pid_tf(10.0, 1000.0), pid_tf(2.0, 40.0)
    # outer loop with the inner loop closed (b=1, c=0: the PI setpoint path equals C)
    inner_closed = ct.feedback(Ci, Pi)  # r_i -> u
    L_out = ct.minreal(Cw * inner_closed * Pw, verbose=False)
    gm, pm, sm, wpc, wgc, _ = ct.stability_margins(L_out)
    f = fig(rep, "speed")
    assert f.pm_deg == pytest.approx(pm, abs=0.05)
    assert f.pm_freq == pytest.approx(wgc, rel=1e-3)
    assert f.ms == pytest.approx(1 / sm, rel=1e-3)
    if 1e-4 < gm < 1e4:  # python-control reports ~300 dB from a spurious crossing here (cf. #784)
        assert f.gm_db == pytest.approx(abs(20 * np.log10(gm)), abs=0.02)
    else:
        assert math.isinf(f.gm_db)
    # closing the inner loop changes the outer margin
    pm_open = ct.stability_margins(ct.minreal(Cw * Ci * Pw, verbose=False))[1]
    assert abs(pm_open - f.pm_deg) > 1.0
    # inner loop broken at its controller output with the outer loop closed: Ci (Pi + Cw Pw)
    L_in = ct.minreal(Ci * (Pi + Cw * Pw), verbose=False)
    _, pm_in, sm_in, _, wgc_in, _ = ct.stability_margins(L_in)
    g = fig(rep, "current")
    assert g.pm_deg == pytest.approx(pm_in, abs=0.05)
    assert g.ms == pytest.approx(dense_ms(L_in), rel=1e-3)  # 5e-4 from the 0.5 us sampling delay at ~1e6 rad/s
    # the plant-input break is the innermost controller output
    assert fig(rep, "plant", "plant_input").pm_deg == pytest.approx(g.pm_deg)
    # closed-loop poles agree with python-control
    cl = ct.feedback(L_in, 1)
    assert rep.stability.stable == bool(np.all(cl.poles().real < 0))
    got = np.array([complex(*p) for p in rep.stability.poles])
    got = np.sort_complex(got[np.abs(got) < 1e5])  # drop the Padé poles of the 0.5 us sampling delay
    want = np.sort_complex(ct.feedback(L_out, 1).poles())
    assert got == pytest.approx(want, rel=1e-3)
    # the angle is not measured: its integrator is reported, not judged
    assert any("not measured" in n for n in rep.notes)


def test_lq_loop_broken_at_plant_input_matches_state_feedback_loop():
    spec = make_spec(
        {"tf": {"num": [1], "den": "(s+1)^3"}},
        [{"type": "lqr"}],
    )
    gains = {"loop0": {"q_x0": 10.0, "q_x1": 1.0, "q_x2": 1.0}}
    rep = run(spec, gains)
    from gaintune.controllers.layout import GainLayout
    from gaintune.controllers.lq import lq_gains
    from gaintune.plants.plant import build_plant

    plant = build_plant(spec.plant)
    lin = plant.linearize()
    lay = GainLayout(spec, plant.states)
    K = lq_gains(spec.loops[0], lay.to_dict(lay.from_dict(gains))["loop0"], lin, 0).K
    L = ct.ss2tf(ct.ss(lin.A, lin.B, K.reshape(1, -1), 0))
    gm, pm, sm, *_ = ct.stability_margins(L)
    f = fig(rep, "plant", "plant_input")
    assert f.pm_deg == pytest.approx(pm, abs=0.05)
    # python-control's sm = 1.38 here misses the infimum |1 + L| -> 1 as w -> inf (Kalman: |1+L| >= 1)
    assert f.ms == pytest.approx(dense_ms(L), rel=1e-4)
    # LQR guarantees: PM >= 60 deg, gain reducible by 6 dB, Ms <= 1 (up to the tiny sampling delay)
    assert f.pm_deg >= 59.9 and f.gm_lower_db >= 6.0 and f.ms <= 1.001
    assert rep.stability.stable


def test_nonlinear_plant_is_linearised_at_operating_point():
    """dx/dt = -x^3 - x + u at x0 = 1 (u0 = 2) linearises to 1/(s+4)."""
    spec = make_spec(
        {"ode": {"states": ["x"], "rhs": {"x": "-x^3 - x + u"}, "outputs": {"y": "x"}, "x0": {"x": 1.0}}},
        [{"type": "pi"}],
    )
    rep = run(spec, {"loop0": {"Kp": 2.0, "Ki": 4.0}})
    ref = run(make_spec({"tf": {"num": [1], "den": [1, 4]}}, [{"type": "pi"}]), {"loop0": {"Kp": 2.0, "Ki": 4.0}})
    assert rep.operating_point["u0"] == pytest.approx(2.0, abs=1e-6)
    assert fig(rep).pm_deg == pytest.approx(fig(ref).pm_deg, abs=1e-6)
    assert fig(rep).ms == pytest.approx(fig(ref).ms, rel=1e-9)
    assert any("linearisation" in n for n in rep.notes)


# ----------------------------------------------------- sampling and Padé


def test_sampling_delay_is_half_the_sample_time():
    base = {"tf": {"num": [1], "den": "(s+1)^3"}}
    g = {"loop0": {"Kp": 1.14, "Ki": 0.454}}
    fine = run(make_spec(base, [{"type": "pi"}]), g)
    coarse = run(make_spec(base, [{"type": "pi"}], scenario={"dt": 0.1, "horizon": 20}), g)
    assert coarse.sampling_delay == pytest.approx(0.05)
    wc = fig(fine).pm_freq
    assert fig(coarse).pm_deg == pytest.approx(fig(fine).pm_deg - math.degrees(wc * 0.05), abs=0.01)
    assert fig(coarse).delay_margin == pytest.approx(fig(fine).delay_margin - 0.05, abs=1e-3)


def test_pade_order_is_checked_for_adequacy():
    plant = {"tf": {"num": [1], "den": [1, 1]}, "delay": 1.0}
    g = {"loop0": {"Kp": 0.5, "Ki": 0.4}}
    good = run(make_spec(plant, [{"type": "pi"}], verify={"pade_order": 8}), g)
    assert good.delay_method == "pade" and good.pade is not None and good.pade.adequate
    exact = run(make_spec(plant, [{"type": "pi"}]), g)
    assert fig(good).pm_deg == pytest.approx(fig(exact).pm_deg, abs=0.01)
    # a first-order Padé of a long delay in a fast loop is not adequate
    bad = run(make_spec(plant, [{"type": "pi"}], verify={"pade_order": 1}), {"loop0": {"Kp": 0.9, "Ki": 0.5}})
    assert bad.pade is not None and not bad.pade.adequate
    assert bad.verdict == "fail" and any("Padé" in r for r in bad.reasons)


# ------------------------------------------------------------- robust


def test_robust_worst_case_not_better_than_nominal():
    spec = make_spec(
        {"tf": {"num": ["K"], "den": "(T*s+1)^3"}, "params": {"K": 1.0, "T": 1.0}, "delay": 0.1},
        [{"type": "pi"}],
        randomize={"params": {"K": [0.7, 1.4], "T": {"dist": "loguniform", "low": 0.8, "high": 1.25}},
                   "delay": [0.05, 0.3]},
        verify={"robust_samples": 6},
    )
    rep = run(spec, {"loop0": {"Kp": 1.0, "Ki": 0.4}})
    assert rep.robust is not None
    assert rep.robust.n_corners == 8 and rep.robust.n_monte_carlo == 6 and rep.robust.n_samples == 14
    for f, w in zip(rep.loops, rep.robust.worst, strict=True):
        assert w.gm_db <= f.gm_db and w.pm_deg <= f.pm_deg and w.delay_margin <= f.delay_margin
        assert w.ms >= f.ms and w.mt >= f.mt and w.disk_alpha <= f.disk_alpha
    # the high-gain, slow, long-delay corner binds GM
    w = rep.robust.worst[0]
    assert w.where["gm_db"] == {"K": 1.4, "T": 1.25, "delay": 0.3}
    assert w.gm_db < fig(rep).gm_db - 1.0
    # same seed, same set
    rep2 = run(spec, {"loop0": {"Kp": 1.0, "Ki": 0.4}})
    assert rep2.robust.worst == rep.robust.worst
    # requirements are checked against the worst case too
    worst_lines = [q for q in rep.requirements if q.case == "worst"]
    assert worst_lines


def test_robust_instability_fails_the_verdict():
    spec = make_spec(
        {"tf": {"num": ["K"], "den": "(s+1)^3"}, "params": {"K": 1.0}},
        [{"type": "p"}],
        randomize={"params": {"K": [0.5, 5.0]}},
        verify={"robust_samples": 0},
        requirements={"gm_min_db": None, "pm_min_deg": None, "ms_max": None},
    )
    rep = run(spec, {"loop0": {"Kp": 2.0}})  # K*Kp = 10 > 8 is unstable
    assert rep.stability.stable
    assert rep.robust.n_unstable == 1
    assert rep.verdict == "fail" and any("robust" in r for r in rep.reasons)


# ------------------------------------------------- verdict and gains


def test_requirement_lines_and_verdict():
    spec = make_spec({"tf": {"num": [1], "den": "(s+1)^3"}}, [{"type": "pi"}],
                     requirements={"gm_min_db": 6, "pm_min_deg": 45, "ms_max": 1.7, "mt_max": 1.3, "dm_min": 0.5})
    ok = run(spec, {"loop0": {"Kp": 1.14, "Ki": 0.454}})
    assert ok.verdict == "pass" and ok.accepted_gains == {"loop0": {"Kp": 1.14, "Ki": 0.454}}
    assert {q.requirement for q in ok.requirements} == {"gm_min_db", "pm_min_deg", "ms_max", "mt_max", "dm_min"}
    pm_line = next(q for q in ok.requirements if q.requirement == "pm_min_deg")
    assert pm_line.margin == pytest.approx(pm_line.value - 45) and pm_line.passed
    bad = run(spec, {"loop0": {"Kp": 3.0, "Ki": 1.5}})
    assert bad.stability.stable and bad.verdict == "fail" and bad.accepted_gains is None
    failing = {q.requirement for q in bad.requirements if not q.passed}
    assert "pm_min_deg" in failing and "ms_max" in failing
    # reasons: binding (largest relative violation) first
    assert bad.reasons[0].startswith("mt_max") and len(bad.reasons) == len(failing)
    text = format_table(bad)
    assert "FAIL" in text and "loop0" in text and "pm_min_deg" in text


def test_gains_as_vectors_and_bad_gains():
    spec = make_spec({"tf": {"num": [1], "den": "(s+1)^3"}},
                     [{"type": "pi", "gains": {"Ki": {"tune": False, "value": 0.454}}}])
    a = run(spec, [1.14, 0.454])  # full vector
    b = run(spec, [1.14])  # tuned only
    c = run(spec, {"loop0": {"Kp": 1.14}})  # fixed gain filled in
    assert a.loops[0].pm_deg == b.loops[0].pm_deg == c.loops[0].pm_deg
    for bad in ([1.0, float("nan")], [1.0, -0.4], [1.0, 2.0, 3.0], [[1.0, 2.0]], "abc",
                {"loop0": {"Kp": float("inf")}}, {"loopX": {"Kp": 1.0}}, {"loop0": {"Kq": 1.0}},
                {"loop0": {"Kp": "1"}}):
        with pytest.raises(GainError):
            run(spec, bad)


def test_report_json_round_trip():
    spec = make_spec({"tf": {"num": [1], "den": [1, 1, 0]}}, [{"type": "p"}])
    rep = run(spec, {"loop0": {"Kp": 1.0}})
    text = rep.model_dump_json()
    data = json.loads(text)  # strict JSON: no bare Infinity/NaN
    assert data["verdict"] in ("pass", "fail")
    assert data["sampling_delay"] == pytest.approx(0.5e-6)
    assert "crossings" in data["loops"][0] and "requirements" in data
    back = VerificationReport.model_validate_json(text)
    assert back.loops[0].pm_deg == pytest.approx(rep.loops[0].pm_deg)


def test_fixed_gain_set_by_the_gains_file_is_verified_and_said_not_silently_swapped():
    # a gains file's value for a `tune: false` gain replaced the spec's without a word in the report
    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}},
                      "loops": [{"type": "pid", "gains": {"Kd": {"value": 0.4, "tune": False}}}],
                      "scenario": {"dt": 0.05, "horizon": 20}})
    given = verify(spec, {"loop0": {"Kp": 1.2, "Ki": 0.5, "Kd": 0.9}})
    assert given.gains["loop0"]["Kd"] == 0.9
    assert any("loop0.Kd = 0.9 was verified, not the spec's fixed value 0.4" in n for n in given.notes), given.notes
    text = format_table(given)
    assert text.splitlines()[1] == "gains: loop0 Kp 1.2, Ki 0.5, Kd 0.9 (ideal: Ti 2.4 s, Td 0.75 s)"
    assert "note: loop0.Kd = 0.9 was verified" in text
    # the figures are those of Kd = 0.9, not 0.4
    spec_value = verify(spec, {"loop0": {"Kp": 1.2, "Ki": 0.5}})
    assert spec_value.gains["loop0"]["Kd"] == 0.4
    assert not any("was verified, not" in n for n in spec_value.notes)
    assert given.loops[0].pm_deg != spec_value.loops[0].pm_deg
