"""The steps of verify() (gaintune.verification.steps) on their own, and the pieces they are built from."""

from __future__ import annotations

import time

import numpy as np
import pytest

from gaintune.controllers.layout import GainLayout
from gaintune.errors import SpecError
from gaintune.plants.plant import build_plant
from gaintune.spec import load_spec
from gaintune.verification import quick_margins, verify
from gaintune.verification.core import loop_frequency_responses
from gaintune.verification.gains import fixed_gain_overrides
from gaintune.verification.report import RequirementLine
from gaintune.verification.requirements import failing_reasons, not_applicable
from gaintune.verification.steps import (
    Findings,
    assemble_report,
    closing_notes,
    noise_figures,
    nominal_analysis,
    nonlinear_step,
    prepare,
    requirement_step,
    robust_step,
    stability_findings,
)

#: PID on 1/(s+1)^3 with K and T randomised: every step has something to do (robust set included).
DEMO = {
    "plant": {"tf": {"num": ["K"], "den": "(T*s+1)^3"}, "params": {"K": 1.0, "T": 1.0}},
    "loops": [{"name": "main", "type": "pid"}],
    "scenario": {"dt": 0.01, "horizon": 20},
    "requirements": {"gm_min_db": 6, "pm_min_deg": 45, "ms_max": 2.0},
    "randomize": {"params": {"K": [0.8, 1.2], "T": [0.8, 1.2]}},
}
GAINS = {"main": {"Kp": 2.0, "Ki": 1.0, "Kd": 1.0}}


def _without_time(d: dict) -> dict:
    return {k: v for k, v in d.items() if k != "elapsed_s"}


@pytest.mark.parametrize("sampled", [True, False])
def test_steps_run_one_by_one_give_the_verify_report(sampled):
    spec = load_spec({**DEMO, "verify": {"sampled": sampled}})
    t0 = time.perf_counter()
    setup = prepare(spec, GAINS, None, None, False, None)
    found = Findings(notes=fixed_gain_overrides(setup.spec, setup.layout, setup.full))
    nom = nominal_analysis(setup, found)
    loops, mks = noise_figures(setup, nom, found)
    stab = stability_findings(nom, found)
    rob, worst = robust_step(setup, nom, mks, None, found)
    nl = nonlinear_step(setup, stab, False, found)
    req = requirement_step(setup, loops, worst, stab, rob, found)
    closing_notes(setup, stab, found)
    rep = assemble_report(setup, nom, found, loops=loops, stab=stab, rob=rob, nl=nl, req=req,
                          elapsed_s=time.perf_counter() - t0)
    assert rob is not None and rob.n_corners == 4  # the robust step ran: 2 parameters, 4 corners
    ref = verify(spec, GAINS, nonlinear=False, cache=False)
    assert _without_time(rep.model_dump()) == _without_time(ref.model_dump())


def _line(requirement: str, margin: float, limit: float, *, case: str = "nominal", passed: bool | None = None):
    return RequirementLine(requirement=requirement, figure="x", limit=limit, value=limit + margin, margin=margin,
                           passed=margin >= 0 if passed is None else passed, loop="main",
                           break_point="controller_output", case=case)


def test_failing_reasons_list_the_tightest_requirement_first():
    lines = [_line("gm_min_db", -0.5, 6.0), _line("pm_min_deg", -20.0, 45.0), _line("ms_max", 0.1, 2.0)]
    reasons = failing_reasons(lines)
    # relative margins: pm -20/45 = -0.44 is tighter than gm -0.5/6 = -0.08; ms passes
    assert [r.split(":")[0] for r in reasons] == ["pm_min_deg", "gm_min_db"]


def test_not_applicable_marks_the_lines_read_on_an_unstable_loop():
    lines = [_line("gm_min_db", 1.0, 6.0), _line("gm_min_db", 1.0, 6.0, case="worst")]
    robust_unstable = not_applicable(lines, nominal_stable=True, robust_stable=False)
    assert [(q.applicable, q.passed) for q in robust_unstable] == [(True, True), (False, False)]
    nominal_unstable = not_applicable(lines, nominal_stable=False, robust_stable=True)
    assert [(q.applicable, q.passed) for q in nominal_unstable] == [(False, False), (False, False)]
    assert failing_reasons(nominal_unstable) == []  # the instability is the reason, not the lines


def _unresolved():
    """A spec whose scenario dt is still to be derived from the plant, with its plant and layout."""
    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}]})
    assert spec.scenarios[0].dt is None
    plant = build_plant(spec.plant)
    return spec, plant, GainLayout(spec, plant.states)


def test_quick_margins_on_a_scenario_without_dt_names_the_field():
    """Was a bare TypeError from max() over None; now a SpecError naming scenarios[0].dt and the fix."""
    spec, plant, layout = _unresolved()
    with pytest.raises(SpecError, match=r"scenarios\[0\]\.dt.*resolve_scenarios"):
        quick_margins(spec, plant, layout, np.array([[1.0, 0.5]]))


def test_loop_frequency_responses_on_a_scenario_without_dt_names_the_field():
    spec, plant, layout = _unresolved()
    with pytest.raises(SpecError, match=r"scenarios\[0\]\.dt"):
        loop_frequency_responses(spec, plant, layout, np.array([1.0, 0.5]), np.array([1.0]))


def test_verify_derives_a_missing_dt_instead():
    spec, _, _ = _unresolved()
    rep = verify(spec, {"loop0": {"Kp": 1.0, "Ki": 0.5}}, nonlinear=False)
    assert rep.dt is not None and rep.dt > 0
    assert any("derived from the plant" in n for n in rep.notes)
