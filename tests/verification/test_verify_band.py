"""The analysis band (10 x Nyquist) and the proven tail above it (gaintune.verification.tail).

The band may only stop short of where |L| is negligible when nothing above it can change a
figure or the stability count. These tests check the pieces (Hamiltonian level test, the
delay-free realisations of the cascade) against brute force, and the whole against the
uncapped analysis, including cases built to have a crossing or an encirclement above the
band edge, delays, open-loop unstable plants, integrators and LQ loops.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from plant_fixtures import MOTOR

from gaintune.controllers.layout import GainLayout
from gaintune.plants.plant import build_plant
from gaintune.spec import load_spec as _load_spec
from gaintune.verification import verify
from gaintune.verification.analysis import analyse, analysis_band, sampling_delay
from gaintune.verification.cascade import build_cascade
from gaintune.verification.figures import loop_figures
from gaintune.verification.freqresp import DelayModel
from gaintune.verification.tail import chain_ss, level_clear, series


def load_spec(d: dict):
    """Every spec here is analysed in continuous time (verify.sampled: false): the band and its
    proven tail belong to the continuous analysis (the sampled one ends at pi/dt)."""
    return _load_spec({**d, "verify": {"sampled": False, **d.get("verify", {})}})


FIGS = ("gm_db", "gm_upper_db", "gm_lower_db", "gm_freq", "pm_deg", "pm_freq", "delay_margin", "ms", "mt", "disk_alpha")


def _mag(g, w):
    A, B, C, D = g
    out = np.empty(w.size)
    for i in range(0, w.size, 20000):
        s = 1j * w[i : i + 20000]
        X = np.linalg.solve(s[:, None, None] * np.eye(A.shape[0])[None] - A[None],
                            np.broadcast_to(B, (s.size,) + B.shape))
        out[i : i + 20000] = np.abs((C[None] @ X)[:, 0, 0] + D)
    return out


def _ss_response(g, s):
    A, B, C, D = g
    if A.shape[0] == 0:
        return np.full(s.shape, D, dtype=complex)
    X = np.linalg.solve(s[:, None, None] * np.eye(A.shape[0])[None] - A[None], np.broadcast_to(B, (s.size,) + B.shape))
    return (C[None] @ X)[:, 0, 0] + D


# ------------------------------------------------------------ level test


def test_level_test_against_brute_force():
    """|G(jw)| < gamma for all w >= w_lo, decided exactly, including resonances and feedthrough."""
    rng = np.random.default_rng(3)
    for trial in range(150):
        if trial % 3 == 0:  # lightly damped resonance
            w0, z = 10 ** rng.uniform(0, 4), 10 ** rng.uniform(-3, -1)
            A = np.array([[0.0, 1.0], [-w0**2, -2 * z * w0]])
        else:
            n = int(rng.integers(1, 5))
            A = rng.normal(size=(n, n)) * 10 ** rng.uniform(-1, 3)
        n = A.shape[0]
        g = (A, rng.normal(size=(n, 1)), rng.normal(size=(1, n)) * 10 ** rng.uniform(-2, 3),
             float(rng.normal() * 0.3) if trial % 2 else 0.0)
        w_lo = 10 ** rng.uniform(0, 4)
        sup = _mag(g, np.logspace(np.log10(w_lo), np.log10(w_lo) + 7, 100_000)).max()
        for gamma in (sup * 1.002, sup * 0.998, max(abs(g[3]) * 1.01, 0.5 * sup)):
            assert level_clear(g, gamma, w_lo) == (sup < gamma), (trial, gamma, sup)


def test_level_test_shifted_contour_and_edge_cases():
    # 1/(s+1) on Re s = -0.5: |G| = 1/|0.5 + jw|, sup over w >= 1 is 1/sqrt(1.25)
    g = (np.array([[-1.0]]), np.array([[1.0]]), np.array([[1.0]]), 0.0)
    edge = 1 / math.sqrt(1.25)
    assert level_clear(g, edge * 1.001, 1.0, shift=0.5) and not level_clear(g, edge * 0.999, 1.0, shift=0.5)
    # feedthrough at least gamma: never below it at infinity
    assert not level_clear((g[0], g[1], g[2], 0.7), 0.7, 1.0)
    # undamped mode above w_lo: unbounded
    osc = (np.array([[0.0, 1.0], [-1e4, 0.0]]), np.array([[0.0], [1.0]]), np.array([[1.0, 0.0]]), 0.0)
    assert not level_clear(osc, 1e3, 10.0)
    assert level_clear(osc, 1e-3, 1e3)  # |G| = 1/|1e4 - w^2| < 1e-3 for w >= 1e3... only above 105
    assert not level_clear(osc, 1e-3, 50.0)
    # a pure gain
    assert level_clear((np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), 0.3), 0.5, 1.0)


# ------------------------------------------------- realisations of the cascade


def _three_loop(loops_extra=None):
    loops = [
        {"name": "position", "type": "p", "measure": "th"},
        {"name": "speed", "type": "pid", "measure": "w", "b": 0.7, "c": 0.3},
        {"name": "current", "type": "pi", "measure": "i", "b": 0.5},
    ]
    spec = load_spec({"plant": MOTOR, "loops": loops, "scenario": {"dt": 1e-3, "horizon": 0.5}})
    gains = {"position": {"Kp": 10.0}, "speed": {"Kp": 2.0, "Ki": 40.0, "Kd": 0.01},
             "current": {"Kp": 10.0, "Ki": 1000.0}}
    return spec, gains


def _cascade(spec, gains):
    plant = build_plant(spec.plant)
    lay = GainLayout(spec, plant.states)
    lin = plant.linearize()
    return build_cascade(spec, lay, lay.from_dict(gains)[None, :], lin), lin


def test_chain_realisations_reproduce_every_break_point():
    """L_i = -d G_i Phi_{i+1} / (1 - d Gin_{i+1}) and L_u = -d G_u with d = e^{-sT}: the
    delay-free realisations used for the tail bound give the cascade's loops exactly."""
    spec, gains = _three_loop()
    cas, lin = _cascade(spec, gains)
    T = 0.0123
    w = np.logspace(-2, 5, 300)
    s = 1j * w
    d = np.exp(-s * T)
    L = cas.loop_responses(s, lin, d)[:, 0, :]
    n = len(cas.loops)
    g_u = _ss_response(chain_ss(cas, lin, 0, n - 1, "u"), s)
    np.testing.assert_allclose(L[n], -d * g_u, rtol=1e-9, atol=1e-12)
    for i in range(n - 1):
        gi = _ss_response(chain_ss(cas, lin, 0, i, "u"), s)
        phi = _ss_response(chain_ss(cas, lin, i + 1, n - 1, "r"), s)
        gin = _ss_response(chain_ss(cas, lin, i + 1, n - 1, "u"), s)
        np.testing.assert_allclose(L[i], -d * gi * phi / (1 - d * gin), rtol=1e-8, atol=1e-12)
        prod = _ss_response(series(chain_ss(cas, lin, 0, i, "u"), chain_ss(cas, lin, i + 1, n - 1, "r")), s)
        np.testing.assert_allclose(prod, gi * phi, rtol=1e-9, atol=1e-12)


def test_chain_realisation_of_lq_loop():
    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "lqi"}],
                      "scenario": {"dt": 0.01, "horizon": 5}})
    plant = build_plant(spec.plant)
    lay = GainLayout(spec, plant.states)
    cas, lin = _cascade(spec, lay.to_dict(lay.full(lay.initial_tuned())))
    w = np.logspace(-2, 4, 200)
    s = 1j * w
    L = cas.loop_responses(s, lin, np.ones(s.size))[:, 0, :]
    np.testing.assert_allclose(L[-1], -_ss_response(chain_ss(cas, lin, 0, 0, "u"), s), rtol=1e-9, atol=1e-12)


# ---------------------------------------------------- capped = uncapped


def _both(spec, gains):
    """(capped analysis as verify runs it, uncapped analysis) of the nominal loop."""
    cas, lin = _cascade(spec, gains)
    delay = DelayModel(lin.delay + sampling_delay(spec), spec.verify.pade_order)
    return (analyse(cas, lin, delay, spec.verify.n_freq, analysis_band(spec)),
            analyse(cas, lin, delay, spec.verify.n_freq))


def _assert_same(capped, full, rel=1e-6):
    assert capped.stability.stable == full.stability.stable
    assert capped.stability.rhp_count == full.stability.rhp_count
    assert capped.stability.nyquist_rhp == full.stability.nyquist_rhp
    for a, b in zip(capped.figures, full.figures, strict=True):
        for k in FIGS:
            x, y = getattr(a, k), getattr(b, k)
            if x is None or y is None or math.isinf(x) or math.isinf(y):
                assert x == y, (a.loop, a.break_point, k, x, y)
            else:
                assert x == pytest.approx(y, rel=rel, abs=1e-12), (a.loop, a.break_point, k)
        # crossings: nothing above the band; the same gain crossings; and every crossing the
        # uncapped report lists inside the band is listed too (fewer competitors in the band)
        top = capped.omega_range[1]
        ra, rb = loop_figures(a), loop_figures(b)
        assert all(c.omega <= top for c in ra.crossings)
        ga, gb = [c for c in ra.crossings if c.kind == "gain"], [c for c in rb.crossings if c.kind == "gain"]
        assert [c.omega for c in ga] == pytest.approx([c.omega for c in gb], rel=1e-6)
        for e in rb.crossings:
            if e.omega <= top * (1 - 1e-9):
                m = [c for c in ra.crossings if c.kind == e.kind and c.omega == pytest.approx(e.omega, rel=1e-6)]
                assert len(m) == 1 and m[0].value == pytest.approx(e.value, rel=1e-6, abs=1e-9), (e.omega, e.value)
                assert m[0].binding == e.binding


API_CASCADE = {
    "plant": {"ss": {"A": [[-100.0, -50.0], [50.0, -0.1]], "B": [[100.0], [0.0]], "C": [[1.0, 0.0], [0.0, 1.0]],
                     "states": ["i", "w"], "outputs": ["i", "w"]}},
    "loops": [{"name": "speed", "type": "pi", "measure": "w"}, {"name": "current", "type": "pi", "measure": "i"}],
    "scenario": {"dt": 1e-3, "horizon": 0.5},
}


@pytest.mark.parametrize("f", [(1, 1, 1, 1), (0.8, 1.25, 0.8, 1.25), (1.25, 0.8, 1.25, 0.8), (4, 1, 0.3, 3)])
def test_cascade_capped_band_matches_uncapped(f):
    spec = load_spec(API_CASCADE)
    gains = {"speed": {"Kp": 2.0 * f[0], "Ki": 40.0 * f[1]}, "current": {"Kp": 10.0 * f[2], "Ki": 1000.0 * f[3]}}
    capped, full = _both(spec, gains)
    assert capped.omega_range[1] == pytest.approx(10 * math.pi / 1e-3)  # the band did stop at 10 x Nyquist
    assert full.omega_range[1] > 100 * capped.omega_range[1]
    _assert_same(capped, full)


def test_three_loop_cascade_with_weights_and_derivative():
    spec, gains = _three_loop()
    capped, full = _both(spec, gains)
    assert capped.omega_range[1] < full.omega_range[1]
    _assert_same(capped, full)


def _resonant(zeta, dt, typ="pi", w0=6000.0):
    """1/(s+1) times a lightly damped mode at w0 (6000 rad/s: 19 x the Nyquist frequency at dt = 0.01)."""
    return load_spec({"plant": {"tf": {"num": [w0**2], "den": np.polymul([1, 1], [1, 2 * zeta * w0, w0**2]).tolist()}},
                      "loops": [{"type": typ}], "scenario": {"dt": dt, "horizon": 5}})


def test_binding_crossing_above_the_band_widens_it():
    """The resonance gives the binding (smallest) GM above 10 x Nyquist: the band must reach it."""
    spec = _resonant(0.002, 0.01)
    gains = {"loop0": {"Kp": 0.5, "Ki": 0.5}}
    capped, full = _both(spec, gains)
    assert analysis_band(spec) < 6000.0 < capped.omega_range[1]
    _assert_same(capped, full)
    f = capped.figures[0]
    assert 5000 < f.gm_freq < 7000  # the resonance binds, not a delay crossing inside 10 x Nyquist
    rep = verify(spec, gains, nonlinear=False)
    assert rep.loops[0].gm_db == pytest.approx(f.gm_db) and rep.analysis_band[1] > 6000.0


@pytest.mark.parametrize("kp, stable", [(0.5, True), (5.0, False)])
def test_encirclement_above_the_band_is_not_missed(kp, stable):
    """A resonance at 20 x Nyquist where the delay brings the phase to -180 deg (w0 T = 10 pi):
    |L(jw0)| ~ 0.2 kp, so kp = 5 encircles -1 far above the band; the capped analysis must say so."""
    spec = _resonant(0.0002, 0.01, "p", w0=10 * math.pi / 0.005)
    gains = {"loop0": {"Kp": kp}}
    capped, full = _both(spec, gains)
    assert full.stability.stable is stable
    _assert_same(capped, full)
    rep = verify(spec, gains, nonlinear=False)
    assert rep.stability.stable is stable and rep.stability.method == "nyquist"
    if not stable:
        assert rep.verdict == "fail" and rep.analysis_band[1] > 10 * math.pi / 0.005


def test_neutral_loop_falls_back_to_the_old_tail_check():
    """PD on (s+2)/(s+1): |L(j inf)| = Kp + Kd/Tf = 22 >= 1 with a delay: unstable, whatever the band."""
    spec = load_spec({"plant": {"tf": {"num": [1, 2], "den": [1, 1]}}, "loops": [{"type": "pd"}],
                      "scenario": {"dt": 0.01}})
    gains = {"loop0": {"Kp": 2.0, "Kd": 0.5}}
    capped, full = _both(spec, gains)
    _assert_same(capped, full)
    rep = verify(spec, gains, nonlinear=False)
    assert not rep.stability.stable and any("neutral" in n for n in rep.notes)


@pytest.mark.parametrize("k, Ld", [(2.0, 0.2), (5.0, 0.05), (20.0, 0.0)])
def test_integrator_with_delay_capped_hand_derived(k, Ld):
    """k e^{-sLt}/s with Lt = delay + dt/2 at dt = 10 ms: the capped band gives the textbook figures."""
    dt = 0.01
    spec = load_spec({"plant": {"tf": {"num": [1], "den": [1, 0]}, "delay": Ld}, "loops": [{"type": "p"}],
                      "scenario": {"dt": dt, "horizon": 5}})
    rep = verify(spec, {"loop0": {"Kp": k}}, nonlinear=False)
    f = rep.loops[0]
    Lt = Ld + dt / 2
    assert rep.analysis_band[1] == pytest.approx(10 * math.pi / dt)
    assert f.pm_freq == pytest.approx(k, rel=1e-6)
    assert f.pm_deg == pytest.approx(90 - k * Lt * 180 / math.pi, abs=1e-4)
    assert f.delay_margin == pytest.approx(math.pi / (2 * k) - Lt, rel=1e-5)
    assert f.gm_freq == pytest.approx(math.pi / (2 * Lt), rel=1e-5)
    assert f.gm_db == pytest.approx(20 * math.log10(math.pi / (2 * Lt) / k), abs=1e-3)
    # phase crossings at w Lt = pi/2 + 2 pi m, all inside the band listed, none above it
    w_pc = [(math.pi / 2 + 2 * math.pi * m) / Lt for m in range(200)]
    inside = [w for w in w_pc if w <= rep.analysis_band[1]]
    assert len(f.phase_crossovers) + f.crossings_omitted == len(inside)
    assert rep.stability.stable and rep.stability.method == "nyquist"


@pytest.mark.parametrize("T, stable", [(0.1, True), (0.55, True), (0.66, False)])
def test_open_loop_unstable_with_delay_capped(T, stable):
    """1/(s-1) e^{-sT} under P = 2 at dt = 10 ms: the Nyquist count with the proven tail."""
    spec = load_spec({"plant": {"tf": {"num": [1], "den": [1, -1]}, "delay": T}, "loops": [{"type": "p"}],
                      "scenario": {"dt": 0.01, "horizon": 5}})
    gains = {"loop0": {"Kp": 2.0}}
    capped, full = _both(spec, gains)
    assert capped.omega_range[1] < full.omega_range[1]
    _assert_same(capped, full)
    assert capped.stability.stable is stable and capped.stability.method == "nyquist"
    if stable:
        dm = math.pi / 3 / math.sqrt(3) - T - 0.005
        assert capped.figures[0].delay_margin == pytest.approx(dm, rel=1e-4)


def test_lq_loop_capped_matches_uncapped():
    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "lqr"}],
                      "scenario": {"dt": 0.01, "horizon": 5}})
    capped, full = _both(spec, {"loop0": {"q_x0": 10.0, "q_x1": 1.0, "q_x2": 1.0}})
    _assert_same(capped, full)


def test_pade_mode_keeps_the_adequacy_check():
    spec = load_spec({"plant": {"tf": {"num": [1], "den": [1, 1]}, "delay": 1.0}, "loops": [{"type": "pi"}],
                      "scenario": {"dt": 0.01, "horizon": 20}, "verify": {"pade_order": 8}})
    capped, full = _both(spec, {"loop0": {"Kp": 0.5, "Ki": 0.4}})
    _assert_same(capped, full)
    rep = verify(spec, {"loop0": {"Kp": 0.5, "Ki": 0.4}}, nonlinear=False)
    assert rep.pade is not None and rep.pade.adequate


def test_robust_worst_case_same_with_and_without_band(monkeypatch):
    """Every robust sample is analysed on the band too; the worst case is the uncapped one."""
    import gaintune.verification.steps as steps

    spec = load_spec({"plant": {"tf": {"num": ["K"], "den": "T*s+1"}, "params": {"K": 1.0, "T": 1.0}, "delay": 0.1},
                      "loops": [{"type": "pi"}], "scenario": {"dt": 0.01, "horizon": 20},
                      "randomize": {"params": {"K": [0.7, 1.4], "T": [0.8, 1.25]}, "delay": [0.05, 0.3]},
                      "verify": {"robust_samples": 3}})
    gains = {"loop0": {"Kp": 1.0, "Ki": 0.4}}
    rep = verify(spec, gains, nonlinear=False, cache=False)
    assert rep.robust.n_samples == 11 and rep.robust.n_unstable == 0
    assert rep.analysis_band[1] == pytest.approx(10 * math.pi / 0.01)
    monkeypatch.setattr(steps, "analysis_band", lambda spec: math.inf)
    ref = verify(spec, gains, nonlinear=False, cache=False)
    assert ref.analysis_band[1] > rep.analysis_band[1]
    for w, v in zip(rep.robust.worst, ref.robust.worst, strict=True):
        for k in ("gm_db", "pm_deg", "delay_margin", "ms", "mt", "disk_alpha"):
            assert getattr(w, k) == pytest.approx(getattr(v, k), rel=1e-6)
        assert w.where == v.where
    assert rep.verdict == ref.verdict and rep.requirements == pytest.approx(ref.requirements) or [
        (q.requirement, q.passed) for q in rep.requirements] == [(q.requirement, q.passed) for q in ref.requirements]


def test_report_band_round_trips_through_json():
    from gaintune.verification.report import VerificationReport

    rep = verify(load_spec(API_CASCADE), {"speed": {"Kp": 2.0, "Ki": 40.0}, "current": {"Kp": 10.0, "Ki": 1000.0}},
                 nonlinear=False)
    back = VerificationReport.model_validate_json(rep.model_dump_json())
    assert back.analysis_band == pytest.approx(rep.analysis_band)
    # a report written before the field existed still loads
    data = rep.model_dump(mode="json")
    data.pop("analysis_band")
    assert VerificationReport.model_validate(data).analysis_band is None


# ------------------------------------------- argument principle: narrow resonances


def _dense_rhp_count(w0, z, a, T, kp, ki):
    """Brute-force Nyquist count for PI x a w0^2 / ((s + a)(s^2 + 2 z w0 s + w0^2)) e^{-sT}."""
    eps = 1e-7 * min(a, w0, ki / kp)
    w = np.concatenate([[0.0], np.logspace(-9, 8, 400_000), w0 + z * w0 * np.linspace(-2000, 2000, 400_001),
                        np.arange(0.0, min(1e6, 4000 / T), 0.05 / T)])
    w = np.unique(w[w >= 0])
    s = -eps + 1j * w
    L = (kp + ki / s) * a * w0**2 / ((s + a) * (s * s + 2 * z * w0 * s + w0**2)) * np.exp(-s * T)
    ph = np.unwrap(np.angle(1 + L))
    ol = np.array([-a, complex(-z * w0, w0 * math.sqrt(1 - z * z)), complex(-z * w0, -w0 * math.sqrt(1 - z * z)), 0.0])
    c = -eps - ol.real
    d_ol = np.sign(c) * (np.pi / 2 - np.arctan(-ol.imag / np.abs(c)))
    zc = (ol.size * np.pi / 2 - d_ol.sum() - (ph[-1] - ph[0])) / np.pi
    assert abs(zc - round(zc)) < 0.05
    return int(round(zc))


@pytest.mark.parametrize("w0, z, a, dt, Ld, kp, ki", [
    (115.8365, 0.0008504, 0.8998, 0.0002085, 0.0, 0.29473, 0.101598),
    (1802.1366, 0.0007928, 1.21539, 0.0008331, 0.0, 6.12413, 1.365855),
    (726.102, 0.0001433, 4.73013, 0.0269004, 0.32602, 0.48164, 0.343513),
])
def test_nyquist_count_sees_a_narrow_resonance(w0, z, a, dt, Ld, kp, ki):
    """Lightly damped modes whose closed-loop pair is unstable: 1 + L circles the origin within
    a fraction of a log-grid step. The count used to miss it (reported stable); the contour
    is now sampled around every open-loop pole."""
    den = np.polymul([1, a], [1, 2 * z * w0, w0**2]).tolist()
    spec = load_spec({"plant": {"tf": {"num": [a * w0**2], "den": den}, "delay": Ld}, "loops": [{"type": "pi"}],
                      "scenario": {"dt": dt, "horizon": max(1.0, 100 * dt)}})
    rep = verify(spec, {"loop0": {"Kp": kp, "Ki": ki}}, nonlinear=False)
    ref = _dense_rhp_count(w0, z, a, Ld + dt / 2, kp, ki)
    assert ref == 2
    assert rep.stability.nyquist_rhp == ref and not rep.stability.stable and rep.verdict == "fail"
