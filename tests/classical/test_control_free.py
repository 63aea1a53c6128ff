"""The classical rules without python-control: gaintune.lti.statespace's helpers against python-control.

python-control stays the reference here: every helper the rule path uses (ss -> tf, tf -> ss,
minreal, transmission zeros, step response, frequency response, series with a Padé delay) is
checked against the python-control operation it replaces, and ``tune_classical`` with those
helpers swapped back for python-control gives the same gains on suite problems.
"""

from __future__ import annotations

import warnings

import control
import numpy as np
import pytest
import scipy.signal

from gaintune.bench.suite import get_suite
from gaintune.classical import fit_fotd, rule_candidates, tune_classical
from gaintune.classical import fotd as F
from gaintune.classical import tuning as TU
from gaintune.classical.fotd import path_poles_zeros, siso_minreal
from gaintune.classical.rules import ultimate_gain
from gaintune.classical.tuning import CLASSICAL_METHODS
from gaintune.lti import pade, statespace
from gaintune.plants import build_plant
from gaintune.spec import load_spec

s = control.tf("s")
RTOL = 1e-12


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def _scrambled(g, seed: int = 0) -> statespace.StateSpace:
    """A non-canonical realisation of the python-control system ``g`` (random similarity transform)."""
    g = control.ss(g)
    T = np.random.default_rng(seed).normal(size=(g.nstates, g.nstates)) + 3 * np.eye(g.nstates)
    Ti = np.linalg.inv(T)
    return statespace.StateSpace(T @ g.A @ Ti, T @ g.B, g.C @ Ti, g.D)


def _dc_motor_speed() -> statespace.StateSpace:
    """Speed cut from the 3-state DC motor (current, speed, position): the position integrator is unobservable."""
    A = np.array([[-100.0, -5.0, 0.0], [50.0, -0.1, 0.0], [0.0, 1.0, 0.0]])
    return statespace.StateSpace(A, [[100.0], [0.0], [0.0]], [[0.0, 1.0, 0.0]], [[0.0]])


#: SISO paths: integrating, 3rd order, zeros (one in the RHP), feedthrough, oscillatory, a MIMO cut.
SYSTEMS = {
    "integrating": _scrambled(1 / (s * (s + 1))),
    "lag3": _scrambled(1 / (s + 1) ** 3, 1),
    "zeros": _scrambled((s + 2) * (1 - 0.5 * s) / ((s + 1) ** 2 * (3 * s + 1) * (0.2 * s + 1)), 2),
    "feedthrough": _scrambled((2 * s + 1) / ((s + 1) * (0.5 * s + 1)) + 0.5, 3),
    "oscillatory": _scrambled(4 / ((s + 1) * (s**2 + 0.4 * s + 4)), 4),
    "mimo_cut": _dc_motor_speed(),
}


def ctl(g: statespace.StateSpace) -> control.StateSpace:
    return control.ss(g.A, g.B, g.C, g.D)


def tf_coeffs(g: control.TransferFunction) -> tuple[np.ndarray, np.ndarray]:
    num, den = control.tfdata(g)
    return (np.atleast_1d(np.squeeze(np.asarray(num[0][0], dtype=float))),
            np.atleast_1d(np.squeeze(np.asarray(den[0][0], dtype=float))))


def assert_same_ss(a: statespace.StateSpace, b) -> None:
    for x, y in zip((a.A, a.B, a.C, a.D), (b.A, b.B, b.C, b.D)):
        assert np.shape(x) == np.shape(y)
        np.testing.assert_allclose(x, y, rtol=RTOL, atol=0)


# ------------------------------------------------------------------ Padé


@pytest.mark.parametrize("order", [1, 2, 3, 6, 10])
@pytest.mark.parametrize("T", [0.02, 0.3, 1.0, 13.0])
def test_pade_matches_python_control(T, order):
    assert pade.pade_monic(T, order) == tuple(control.pade(T, order))
    assert_same_ss(statespace.pade_state_space(T, order), control.ss(control.tf(*control.pade(T, order))))
    ref = control.tf(*control.pade(T, order))
    np.testing.assert_array_equal(tf_coeffs(pade.pade_tf(T, order))[0], tf_coeffs(ref)[0])


@pytest.mark.parametrize("order", [1, 4, 6, 10])
def test_unit_pade_realisation_is_unchanged(order):
    """pade_ss / pade_coeffs (the verification's normalisation) as before: scipy.signal.tf2ss of control.pade(1, n)."""
    num, den = control.pade(1.0, order)
    Ad, Bd, Cd, Dd = scipy.signal.tf2ss(num, den)
    A, B, C, D = pade.pade_ss(2.0, order)
    np.testing.assert_array_equal(A, Ad / 2.0)
    np.testing.assert_array_equal(B, Bd / 2.0)
    np.testing.assert_array_equal(C, Cd)
    assert D == float(Dd[0, 0])
    k = np.arange(order, -1, -1)
    np.testing.assert_array_equal(pade.pade_coeffs(2.0, order)[1], np.asarray(den) * 2.0**k)


# ------------------------------------------------------------------ the StateSpace record


def test_state_space_record():
    g = statespace.StateSpace([], [], [], [[2.5]])
    assert (g.nstates, g.ninputs, g.noutputs) == (0, 1, 1)
    assert g.A.shape == (0, 0) and g.B.shape == (0, 1) and g.C.shape == (1, 0)
    assert complex(g(1j)[0, 0]) == 2.5
    h = SYSTEMS["lag3"]
    assert h(0.5).shape == (1, 1) and h(np.array([0.5, 1.0])).shape == (1, 1, 2)
    with pytest.raises(ValueError):
        h.A[0, 0] = 1.0  # read-only copies
    with pytest.raises(ValueError, match="inconsistent"):
        statespace.StateSpace(np.eye(2), np.ones((3, 1)), np.ones((1, 2)), [[0.0]])
    assert statespace.as_state_space(h) is h
    assert_same_ss(statespace.as_state_space(ctl(h)), h)
    assert_same_ss(statespace.as_state_space(1 / (s + 1)), control.ss(1 / (s + 1)))


# ------------------------------------------------------------------ helpers against python-control


@pytest.mark.parametrize("name", SYSTEMS)
def test_ss_to_tf_and_back(name):
    g = SYSTEMS[name]
    num, den = statespace.ss_to_tf(g)
    rnum, rden = tf_coeffs(control.tf(ctl(g)))
    np.testing.assert_allclose(num, rnum, rtol=RTOL, atol=1e-14)
    np.testing.assert_allclose(den, rden, rtol=RTOL, atol=1e-14)
    assert_same_ss(statespace.tf_to_ss(num, den), control.ss(control.tf(num, den)))


@pytest.mark.parametrize("name", SYSTEMS)
def test_transmission_zeros_and_poles(name):
    g = SYSTEMS[name]
    z, zr = np.sort_complex(g.zeros()), np.sort_complex(np.asarray(control.zeros(ctl(g))))
    np.testing.assert_allclose(z, zr, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(np.sort_complex(g.poles()), np.sort_complex(control.poles(ctl(g))), rtol=1e-12)


@pytest.mark.parametrize("name", SYSTEMS)
def test_step_response(name):
    g = SYSTEMS[name]
    t = np.linspace(0.0, 12.0, 600)
    ref = np.asarray(control.step_response(ctl(g), T=t).outputs, dtype=float).ravel()
    y = statespace.step_response(g, t)
    assert y.shape == (1, t.size)
    np.testing.assert_allclose(y[0], ref, rtol=RTOL, atol=1e-14)


@pytest.mark.parametrize("name", SYSTEMS)
def test_frequency_response(name):
    g = SYSTEMS[name]
    w = np.logspace(-2, 2, 50)
    ref = np.asarray(ctl(g)(1j * w, squeeze=False))
    np.testing.assert_allclose(g.freqresp(1j * w), ref, rtol=RTOL, atol=1e-15)


@pytest.mark.parametrize("name", SYSTEMS)
def test_minreal(name):
    g = SYSTEMS[name]
    num, den = statespace.ss_to_tf(g)
    rnum, rden = tf_coeffs(control.minreal(control.tf(num, den), tol=1e-6, verbose=False))
    mnum, mden = statespace.tf_minreal(num, den, tol=1e-6)
    np.testing.assert_allclose(mnum, rnum, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(mden, rden, rtol=1e-10, atol=1e-12)
    rnum, rden = tf_coeffs(control.minreal(control.tf(num, den), verbose=False))  # default tolerance
    np.testing.assert_allclose(statespace.tf_minreal(num, den)[1], rden, rtol=1e-10, atol=1e-12)


def _siso_minreal_with_control(sys, tol=1e-6):
    """The python-control implementation siso_minreal replaced."""
    g = control.tf(control.ss(sys))
    num, den = tf_coeffs(g)
    scale = max(np.abs(num).max(initial=0.0), 1e-300)
    num = np.where(np.abs(num) < 1e-10 * scale, 0.0, num)
    if np.any(num):
        num = np.trim_zeros(num, "f")
    return control.ss(control.minreal(control.tf(num, den), tol=tol, verbose=False))


@pytest.mark.parametrize("name", SYSTEMS)
def test_siso_minreal_matches_python_control(name):
    g = SYSTEMS[name]
    m = siso_minreal(g)
    assert_same_ss(m, _siso_minreal_with_control(ctl(g)))
    assert_same_ss(siso_minreal(ctl(g)), m)  # python-control input still accepted
    if name == "mimo_cut":
        assert m.nstates == 2  # the unobservable position integrator is gone


def test_series_with_pade_on_a_mimo_cut():
    """One input, two outputs (the cascade's plant) behind a 6th-order Padé delay."""
    g = statespace.StateSpace([[-2.0, 0.0], [1.0, -0.5]], [[2.0], [0.0]], np.eye(2), [[0.0], [0.1]])
    ref = control.series(control.ss(control.tf(*control.pade(0.3, 6))), ctl(g))
    assert_same_ss(statespace.with_input_delay(g, 0.3, 6), ref)
    assert statespace.with_input_delay(g, 0.0, 6) is g
    g1, g2 = SYSTEMS["lag3"], SYSTEMS["zeros"]
    assert_same_ss(statespace.series(g1, g2), control.series(ctl(g1), ctl(g2)))


# ------------------------------------------------------------------ public functions keep accepting python-control


@pytest.mark.parametrize("name", ["integrating", "lag3", "zeros", "mimo_cut"])
def test_fit_fotd_and_ultimate_gain_accept_python_control(name):
    g = SYSTEMS[name]
    for method in ("auto", "step_fit"):
        ours = fit_fotd(g, 0.5, method=method)
        assert fit_fotd(ctl(g), 0.5, method=method) == ours
        # a transfer function is realised differently (control.ss): the least-squares fits agree to their tolerance
        _assert_close(fit_fotd(control.tf(ctl(g)), 0.5, method=method).to_dict(), ours.to_dict(), name, rel=1e-3)
    assert ultimate_gain(ctl(g), 0.5) == ultimate_gain(g, 0.5)
    p, z = path_poles_zeros(ctl(g))
    np.testing.assert_array_equal(p, path_poles_zeros(g)[0])


# ------------------------------------------------------------------ the rules against python-control


def _control_helpers(monkeypatch) -> None:
    """Swap the lti helpers the rule path uses for the python-control operations they replace."""

    def back(c) -> statespace.StateSpace:
        return statespace.StateSpace(c.A, c.B, c.C, c.D)

    def delayed(sys, delay, order):
        if delay <= 0:
            return sys
        return back(control.series(control.ss(control.tf(*control.pade(delay, order))), ctl(sys)))

    monkeypatch.setattr(F, "ss_to_tf", lambda sys: tf_coeffs(control.tf(ctl(sys))))
    monkeypatch.setattr(F, "tf_to_ss", lambda num, den: back(control.ss(control.tf(num, den))))
    monkeypatch.setattr(F, "tf_minreal", lambda num, den, tol=None: tf_coeffs(
        control.minreal(control.tf(num, den), tol=tol, verbose=False)))
    monkeypatch.setattr(F, "step_response", lambda sys, t: np.asarray(
        control.step_response(ctl(sys), T=t).outputs, dtype=float).reshape(1, -1))
    monkeypatch.setattr(TU, "with_input_delay", delayed)
    monkeypatch.setattr(statespace.StateSpace, "zeros", lambda self: np.asarray(control.zeros(ctl(self)), dtype=complex))
    monkeypatch.setattr(statespace.StateSpace, "freqresp", lambda self, x: np.asarray(ctl(self)(x, squeeze=False)))


DELAYED_CASCADE = {
    "plant": {"ss": {"A": [[-2.0, 0.0, 0.0], [1.0, -1.0, 0.0], [0.0, 0.4, -0.4]], "B": [[2.0], [0.0], [0.0]],
                     "C": np.eye(3).tolist(), "outputs": ["a", "b", "c"]}, "delay": 0.1},
    "loops": [{"name": "o", "measure": "c", "type": "pid"}, {"name": "m", "measure": "b", "type": "pi"},
              {"name": "i", "measure": "a", "type": "pid"}],
}
SUITE = {p.name: p.spec for name in ("standard", "cascades") for p in get_suite(name)}
PROBLEMS = {"std_lag3_pid": SUITE["std_lag3_pid"], "std_fastslow_pi": SUITE["std_fastslow_pi"],
            "std_integ_pid": SUITE["std_integ_pid"], "std_nmp05_pi": SUITE["std_nmp05_pi"],
            "std_osc2_pid": SUITE["std_osc2_pid"], "dc_motor_cascade": SUITE["dc_motor_cascade"],
            "delayed_cascade": DELAYED_CASCADE}


def _everything(spec, plant) -> dict:
    out = {}
    for method in CLASSICAL_METHODS:
        try:
            r = tune_classical(spec, plant, method)
        except Exception as exc:  # the same rules must fail, with the same message
            out[method] = f"{type(exc).__name__}: {exc}"
            continue
        out[method] = (r.gains, {k: m.to_dict() for k, m in r.fotd.items()}, r.ultimate)
    return out


def _assert_close(a, b, path: str = "", rel: float = 1e-10) -> None:
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            _assert_close(a[k], b[k], f"{path}/{k}", rel)
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_close(x, y, f"{path}[{i}]", rel)
    elif isinstance(a, float):
        assert a == pytest.approx(b, rel=rel, abs=1e-12 * rel), path
    else:
        assert a == b, path


@pytest.mark.parametrize("name", PROBLEMS)
def test_rules_match_the_python_control_path(name, monkeypatch):
    """Gains, FOTD models and (Ku, Pu) of every rule equal those computed with python-control's operations."""
    spec = load_spec(PROBLEMS[name])
    plant = build_plant(spec.plant)
    ours = _everything(spec, plant)
    with monkeypatch.context() as mp:
        _control_helpers(mp)
        ref = _everything(spec, plant)
    _assert_close(ours, ref, name)
    assert rule_candidates(spec, plant) == {m: v[0] for m, v in ours.items() if not isinstance(v, str)}
