"""Johansson's quadruple tank: operating points, time constants, static gains and zeros against the paper."""

from __future__ import annotations

import numpy as np
import pytest

from gaintune.classical.blt import _closed_loop_stable
from gaintune.classical.mimo_references import QUADTANK_REFERENCES
from gaintune.plants.expr import to_float
from gaintune.plants.quadtank import (
    MIN_PHASE,
    NON_MIN_PHASE,
    ODE_INPUTS,
    ODE_OUTPUTS,
    ODE_RHS,
    ODE_STATES,
    PAPER_OPERATING_POINTS,
    OperatingPoint,
    levels_point,
    linearise,
    operating_point,
    time_constants,
    transmission_zeros,
)

SETTINGS = [("min_phase", MIN_PHASE), ("non_min_phase", NON_MIN_PHASE)]


@pytest.mark.parametrize("name, p", SETTINGS)
def test_levels_at_the_papers_pump_voltages_are_within_2_mm_of_its_table(name, p):
    """The paper's levels are measured; the model's steady state at v0 is within 0.2 cm of each."""
    paper = PAPER_OPERATING_POINTS[name]
    op = operating_point(p, *paper["v0"])
    assert np.max(np.abs(np.array(op.h) - paper["h0"])) < 0.2


@pytest.mark.parametrize("name, p", SETTINGS)
def test_time_constants_match_the_paper_to_its_rounding(name, p):
    """T_i = A_i/a_i sqrt(2 h_i0/g), printed in whole seconds: within 1 s at the paper's levels and at the model's."""
    paper = PAPER_OPERATING_POINTS[name]
    at_paper_levels = time_constants(p, OperatingPoint(paper["h0"], paper["v0"]))
    at_model_levels = time_constants(p, operating_point(p, *paper["v0"]))
    assert np.max(np.abs(np.array(at_paper_levels) - paper["T"])) < 1.0
    assert np.max(np.abs(np.array(at_model_levels) - paper["T"])) < 1.0


def test_static_gains_of_the_minimum_phase_linearisation_match_the_papers_transfer_matrix():
    """G-(s) = [[2.6/(1+62s), 1.5/((1+23s)(1+62s))], [1.4/((1+30s)(1+90s)), 2.8/(1+90s)]]."""
    paper = PAPER_OPERATING_POINTS["min_phase"]
    G = linearise(MIN_PHASE, operating_point(MIN_PHASE, *paper["v0"]))
    assert G.dcgain() == pytest.approx(np.array([[2.6, 1.5], [1.4, 2.8]]), abs=0.05)
    assert G.shape == (2, 2) and G.inputs == ODE_INPUTS


@pytest.mark.parametrize("name, p, rhp", [("min_phase", MIN_PHASE, 0), ("non_min_phase", NON_MIN_PHASE, 1)])
def test_transmission_zeros_are_where_det_g_vanishes_and_on_the_papers_side(name, p, rhp):
    op = operating_point(p, *PAPER_OPERATING_POINTS[name]["v0"])
    zeros = transmission_zeros(p, op)
    assert np.all(np.abs(zeros.imag) < 1e-12)
    assert int(np.sum(zeros.real > 0)) == rhp
    G = linearise(p, op)
    for z in zeros.real:
        Gz = np.array([[e.response(np.array([z + 0j]))[0] for e in row] for row in G.entries])
        assert abs(np.linalg.det(Gz)) < 1e-9 * np.abs(Gz).max() ** 2


def test_the_zero_crosses_into_the_right_half_plane_when_the_valve_split_sums_below_one():
    """Johansson's condition: minimum phase iff gamma1 + gamma2 > 1."""
    assert MIN_PHASE.gamma1 + MIN_PHASE.gamma2 > 1 > NON_MIN_PHASE.gamma1 + NON_MIN_PHASE.gamma2


@pytest.mark.parametrize("p", [MIN_PHASE, NON_MIN_PHASE])
def test_levels_point_inverts_operating_point(p):
    op = operating_point(p, 3.0, 3.2)
    back = levels_point(p, op.h[0], op.h[1])
    assert back.v == pytest.approx((3.0, 3.2), rel=1e-12)
    assert back.h == pytest.approx(op.h, rel=1e-12)


def test_ode_strings_vanish_at_the_operating_point_and_give_the_outputs():
    """The nonlinear model as OdeSpec expressions: zero derivative at a steady state, y = kc h."""
    op = operating_point(MIN_PHASE, 3.0, 3.0)
    env = MIN_PHASE.values() | dict(zip(ODE_STATES, op.h, strict=True)) | dict(zip(ODE_INPUTS, op.v, strict=True))
    for state in ODE_STATES:
        assert to_float(ODE_RHS[state], env) == pytest.approx(0.0, abs=1e-12)
    assert to_float(ODE_OUTPUTS["y1"], env) == pytest.approx(0.5 * op.h[0])
    moved = env | {"v1": 3.5}
    assert to_float(ODE_RHS["h1"], moved) > 0 and to_float(ODE_RHS["h4"], moved) > 0


def test_bad_operating_points_are_refused():
    with pytest.raises(ValueError, match="pump voltages must be >= 0"):
        operating_point(MIN_PHASE, -1.0, 3.0)
    with pytest.raises(ValueError, match="levels must be > 0"):
        levels_point(MIN_PHASE, 0.0, 10.0)
    with pytest.raises(ValueError, match="negative pump voltage"):
        levels_point(MIN_PHASE, 20.0, 0.5)


def test_the_papers_pi_stabilises_the_minimum_phase_tank_but_not_the_non_minimum_phase_one():
    """Johansson's K = 3.0, Ti = 30 s and K = 2.7, Ti = 40 s on the linearisations at the paper's voltages."""
    row = QUADTANK_REFERENCES[0]
    kc = np.array([g["Kc"] for g in row.loops])
    ti = np.array([g["Ti"] for g in row.loops])
    G_min = linearise(MIN_PHASE, operating_point(MIN_PHASE, 3.0, 3.0))
    G_nmp = linearise(NON_MIN_PHASE, operating_point(NON_MIN_PHASE, 3.15, 3.15))
    assert _closed_loop_stable(G_min, (0, 1), kc, ti)
    assert not _closed_loop_stable(G_nmp, (0, 1), kc, ti)
