"""The nonlinear quadrotor (models/quadrotor_ode.yaml): it linearises about hover exactly to the linearised
model, and its rigid-body terms (thrust rotation, Euler kinematics, gyroscopic coupling) are the textbook ones."""

from __future__ import annotations

import numpy as np

from gaintune.plants import build_plant
from gaintune.spec import PlantSpec


def _plant():
    return build_plant(PlantSpec(model="quadrotor_ode"))


def test_nonlinear_quadrotor_linearises_about_hover_to_the_linearised_model() -> None:
    nl, lin = _plant(), build_plant(PlantSpec(model="quadrotor")).lti()
    got = nl.lti()
    assert nl.input_names == ["T", "tau_x", "tau_y", "tau_z"] and tuple(nl.outputs) == tuple(lin.outputs)
    for name in ("A", "B", "C"):
        np.testing.assert_allclose(getattr(got, name), getattr(lin, name), atol=1e-12, err_msg=name)
    x0, u0, y0 = nl.operating_point()
    np.testing.assert_allclose(u0, [9.81, 0.0, 0.0, 0.0])  # hover: the thrust carries the weight
    np.testing.assert_allclose(x0, 0.0)


def test_nonlinear_quadrotor_right_hand_side_matches_hand_derived_values_at_a_tilted_spinning_state() -> None:
    plant = _plant()
    pv = plant.param_vector()

    def rhs(x, u):
        return np.asarray(plant.ode.f(x, u, pv)).ravel()

    ph, th, ps, p, q, r = 0.3, -0.2, 0.7, 0.5, -1.0, 2.0
    m, g, c, Ixx, Iyy, Izz = 1.0, 9.81, 0.1, 0.01, 0.01, 0.02
    x = np.array([1.0, 2.0, 3.0, 0.4, -0.3, 0.2, ph, th, ps, p, q, r])
    u = np.array([12.0, 0.01, -0.02, 0.003])
    dx = rhs(x, u)
    T = u[0] / m
    want = [0.4, -0.3, 0.2,
            T * (np.cos(ph) * np.sin(th) * np.cos(ps) - np.sin(ph) * np.sin(ps)) - c * 0.4,
            T * (np.cos(ph) * np.sin(th) * np.sin(ps) + np.sin(ph) * np.cos(ps)) + c * 0.3,
            T * np.cos(ph) * np.cos(th) - g - c * 0.2,
            p - np.tan(th) * (r * np.cos(ph) - q * np.sin(ph)),
            q * np.cos(ph) + r * np.sin(ph),
            (r * np.cos(ph) - q * np.sin(ph)) / np.cos(th),
            ((Izz - Iyy) * q * r + u[1]) / Ixx, ((Ixx - Izz) * p * r + u[2]) / Iyy, ((Iyy - Ixx) * p * q + u[3]) / Izz]
    np.testing.assert_allclose(dx, want, rtol=1e-12, atol=1e-12)
    # a positive pitch tilts the thrust toward +x and a positive roll toward +y, as in the linearised model
    level = np.zeros(12)
    assert rhs(level + np.eye(12)[7] * 0.1, np.array([9.81, 0, 0, 0]))[3] > 0
    assert rhs(level + np.eye(12)[6] * 0.1, np.array([9.81, 0, 0, 0]))[4] > 0
