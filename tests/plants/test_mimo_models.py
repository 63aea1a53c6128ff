"""The built-in MIMO models: Wood-Berry and Johansson's quadruple tank, against their published figures."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from gaintune.lti.mimo import DelayedSS, TfMatrix
from gaintune.plants import build_plant
from gaintune.plants.checks import validate_against_plant
from gaintune.plants.library import load_model
from gaintune.spec import load_spec

MIMO_MODELS = ("wood_berry", "quadruple_tank_min", "quadruple_tank_nmp")


@pytest.mark.parametrize("name", MIMO_MODELS)
def test_mimo_model_documents_its_signals_and_its_example_is_a_problem(name: str) -> None:
    model = load_model(name)
    plant = build_plant(model.plant)
    assert list(model.inputs) == plant.input_names and list(model.outputs) == plant.outputs
    assert [s.unit for s in plant.inputs] == [d.unit for d in model.inputs.values()]
    assert all(p.unit and p.description for p in model.parameters.values())
    spec = load_spec(model.example_spec())
    built = build_plant(spec.plant)
    validate_against_plant(spec, built)
    assert all(lp.drives in built.input_names for lp in spec.loops)
    assert [sc.reference.loop for sc in spec.scenarios] == [lp.name for lp in spec.loops]


def test_wood_berry_is_the_published_matrix() -> None:
    lti = build_plant(load_model("wood_berry").plant).lti()
    assert isinstance(lti, TfMatrix) and lti.inputs == ("R", "S", "F") and lti.outputs == ("xD", "xB")
    np.testing.assert_allclose(lti.dcgain(), [[12.8, -18.9, 3.8], [6.6, -19.4, 4.9]])
    delays = [[e.delay for e in row] for row in lti.entries]
    np.testing.assert_allclose(delays, [[1, 3, 8.1], [7, 3, 3.4]])
    taus = [[e.den[0] / e.den[1] for e in row] for row in lti.entries]
    np.testing.assert_allclose(taus, [[16.7, 21, 14.9], [10.9, 14.4, 13.2]])


@pytest.mark.parametrize("name, T, zeros", [
    ("quadruple_tank_min", (62, 90, 23, 30), (-0.060, -0.018)),  # Johansson 2000, minimum phase
    ("quadruple_tank_nmp", (63, 91, 39, 56), (-0.056, 0.013)),  # non-minimum phase: a zero in the RHP
])
def test_quadruple_tank_operating_point_matches_the_paper(name: str, T: tuple, zeros: tuple) -> None:
    lti = build_plant(load_model(name).plant).lti()
    assert isinstance(lti, DelayedSS)
    np.testing.assert_allclose(-1 / np.diag(lti.A), T, rtol=0.03)
    M = np.block([[lti.A, lti.B], [-lti.C, lti.D]])
    N = scipy.linalg.block_diag(np.eye(4), np.zeros((2, 2)))
    z = scipy.linalg.eigvals(M, N)
    z = np.sort(z[np.isfinite(z)].real)
    np.testing.assert_allclose(z, np.sort(zeros), atol=2e-3)
