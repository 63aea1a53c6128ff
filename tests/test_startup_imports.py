"""Start-up (issue 13): the light paths stay light. No timings: each test runs a fresh interpreter and
checks which heavy packages the path loaded (``gaintune bench startup`` measures the times)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

#: Loaded only by the search, the report or ODE plants; never by the verification of an LTI loop.
SEARCH_AND_REPORT = ("torch", "stable_baselines3", "gymnasium", "control", "scipy.signal", "scipy.stats", "matplotlib",
                     "jinja2", "cmaes", "casadi", "sympy")
SPEC = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
        "scenario": {"dt": 0.05, "horizon": 20}, "search": {"budget": 3000, "seed": 0}}
GAINS = {"loop0": {"Kp": 1.14, "Ki": 0.454}}


@pytest.fixture(scope="module")
def loaded(fresh_python):
    """``loaded(code, heavy)``: the packages of ``heavy`` in ``sys.modules`` after running ``code``
    in a fresh interpreter."""

    def probe(code: str, heavy: tuple[str, ...]) -> list[str]:
        return fresh_python(f"{code}\nimport sys, json\nprint(json.dumps([m for m in {list(heavy)!r} if m in sys.modules]))")

    return probe


def test_import_verify_loads_no_simulator_search_or_report(loaded) -> None:
    assert loaded("import gaintune.verification", SEARCH_AND_REPORT + ("numba",)) == []


def test_cli_help_loads_no_science_stack(loaded) -> None:
    code = ("from typer.testing import CliRunner\nfrom gaintune.cli import app\n"
            "assert CliRunner().invoke(app, ['--help']).exit_code == 0")
    heavy = SEARCH_AND_REPORT + ("numba", "scipy", "pydantic", "gaintune.spec", "gaintune.verification", "rich.console")
    assert loaded(code, heavy) == []


def test_cli_verify_of_an_lti_loop_loads_neither_search_nor_report(loaded, tmp_path: Path) -> None:
    """``gaintune verify`` simulates (numba) but needs no torch, python-control, matplotlib, casadi or rich."""
    spec = tmp_path / "pi.json"
    spec.write_text(json.dumps(SPEC))
    code = ("from typer.testing import CliRunner\nfrom gaintune.cli import app\n"
            f"res = CliRunner().invoke(app, ['verify', {str(spec)!r}, '--gains', {json.dumps(GAINS)!r}])\n"
            "assert res.exit_code == 0, res.output\nassert 'nonlinear check: ok' in res.output, res.output")
    assert loaded(code, SEARCH_AND_REPORT + ("rich.console", "rich.table")) == []


#: A delayed position/speed cascade: the outer loop's path closes the inner loop around a Padé delay.
CASCADE = {"plant": {"ss": {"A": [[0, 1], [0, -10]], "B": [[0], [10]], "C": [[1, 0], [0, 1]],
                            "outputs": ["pos", "vel"]}, "delay": 0.02},
           "loops": [{"name": "pos", "measure": "pos", "type": "p"}, {"name": "vel", "measure": "vel", "type": "pi"}]}
PI = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}]}


@pytest.mark.parametrize("spec", [PI, CASCADE], ids=["pi", "delayed_cascade"])
def test_classical_rules_load_neither_python_control_nor_scipy_signal(loaded, spec: dict) -> None:
    """Rule candidates (FOTD fits, ultimate gain, closed inner loops) use gaintune.lti.statespace, not python-control (~1 s).

    A PI loop on a lag plant needs no scipy.optimize either (0.14 s with scipy.sparse): its model is
    analytic and the ultimate gain's crossing is refined on grids. The cascade's path is fitted by
    least squares, which does import it."""
    code = ("import gaintune\nfrom gaintune.plants.plant import build_plant\n"
            "from gaintune.classical import rule_candidates\n"
            f"spec = gaintune.load_spec({spec!r})\n"
            "assert 'simc' in rule_candidates(spec, build_plant(spec.plant))")
    optimizer = ("scipy.optimize",) if spec is PI else ()
    assert loaded(code, ("control", "scipy.signal", "matplotlib", *optimizer)) == []


def test_reading_and_exporting_a_result_loads_no_search_stack(loaded) -> None:
    code = "import gaintune.search, gaintune.search.result, gaintune.export"
    assert loaded(code, ("torch", "stable_baselines3", "gymnasium", "numba", "matplotlib", "casadi")) == []


@pytest.mark.parametrize("module", ["gaintune.plants", "gaintune.sim.build", "gaintune.sim.kernel"])
def test_lti_modules_do_not_import_casadi(loaded, module: str) -> None:
    """casadi is imported when an ODE plant is built (symbolic right-hand side, tape), not before."""
    assert loaded(f"import {module}", ("casadi",)) == []


def test_an_ode_plant_still_builds_and_tapes_with_casadi(loaded) -> None:
    code = ("from gaintune.plants.library import load_model\nfrom gaintune.spec import load_spec\n"
            "from gaintune.plants import build_plant\nfrom gaintune.sim.tape import make_tape, OPS\n"
            "p = build_plant(load_spec(load_model('water_tank').example_spec()).plant)\n"
            "t = make_tape(p.f)\nassert p.kind == 'nonlinear' and t.op.size > 0 and len(OPS) > 30\n"
            "assert p.linearize().A.shape[0] >= 1")
    assert loaded(code, ("casadi",)) == ["casadi"]
