"""MIMO stability with open-loop poles at s = 0 (integrating plants, PI/PID cascades)."""

from __future__ import annotations

import control
import numpy as np
from mimo_fixtures import entry

from gaintune.lti.mimo import TfEntry, TfMatrix
from gaintune.spec import load_spec
from gaintune.verification import verify
from gaintune.verification.mimo_loop import MimoLoop, PidLoop, decentralised_pid
from gaintune.verification.mimo_stability import hidden_modes_in_full, mimo_stability

ZERO = TfEntry(np.array([0.0]), np.array([1.0]))


def test_double_integrators_with_pd_are_stable_as_derived_by_hand() -> None:
    """1/s^2 with Kp + Kd s/(Tf s + 1): Tf s^3 + s^2 + (Kd + Kp Tf) s + Kp, Routh-stable for
    Tf (Kp) < Kd + Kp Tf, i.e. always with Kd > 0: Kp = 1, Kd = 1, Tf = 0.01 is stable; Kd < 0 is not."""
    G = TfMatrix(((entry([1], [1, 0, 0], 0.01), ZERO), (ZERO, entry([2], [1, 0, 0], 0.01))),
                 inputs=("u1", "u2"), outputs=("y1", "y2"))
    for kd, stable in ((1.0, True), (-1.0, False)):
        loops = [PidLoop("a", "y1", "u1", Kp=1, Kd=kd, Tf=0.01), PidLoop("b", "y2", "u2", Kp=1, Kd=kd, Tf=0.01)]
        st = mimo_stability(MimoLoop.build(G, decentralised_pid(G, loops), loops))
        assert st.stable is stable and st.agree, st.notes
    cl = control.feedback(control.tf([1.01, 1], [0.01, 1, 0, 0]), 1).poles()  # Kp = Kd = 1, delay-free
    assert np.all(cl.real < 0)


#: x' = v, v' = g theta, theta' = q, q' = tau / I: the quadrotor's pitch axis (four integrators)
_AXIS = {"ss": {"A": [[0, 1, 0, 0], [0, -0.1, 9.81, 0], [0, 0, 0, 1], [0, 0, 0, 0]],
                "B": [[0], [0], [0], [100.0]], "C": np.eye(4).tolist(),
                "outputs": ["x", "v", "theta", "q"], "inputs": ["tau"]}}
_GAINS = {"x": {"Kp": 1.0}, "v": {"Kp": 0.2, "Ki": 0.05, "Kd": 0.01}, "theta": {"Kp": 6.0},
          "q": {"Kp": 0.1, "Ki": 0.2, "Kd": 0.002}}


def _axis_spec(sampled: bool = True):
    loops = [{"name": "x", "measure": "x", "drives": "loop:v", "type": "p", "direction": "direct"},
             {"name": "v", "measure": "v", "drives": "loop:theta", "type": "pid", "direction": "direct"},
             {"name": "theta", "measure": "theta", "drives": "loop:q", "type": "p", "direction": "direct"},
             {"name": "q", "measure": "q", "drives": "tau", "type": "pid", "direction": "direct"}]
    return load_spec({"plant": _AXIS, "loops": loops, "scenarios": [{"dt": 0.005, "horizon": 8.0}],
                      "verify": {"sampled": sampled}})


def _axis_closed_loop_poles() -> np.ndarray:
    """Poles of the nested closed loops, built with python-control loop by loop (inner first)."""
    s = control.tf("s")

    def pid(g):
        return g["Kp"] + g.get("Ki", 0.0) / s + g.get("Kd", 0.0) * s / (0.1 * g.get("Kd", 0.0) / g["Kp"] * s + 1)

    h = control.feedback(pid(_GAINS["q"]) * 100.0 / s, 1)  # q_ref -> q
    h = control.feedback(pid(_GAINS["theta"]) * h / s, 1)  # theta_ref -> theta
    h = control.feedback(pid(_GAINS["v"]) * h * 9.81 / (s + 0.1), 1)  # v_ref -> v
    return control.feedback(pid(_GAINS["x"]) * h / s, 1).poles()


def test_cascade_with_repeated_controller_integrators_on_an_integrating_plant_is_stable_not_marginal() -> None:
    """The quadrotor's hand gains were judged unstable: its cascades' controller, realised entry by entry,
    repeats each chain's integrators (x -> v -> theta -> q has two PID integrators, so the x and v entries
    each carry a double pole at s = 0); the eigenvector test dropped only some of these unseen Jordan chains,
    and the leftover poles at s = 0 counted as closed-loop poles on the axis (both in the Padé count and
    in the Nyquist count's open-loop P). Hidden modes are now counted in full (minimal part)."""
    assert np.all(_axis_closed_loop_poles().real < 0)  # python-control: the cascade is stable
    rep = verify(_axis_spec(sampled=False), _GAINS, nonlinear=False)
    assert rep.stability.stable, rep.reasons
    assert rep.stability.rhp_count == 0 and rep.stability.nyquist_rhp == 0
    rep = verify(_axis_spec(), _GAINS, nonlinear=False)  # the sampled loop at dt = 5 ms: stable too
    assert rep.sampled and rep.stability.stable and rep.stability.spectral_radius < 1


def test_hidden_integrators_of_an_entrywise_cascade_realisation_are_counted_in_full() -> None:
    """Row [C1 C2, C2] with PI laws C1, C2 realised entry by entry: three states at s = 0 (a double
    pole and a single one), of which the minimal realisation has two; one is hidden."""
    c1 = control.ss(control.tf([1.0, 0.5], [1.0, 0.0]))
    c2 = control.ss(control.tf([2.0, 0.3], [1.0, 0.0]))
    a, b = control.ss(c1 * c2), c2
    A = np.block([[a.A, np.zeros((a.nstates, b.nstates))], [np.zeros((b.nstates, a.nstates)), b.A]])
    B = np.block([[a.B, np.zeros((a.nstates, 1))], [np.zeros((b.nstates, 1)), b.B]])
    C = np.hstack([a.C, b.C])
    hid = hidden_modes_in_full(A, B, C, -1e-6)
    assert hid.size == 1 and abs(hid[0]) < 1e-6


def test_robot_arm_hand_gains_get_a_nyquist_count_that_is_not_negative() -> None:
    """The 18-loop arm (position -> velocity -> current PID on six joints): its controller, realised entry by
    entry, has 36 poles at s = 0 of which 18 are seen. The eigenvector test dropped 24 (a generalised Nyquist
    count of -6, impossible, and the verdict "unstable" though every Padé pole is stable); a Kalman staircase
    on the states, swamped by the realisation's scaling (B ~ 1e-7, C ~ 1e23), dropped 21. The Markov
    parameters' Hankel rank counts 18, and the continuous and the sampled loops are stable."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "plants"))
    from test_big_models import _arm_gains

    from gaintune.plants.library import load_model

    for sampled in (False, True):
        d = load_model("robot_arm6").example_spec()
        d.setdefault("verify", {})["sampled"] = sampled
        rep = verify(load_spec(d), _arm_gains(), nonlinear=False)
        assert rep.stability.stable and rep.stability.rhp_count == 0 and rep.sampled is sampled, rep.stability.notes
        if not sampled:
            assert rep.stability.nyquist_rhp == 0


def test_double_integrators_in_general_coordinates_get_a_consistent_nyquist_count() -> None:
    """Two double integrators y_i = u_i / s^2 (plus an unseen stable lag) in random state coordinates, PD on
    each (0.01 s delay): stable by hand (s^2 + Kd s + Kp per loop). The eigenvalue solver spreads the
    four poles at s = 0 by about 1e-8 to either side, and the contour at Re s = -1e-15 had some of them
    on its left: the open-loop count P and the contour disagreed, giving Nyquist counts of -1, 1 or
    'not computable' beside a Padé count of 0. The contour now runs clear of the spread poles."""
    from gaintune.lti.mimo import DelayedSS

    J = np.zeros((5, 5))
    J[0, 1] = J[2, 3] = 1.0
    J[4, 4] = -1.0
    rng = np.random.default_rng(0)
    for _ in range(5):
        T = rng.normal(size=(5, 5))
        Ti = np.linalg.inv(T)
        B = T @ np.array([[0, 0], [1, 0], [0, 0], [0, 1], [1, 1.0]])
        C = np.array([[1, 0, 0, 0, 0], [0, 0, 1, 0, 0.0]]) @ Ti
        G = DelayedSS(T @ J @ Ti, B, C, np.zeros((2, 2)), inputs=("u1", "u2"), outputs=("y1", "y2"),
                      input_delays=np.array([0.01, 0.01]))
        for kd, stable in ((1.0, True), (-1.0, False)):
            loops = [PidLoop("a", "y1", "u1", Kp=1, Kd=kd, Tf=0.01), PidLoop("b", "y2", "u2", Kp=1, Kd=2 * kd, Tf=0.01)]
            st = mimo_stability(MimoLoop.build(G, decentralised_pid(G, loops), loops))
            assert st.stable is stable and st.agree and st.nyquist_rhp == st.rhp_poles, (st.nyquist_rhp, st.rhp_poles)


def test_ordered_schur_refused_by_lapack_moves_its_threshold_into_a_gap(monkeypatch) -> None:
    """A tune of the nonlinear arm stopped with LinAlgError "Leading eigenvalues do not satisfy sort
    condition": LAPACK refuses an ordered Schur form when an eigenvalue within rounding of the threshold
    crosses it while the form is reordered. The split then retries with a threshold in a gap."""
    import scipy.linalg

    from gaintune.verification import mimo_stability as ms

    rng = np.random.default_rng(3)
    S = rng.normal(size=(5, 5))
    A = S @ np.diag([-2.0, -1.0, -1e-9, 0.5, 1.0]) @ np.linalg.inv(S)
    B, C = rng.normal(size=(5, 2)), rng.normal(size=(2, 5))
    real = scipy.linalg.schur
    calls = []

    def refusing(a, output="real", sort=None):
        calls.append(sort)
        if len(calls) == 1:  # the first threshold, as LAPACK refused it in the arm's tune
            raise np.linalg.LinAlgError("Leading eigenvalues do not satisfy sort condition.")
        return real(a, output=output, sort=sort)

    monkeypatch.setattr(scipy.linalg, "schur", refusing)
    k, (Ar, Br, Cr), (Al, Bl, Cl) = ms._split(A, B, C, False, -1e-6)
    # the same modes as the threshold asked for (Re > -1e-6), from a threshold in the gap that holds it
    assert len(calls) == 2 and k == 3
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(Ar).real), [-1e-9, 0.5, 1.0], atol=1e-8)
    s = 0.7j  # the split is additive: the parts' responses sum to the whole system's
    whole = C @ np.linalg.solve(s * np.eye(5) - A, B)
    parts = Cr @ np.linalg.solve(s * np.eye(3) - Ar, Br) + Cl @ np.linalg.solve(s * np.eye(2) - Al, Bl)
    np.testing.assert_allclose(parts, whole, rtol=1e-9, atol=1e-9)


def test_ordered_schur_of_a_badly_scaled_matrix_is_taken_balanced_or_nothing_is_trimmed(monkeypatch) -> None:
    """A cascade controller realised entry by entry (B ~ 1e-7, C ~ 1e23) stopped a tune of the nonlinear arm
    ("no threshold separates the eigenvalues"). The split then takes the Schur form of A balanced; when
    nothing works it trims nothing, so every mode stays counted."""
    import scipy.linalg

    from gaintune.verification import mimo_stability as ms

    rng = np.random.default_rng(4)
    S = rng.normal(size=(4, 4)) * np.array([1e-6, 1.0, 1e6, 1.0])[:, None]
    A = S @ np.diag([-3.0, -1.0, 0.5, 2.0]) @ np.linalg.inv(S)
    B, C = rng.normal(size=(4, 1)), rng.normal(size=(1, 4))
    real = scipy.linalg.schur

    def refuse_unbalanced(a, output="real", sort=None):
        if a is A:
            raise np.linalg.LinAlgError("Leading eigenvalues do not satisfy sort condition.")
        return real(a, output=output, sort=sort)

    monkeypatch.setattr(scipy.linalg, "schur", refuse_unbalanced)
    k, (Ar, Br, Cr), (Al, Bl, Cl) = ms._split(A, B, C, False, -1e-6)
    assert k == 2
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(Ar).real), [0.5, 2.0], rtol=1e-6)
    s = 0.3 + 1.1j
    whole = C @ np.linalg.solve(s * np.eye(4) - A, B)
    parts = Cr @ np.linalg.solve(s * np.eye(2) - Ar, Br) + Cl @ np.linalg.solve(s * np.eye(2) - Al, Bl)
    np.testing.assert_allclose(parts, whole, rtol=1e-6)

    def refuse(a, output="real", sort=None):
        raise np.linalg.LinAlgError("Leading eigenvalues do not satisfy sort condition.")

    monkeypatch.setattr(scipy.linalg, "schur", refuse)
    k, _, left = ms._split(A, B, C, False, -1e-6)
    assert k == 0 and left[0] is A  # nothing trimmed: the modes stay counted
    assert ms.trim_hidden(A, B, C)[3].size == 0
