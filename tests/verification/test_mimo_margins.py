"""MIMO margins against published figures, hand-derived 2 x 2 cases and python-control."""

from __future__ import annotations

import math

import control
import numpy as np
import pytest
from mimo_fixtures import PAIRS, blt_loops, diagonal_plant, entry, satellite, static_controller, wood_berry
from scipy.optimize import minimize_scalar

from gaintune.lti.mimo import TfMatrix
from gaintune.verification.mimo import judge, mimo_report
from gaintune.verification.mimo_loop import LoopPair, MimoLoop, PidLoop, decentralised_pid
from gaintune.verification.mimo_margins import disk_range, mu_bounds, multiloop_disk


def test_mathworks_diskmargin_example_multiloop_margins():
    """MATLAB's diskmargin doc: satellite with C = [1 -2; 0 1]: loop-at-a-time DM 2 (GM [0, inf], PM 90)
    per channel; multiloop DM 0.3754 (lower) to 0.3762 (upper) at w = 0, GM [0.6839, 1.4621], PM 21.26."""
    rep = mimo_report(satellite(), static_controller([[1.0, -2.0], [0.0, 1.0]]), PAIRS)
    for disk in (rep.disk_input, rep.disk_output):
        assert 0.3754 <= disk.alpha <= 0.3762
        assert disk.freq is not None and disk.freq < 1e-3
        assert disk.gm_low == pytest.approx(0.6839, abs=1e-3) and disk.gm_high == pytest.approx(1.4621, abs=2e-3)
        assert disk.pm_deg == pytest.approx(21.26, abs=0.1)
    for f in rep.output_breaks:
        assert f.disk_alpha == pytest.approx(2.0, rel=1e-3) and math.isinf(f.gm_db)


def test_satellite_identity_controller_multiloop_margin_is_hand_derived():
    """K = I: S = [[s, -a], [a, s]]/(s + 1), so M = S - I/2 is normal and mu = sigma_max:
    mu(w)^2 = (1/4 + (a + w/2)^2)/(1 + w^2). Loop at a time, L_1 = 1/S_11 - 1 = 1/s."""
    a = 10.0
    rep = mimo_report(satellite(a), static_controller(np.eye(2)), PAIRS)
    res = minimize_scalar(lambda w: -(0.25 + (a + w / 2) ** 2) / (1 + w**2), bounds=(0, 1), method="bounded",
                          options={"xatol": 1e-10})
    alpha = 1.0 / math.sqrt(-res.fun)
    assert rep.disk_input.alpha == pytest.approx(alpha, rel=1e-6)
    assert rep.disk_input.freq == pytest.approx(res.x, rel=1e-2)
    assert rep.disk_input.alpha < 0.1  # gain variations of 10 % in both channels can destabilise
    for f in rep.input_breaks:  # L = 1/s: GM inf, PM 90 deg at w = 1, delay margin pi/2
        assert math.isinf(f.gm_db) and f.pm_deg == pytest.approx(90.0, abs=1e-6)
        assert f.delay_margin == pytest.approx(math.pi / 2, rel=1e-6) and f.disk_alpha == pytest.approx(2.0, rel=1e-6)


def test_diagonal_plant_multiloop_equals_loop_at_a_time():
    """Decoupled loops: the multiloop disk margin is the worst loop's disk margin, and each loop's
    margins are those of its SISO loop (python-control)."""
    plant = diagonal_plant()
    loops = [PidLoop("l1", "y1", "u1", Kp=1.14, Ki=0.454), PidLoop("l2", "y2", "u2", Kp=0.3, Ki=0.2)]
    rep = mimo_report(plant, decentralised_pid(plant, loops), loops)
    siso = [control.tf([1], [1, 3, 3, 1]) * control.tf([1.14, 0.454], [1, 0]),
            control.tf([2], np.polymul([1, 0.6, 1], [0.5, 1])) * control.tf([0.3, 0.2], [1, 0])]
    omega = np.logspace(-3, 2, 20001)
    for f, L in zip(rep.input_breaks, siso, strict=True):
        gm, pm, _, _, _, _ = control.stability_margins(L)
        assert f.gm_db == pytest.approx(20 * math.log10(gm), rel=1e-6)
        assert f.pm_deg == pytest.approx(pm, rel=1e-6)
        dm = control.disk_margins(L, omega)[0]
        assert f.disk_alpha == pytest.approx(dm, rel=1e-4)
    assert rep.disk_input.alpha == pytest.approx(min(f.disk_alpha for f in rep.input_breaks), rel=1e-6)
    assert rep.ms == pytest.approx(max(f.ms for f in rep.input_breaks), rel=1e-6)


def test_loop_at_a_time_is_the_loop_with_the_other_loops_closed():
    """Wood-Berry, loop 1 broken: L_1 = c1 (g11 - g12 g21 c2 / (1 + g22 c2)) (hand-derived), whose
    gain crossover is where the reported phase margin sits."""
    plant, loops = wood_berry(), blt_loops()
    rep = mimo_report(plant, decentralised_pid(plant, loops), loops)
    f = rep.input_breaks[0]
    s = 1j * f.pm_freq
    g = plant.freqresp(np.array([f.pm_freq]))[0]
    c1, c2 = 0.375 * (1 + 1 / (8.29 * s)), -0.075 * (1 + 1 / (23.6 * s))
    L1 = c1 * (g[0, 0] - g[0, 1] * g[1, 0] * c2 / (1 + g[1, 1] * c2))
    assert abs(L1) == pytest.approx(1.0, abs=1e-8)
    assert 180 + math.degrees(np.angle(L1)) == pytest.approx(f.pm_deg, abs=1e-6)


def test_wood_berry_blt_figures():
    """Regression figures of the BLT tuning (measured): output-side MIMO Ms 2.0996 (BLT's own figure
    is 2.1), input side 2.419; multiloop disk margin 0.6285 at 0.364 rad/min on both sides."""
    plant, loops = wood_berry(), blt_loops()
    rep = mimo_report(plant, decentralised_pid(plant, loops), loops)
    assert rep.stability.stable and rep.stability.agree
    assert rep.ms_output.value == pytest.approx(2.0996, abs=1e-3) and rep.ms_output.value <= 2.1
    assert rep.ms_input.value == pytest.approx(2.4191, abs=1e-3)
    assert rep.disk_input.alpha == pytest.approx(0.6285, abs=1e-3)
    assert rep.disk_output.alpha == pytest.approx(rep.disk_input.alpha, rel=1e-9)
    assert rep.input_breaks[0].gm_db == pytest.approx(14.296, abs=1e-2)
    assert rep.input_breaks[1].pm_deg == pytest.approx(113.06, abs=1e-1)


def test_sigma_peaks_match_a_dense_python_control_response():
    P = satellite()
    K = [[1.0, -2.0], [0.0, 1.0]]
    rep = mimo_report(P, static_controller(K), PAIRS)
    Lo = control.ss(P.A, P.B, P.C, P.D) * control.ss([], [], [], K)
    S = control.feedback(control.ss([], [], [], np.eye(2)), Lo)
    w = np.logspace(-2, 3, 20001)
    resp = S.frequency_response(w)
    Sj = (resp.magnitude * np.exp(1j * resp.phase)).transpose(2, 0, 1)
    ref = np.linalg.norm(Sj, ord=2, axis=(1, 2)).max()
    assert rep.ms_output.value == pytest.approx(ref, rel=1e-4)
    assert rep.ms_output.value >= ref * (1 - 1e-9)


def test_multiloop_disk_of_one_channel_matches_control_disk_margins_with_skew():
    L = control.tf(25, [1, 10, 10, 10])
    w = np.logspace(-1, 2, 3001)
    S = np.asarray(control.feedback(1, L)(1j * w)).reshape(-1, 1, 1)

    def S_at(ww):
        return np.asarray(control.feedback(1, L)(1j * ww)).reshape(-1, 1, 1)

    for skew in (0.0, 0.5, -1.0):
        ref = control.disk_margins(L, w, skew=skew)
        d = multiloop_disk(S_at, w, S, sigma=skew)
        assert d.alpha == pytest.approx(ref[0], rel=1e-3)
        assert d.gm_db == pytest.approx(ref[1], rel=1e-3)
        assert d.pm_deg == pytest.approx(ref[2], rel=1e-3)


def test_mu_bounds_of_a_3x3_match_brute_force_scaling():
    rng = np.random.default_rng(3)
    M = rng.normal(size=(3, 3)) + 1j * rng.normal(size=(3, 3))
    ub, lb, _ = mu_bounds(M)
    grid = np.linspace(-3, 3, 121)
    brute = min(np.linalg.norm(np.diag(np.exp([0, x, y])) @ M @ np.diag(np.exp([0, -x, -y])), 2)
                for x in grid for y in grid)
    assert ub <= brute * (1 + 1e-9)
    assert lb <= ub * (1 + 1e-12) and lb >= 0.9 * ub  # up to three blocks the bound is exact


def test_mimo_disk_margins_match_slycot_ab13md_where_it_is_installed():
    pytest.importorskip("slycot")
    P = satellite()
    K = [[1.0, -2.0], [0.0, 1.0]]
    w = np.concatenate([[0.0], np.logspace(-2, 3, 501)])
    Lo = control.ss(P.A, P.B, P.C, P.D) * control.ss([], [], [], K)
    ref = control.disk_margins(Lo, w)
    rep = mimo_report(P, static_controller(K), PAIRS)
    assert rep.disk_output.alpha == pytest.approx(ref[0], rel=2e-3)


def test_disk_range_matches_matlab_conventions():
    lo, hi, gm_db, pm = disk_range(0.3754)
    assert (lo, hi) == (pytest.approx(0.6839, abs=1e-4), pytest.approx(1.4621, abs=1e-4))
    assert pm == pytest.approx(21.2607, abs=1e-3) and gm_db == pytest.approx(20 * math.log10(1.4621), abs=1e-3)
    assert disk_range(0.0)[:2] == (1.0, 1.0)
    assert disk_range(2.0)[1] == math.inf


def test_judge_names_loops_inputs_outputs_and_all():
    plant, loops = wood_berry(), blt_loops()
    rep = mimo_report(plant, decentralised_pid(plant, loops), loops)
    lines = judge(rep, {"mimo_ms_max": {"output": 2.1, "all": 2.1}, "gm_min_db": {"all": 3, "top": 12, "steam": 12},
                        "disk_alpha_min": 0.5, "pm_min_deg": {"xB": 100}})
    got = {(q.requirement, q.target): q for q in lines}
    assert got[("mimo_ms_max", "output")].passed and not got[("mimo_ms_max", "all")].passed
    assert got[("mimo_ms_max", "all")].where == "input"
    assert got[("gm_min_db", "top")].passed and not got[("gm_min_db", "steam")].passed
    assert got[("gm_min_db", "steam")].where == "bottom/plant_input"
    assert got[("disk_alpha_min", "all")].passed and got[("pm_min_deg", "xB")].passed


@pytest.mark.parametrize(("req", "match"), [
    ({"ms_maximum": 2.0}, "requirement 'ms_maximum' is unknown"),
    ({"gm_min_db": {"middle": 3.0}}, "target 'middle' is not a loop"),
    ({"mimo_ms_max": {"top": 2.0}}, "takes 'all', 'input' or 'output'"),
    ({"pm_min_deg": float("nan")}, "must be a finite number"),
])
def test_bad_requirement_is_refused_with_its_name(req, match):
    plant, loops = wood_berry(), blt_loops()
    rep = mimo_report(plant, decentralised_pid(plant, loops), loops)
    with pytest.raises(ValueError, match=match):
        judge(rep, req)


def test_unstable_loop_fails_every_requirement_and_has_no_disk_margin():
    plant, loops = wood_berry(), blt_loops(6.0)
    rep = mimo_report(plant, decentralised_pid(plant, loops), loops)
    assert not rep.stability.stable and rep.disk_alpha == 0.0
    assert not any(q.passed for q in judge(rep, {"gm_min_db": -100.0, "mimo_ms_max": 1e9}))


def test_mimo_loop_build_is_reused_by_the_report():
    plant, loops = wood_berry(), blt_loops()
    loop = MimoLoop.build(plant, decentralised_pid(plant, loops), loops)
    assert loop.diagonal_controller() and loop.max_delay() == 7.0


def _dense_sigma_peak(L, w):
    S = control.feedback(control.ss([], [], [], np.eye(2)), L)
    resp = S.frequency_response(w)
    return np.linalg.norm((resp.magnitude * np.exp(1j * resp.phase)).transpose(2, 0, 1), ord=2, axis=(1, 2)).max()


def test_wood_berry_sigma_peaks_match_python_control_on_the_pade_loop():
    """python-control on the Padé-6 realisation (delays approximated, dense grid) against the exact-delay figures."""
    plant, loops = wood_berry(), blt_loops()
    K = decentralised_pid(plant, loops)
    loop = MimoLoop.build(plant, K, loops)
    P, Kr = loop.realisations(6)
    G, Kc = control.ss(*P), control.ss(*Kr)
    w = np.logspace(-3, 1, 8001)
    rep = mimo_report(plant, K, loops)
    assert rep.ms_output.value == pytest.approx(_dense_sigma_peak(G * Kc, w), rel=1e-4)
    assert rep.ms_input.value == pytest.approx(_dense_sigma_peak(Kc * G, w), rel=1e-4)


def test_wood_berry_disk_margins_match_slycot_ab13md_where_it_is_installed():
    pytest.importorskip("slycot")
    plant, loops = wood_berry(), blt_loops()
    K = decentralised_pid(plant, loops)
    P, Kr = MimoLoop.build(plant, K, loops).realisations(6)
    G, Kc = control.ss(*P), control.ss(*Kr)
    w = np.logspace(-3, 1, 4001)
    rep = mimo_report(plant, K, loops)
    assert rep.disk_output.alpha == pytest.approx(control.disk_margins(G * Kc, w)[0], rel=1e-4)
    assert rep.disk_input.alpha == pytest.approx(control.disk_margins(Kc * G, w)[0], rel=1e-4)


def test_cascade_sharing_one_input_breaks_at_the_input_and_at_each_measurement():
    """Position P (1) around speed P (4) on one motor input: u = 4 (1 (r - pos) - speed), so
    K = [4, 4] from (pos, speed) and the plant-input loop is 4/(s(s+1)) + 4/(s+1) = 4/s:
    GM inf, PM 90 deg at 4 rad/s, delay margin pi/8, disk margin 2."""
    plant = TfMatrix(((entry([1], [1, 1, 0]),), (entry([1], [1, 1]),)), inputs=("u",), outputs=("pos", "speed"))
    K = TfMatrix(((entry([4.0], [1]), entry([4.0], [1])),), inputs=("pos", "speed"), outputs=("u",))
    pairing = [LoopPair("position", "pos", "u"), LoopPair("speed", "speed", "u")]
    rep = mimo_report(plant, K, pairing)
    assert rep.stability.stable and rep.stability.agree
    (fi,) = rep.input_breaks
    assert fi.loop == "position+speed" and math.isinf(fi.gm_db)
    assert fi.pm_deg == pytest.approx(90.0, abs=1e-6) and fi.pm_freq == pytest.approx(4.0, rel=1e-8)
    assert fi.delay_margin == pytest.approx(math.pi / 8, rel=1e-8)
    assert rep.disk_input.alpha == pytest.approx(2.0, rel=1e-6)
    assert [f.loop for f in rep.output_breaks] == ["position", "speed"]
    lines = judge(rep, {"pm_min_deg": {"u": 80.0, "speed": 30.0}})
    assert all(q.passed for q in lines) and lines[0].where == "position+speed/plant_input"


def test_given_grid_keeps_positive_frequencies_and_refuses_an_empty_one():
    plant, loops = wood_berry(), blt_loops()
    K = decentralised_pid(plant, loops)
    rep = mimo_report(plant, K, loops, w=np.concatenate([[0.0, -1.0, np.nan], np.logspace(-3, 1, 800)]))
    assert rep.grid_points == 800 and rep.ms_output.value == pytest.approx(2.0996, abs=2e-3)
    with pytest.raises(ValueError, match="at least two finite positive frequencies"):
        mimo_report(plant, K, loops, w=[0.0, -1.0])
