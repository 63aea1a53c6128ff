"""MIMO loop set-up and closed-loop stability (Padé eigenvalues against the generalised Nyquist count)."""

from __future__ import annotations

import control
import numpy as np
import pytest
from mimo_fixtures import PAIRS, blt_loops, entry, satellite, static_controller, wood_berry

from gaintune.lti.mimo import DelayedSS, TfMatrix
from gaintune.verification.mimo_loop import LoopPair, MimoLoop, PidLoop, decentralised_pid, pid_entry, response
from gaintune.verification.mimo_stability import mimo_stability


def _loop(plant, loops):
    return MimoLoop.build(plant, decentralised_pid(plant, loops), loops)


def test_pid_entry_is_the_filtered_pid_law():
    s = np.array([0.3j, 2.0 + 1j, 7j])
    e = pid_entry(2.0, 0.5, 0.3, 0.05)
    assert np.allclose(e.response(s), 2.0 + 0.5 / s + 0.3 * s / (0.05 * s + 1))
    assert np.allclose(pid_entry(1.5, 0.2).response(s), 1.5 + 0.2 / s)
    assert np.allclose(pid_entry(1.5, 0.0, 0.4, 0.1).response(s), 1.5 + 0.4 * s / (0.1 * s + 1))
    assert np.allclose(pid_entry(3.0).response(s), 3.0)


def test_decentralised_pid_places_each_law_from_its_output_to_its_input():
    K = decentralised_pid(wood_berry(), blt_loops())
    assert K.shape == (2, 2) and K.inputs == ("xD", "xB") and K.outputs == ("reflux", "steam")
    s = np.array([0.1j])
    Kj = response(K, s)[0]
    assert np.isclose(Kj[0, 0], 0.375 + 0.375 / 8.29 / s[0]) and Kj[0, 1] == 0 and Kj[1, 0] == 0


def test_response_of_a_state_space_plant_matches_its_freqresp():
    P = DelayedSS(np.array([[-1.0, 2.0], [0.0, -3.0]]), np.array([[1.0, 0.0], [1.0, 1.0]]), np.eye(2),
                  np.array([[0.0, 0.1], [0.0, 0.0]]), inputs=("a", "b"), outputs=("c", "d"),
                  input_delays=np.array([0.2, 0.0]), output_delays=np.array([0.0, 0.5]))
    w = np.array([0.1, 1.0, 10.0])
    assert np.allclose(response(P, 1j * w), P.freqresp(w))
    K = DelayedSS(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((2, 0)), np.eye(2), inputs=("c", "d"),
                  outputs=("a", "b"))
    lp = MimoLoop.build(P, K, [LoopPair("x", "c", "a"), LoopPair("y", "d", "b")])
    assert np.allclose(lp.channels(1j * w)[0], P.freqresp(w))  # the eigendecomposition path


@pytest.mark.parametrize(("factor", "stable", "rhp"),
                         [(1.0, True, 0), (3.0, True, 0), (4.0, False, 2), (6.0, False, 4)])
def test_wood_berry_blt_stability_counts_agree(factor, stable, rhp):
    st = mimo_stability(_loop(wood_berry(), blt_loops(factor)))
    assert st.stable is stable and st.method == "nyquist"
    assert st.nyquist_rhp == rhp and st.rhp_poles == rhp and st.agree


def test_wood_berry_pade_order_does_not_change_the_count():
    for order in (2, 4, 8, 10):
        st = mimo_stability(_loop(wood_berry(), blt_loops(4.0)), pade_order=order)
        assert (st.rhp_poles, st.nyquist_rhp) == (2, 2), order


def test_delay_free_poles_match_python_control_feedback():
    P = satellite()
    K = [[1.0, -2.0], [0.0, 1.0]]
    st = mimo_stability(MimoLoop.build(P, static_controller(K), PAIRS))
    ref = control.feedback(control.ss(P.A, P.B, P.C, P.D) * control.ss([], [], [], K), np.eye(2)).poles()
    assert st.method == "poles" and st.stable and st.agree
    assert np.allclose(np.sort_complex(st.poles), np.sort_complex(ref))


def test_unstable_satellite_gain_is_found_by_both_counts():
    # u = -k y with k = -0.5 per channel: det(I + G K) has RHP zeros
    st = mimo_stability(MimoLoop.build(satellite(), static_controller(-0.5 * np.eye(2)), PAIRS))
    assert not st.stable and st.rhp_poles == st.nyquist_rhp > 0


def test_static_controller_entry_adds_no_marginal_pole():
    """A P-only entry's canonical realisation carries a dummy state at s = 0: it must not count."""
    plant = TfMatrix(((entry([1], [1, 1]), entry([0.2], [2, 1])), (entry([0.1], [1, 1]), entry([1], [3, 1]))),
                     inputs=("u1", "u2"), outputs=("y1", "y2"))
    loops = [PidLoop("a", "y1", "u1", Kp=2.0), PidLoop("b", "y2", "u2", Kp=1.0)]
    st = mimo_stability(_loop(plant, loops))
    assert st.stable and st.rhp_poles == 0 and st.nyquist_rhp == 0 and st.max_real_pole < 0


def test_unstable_mode_no_loop_sees_fails_the_loop():
    P = DelayedSS(np.diag([-1.0, 0.5]), np.array([[1.0], [1.0]]), np.eye(2), np.zeros((2, 1)),
                  inputs=("u",), outputs=("y", "z"))
    K = DelayedSS(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((1, 0)), np.array([[1.0, 0.0]]),
                  inputs=("y", "z"), outputs=("u",))
    st = mimo_stability(MimoLoop.build(P, K, [LoopPair("only", "y", "u")]))
    assert not st.stable and st.agree and np.allclose(st.hidden_modes, [0.5])
    assert any("not seen by the loop channels" in n for n in st.notes)


def test_marginal_mode_no_loop_sees_is_noted_not_failed():
    P = DelayedSS(np.array([[-1.0, 0.0], [1.0, 0.0]]), np.array([[1.0], [0.0]]), np.eye(2), np.zeros((2, 1)),
                  inputs=("u",), outputs=("speed", "angle"))
    K = DelayedSS(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((1, 0)), np.array([[2.0, 0.0]]),
                  inputs=("speed", "angle"), outputs=("u",))
    st = mimo_stability(MimoLoop.build(P, K, [LoopPair("speed", "speed", "u")]))
    assert st.stable and any("marginal plant mode" in n for n in st.notes)


@pytest.mark.parametrize(("pairing", "match"), [
    ([LoopPair("a", "xD", "reflux"), LoopPair("b", "xD", "steam")], "measured by more than one loop"),
    ([LoopPair("a", "xQ", "reflux")], "output 'xQ' is not a plant output"),
    ([LoopPair("a", "xD", 5)], "input 5 is not a plant input"),
    ([], "at least one loop"),
])
def test_bad_pairing_is_refused_with_its_field(pairing, match):
    K = decentralised_pid(wood_berry(), blt_loops())
    with pytest.raises(ValueError, match=match):
        MimoLoop.build(wood_berry(), K, pairing)


def test_controller_path_outside_the_pairing_is_refused():
    K = decentralised_pid(wood_berry(), blt_loops())
    with pytest.raises(ValueError, match="no loop of the pairing uses"):
        MimoLoop.build(wood_berry(), K, [LoopPair("top", "xD", "reflux")])


def test_pid_with_derivative_and_no_filter_is_refused():
    with pytest.raises(ValueError, match="Tf > 0"):
        decentralised_pid(wood_berry(), [PidLoop("top", "xD", "reflux", Kp=1.0, Kd=0.5)])
    with pytest.raises(ValueError, match="not finite"):
        pid_entry(float("nan"))


def test_controller_of_the_wrong_shape_is_refused():
    with pytest.raises(ValueError, match=r"shape \(1, 2\)"):
        MimoLoop.build(wood_berry(), TfMatrix(((entry([1], [1]), entry([1], [1])),), inputs=("xD", "xB"),
                                              outputs=("reflux",)), blt_loops())


def test_integrating_plant_modes_are_not_taken_for_hidden_modes():
    """Regression: a rank test scaled by the Padé states (entries ~1e7) flagged the controllable,
    observable integrators of 1/s and 1/s^2 as hidden, and dropped three real closed-loop poles."""
    plant = TfMatrix(((entry([1], [1, 0], 0.1), entry([0.3], [1, 1], 0.2)),
                      (entry([-0.2], [1, 1], 0.1), entry([2], [1, 0, 0], 0.05))), inputs=("a", "b"), outputs=("x", "y"))
    for factor, rhp in ((1.0, 0), (10.0, 4)):
        loops = [PidLoop("l1", "x", "a", Kp=factor, Ki=0.1 * factor),
                 PidLoop("l2", "y", "b", Kp=factor, Ki=0.05 * factor, Kd=1.5 * factor, Tf=0.05)]
        st = mimo_stability(_loop(plant, loops))
        assert st.hidden_modes.size == 0 and not st.notes
        assert st.rhp_poles == st.nyquist_rhp == rhp
        n_plant = MimoLoop.build(plant, decentralised_pid(plant, loops), loops).realisations(6)[0][0].shape[0]
        assert st.poles.size == n_plant + 3  # controller states: PI 1, PID 2


def _random_loop(rng: np.random.Generator):
    """A random 2 x 2 or 3 x 3 loop: first/second-order entries (some unstable or integrating), delays
    up to 1.5 s, decentralised PI(D) gains."""
    n = int(rng.integers(2, 4))
    rows = []
    for i in range(n):
        row = []
        for j in range(n):
            k = rng.uniform(0.5, 2) * (1 if i == j else rng.uniform(-0.6, 0.6))
            tau = rng.uniform(0.2, 5)
            den = np.poly1d([tau, 1]) ** int(rng.choice([1, 1, 1, 2]))
            r = rng.random()
            den = np.poly1d([tau, -1]) if r < 0.1 else (np.poly1d([1, 0]) * np.poly1d([tau, 1]) if r < 0.2 else den)
            row.append(entry([k], list(den.coeffs), rng.uniform(0, 1.5)))
        rows.append(tuple(row))
    plant = TfMatrix(tuple(rows), inputs=tuple(f"u{i}" for i in range(n)), outputs=tuple(f"y{i}" for i in range(n)))
    loops = [PidLoop(f"l{i}", f"y{i}", f"u{i}", Kp=rng.uniform(0.05, 1.0), Ki=rng.uniform(0, 0.4),
                     Kd=rng.uniform(0, 1) if rng.random() < 0.3 else 0.0, Tf=0.1) for i in range(n)]
    return plant, loops


def test_random_loops_pade_eigenvalues_and_exact_nyquist_count_agree():
    """24 random loops (about half unstable): the verdicts always agree; the counts may differ only on
    unstable loops, where the order-6 Padé approximant misplaces roots that the delays create."""
    rng = np.random.default_rng(2)
    verdicts, same = [], 0
    for _ in range(24):
        st = mimo_stability(_loop(*_random_loop(rng)))
        assert (st.rhp_poles > 0) == (st.nyquist_rhp > 0), (st.rhp_poles, st.nyquist_rhp, st.notes)
        same += st.agree
        verdicts.append(st.stable)
    assert 4 <= sum(verdicts) <= 20  # both kinds are exercised
    assert same >= 21
