"""The phase-margin requirement judges the binding crossover's phase distance from -180 degrees (|PM|).

A crossover with phase lead (+91 degrees) reports PM = -89 degrees, yet it lies 89 degrees away from
-1 either way; the binding crossover is chosen by that same distance. Judging the signed value failed
the velocity loops of the six-joint arm's cascade, stable with sensitivity peaks of 1.01-1.14.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from gaintune.spec import RequirementsSpec
from gaintune.verification.margins import judged_pm
from gaintune.verification.quick import margin_terms
from gaintune.verification.report import LoopFigures
from gaintune.verification.requirements import requirement_lines


def _figures(loop: str, pm: float, ms: float) -> LoopFigures:
    return LoopFigures(loop=loop, break_point="plant_output", gm_db=12.0, gm_upper_db=12.0, gm_lower_db=np.inf,
                       gm_binding="increase", gm_freq=3.0, pm_deg=pm, pm_freq=1.0, delay_margin=4.7, ms=ms,
                       mt=1.0, disk_alpha=1.5, disk_gm_db=10.0, disk_pm_deg=60.0)


def test_crossover_with_phase_lead_is_judged_by_its_phase_distance() -> None:
    from gaintune.spec import load_spec

    spec = load_spec({"plant": {"tf": {"num": [1], "den": [1, 1]}}, "loops": [{"type": "pi"}],
                      "requirements": {"pm_min_deg": 45, "gm_min_db": None, "ms_max": None}})
    lines = requirement_lines(spec, [_figures("w6", -88.9, 1.14)], None)
    (pm,) = [q for q in lines if q.requirement == "pm_min_deg"]
    assert pm.value == pytest.approx(88.9) and pm.passed  # the signed value (-88.9) failed it
    lines = requirement_lines(spec, [_figures("w6", -30.0, 2.5)], None)
    (pm,) = [q for q in lines if q.requirement == "pm_min_deg"]
    assert pm.value == pytest.approx(30.0) and not pm.passed  # 30 degrees from -1 is 30 degrees, either way


def test_search_estimate_grades_the_same_phase_distance_as_the_verdict() -> None:
    req = RequirementsSpec(pm_min_deg=45.0, gm_min_db=None, ms_max=None)
    q = SimpleNamespace(pm_deg=np.array([[-88.9, 50.0, -30.0]]))
    (terms,) = margin_terms(req, q)  # type: ignore[arg-type]
    assert terms[0] == pytest.approx([(45 - 88.9) / 45, (45 - 50) / 45, (45 - 30) / 45])
    assert judged_pm(-88.9) == pytest.approx(88.9)


def test_arm_velocity_breaks_with_phase_lead_do_not_bind_the_mimo_pm_line() -> None:
    from gaintune.envs.problem import GainProblem
    from gaintune.plants.library import load_model
    from gaintune.spec import load_spec
    from gaintune.verification.mimo_sampled_report import sampled_margins

    spec = load_spec(load_model("robot_arm6").example_spec())
    p = GainProblem(spec)
    ev, layout = p.evaluator, p.layout
    _, rep, lines = sampled_margins(ev.spec, ev.plant, layout, layout.full(layout.initial_tuned()), aimed=False)
    breaks = rep.input_breaks + rep.output_breaks
    lead = [f for f in breaks if f.pm_deg < -60]
    assert lead and max(f.ms for f in lead) < 1.2  # robust loops whose crossover has phase lead
    (pm,) = [q for q in lines if q.requirement == "pm_min_deg"]
    assert pm.value == pytest.approx(min(abs(f.pm_deg) for f in breaks))
    assert pm.where.split("/")[0] not in {f.loop for f in lead}
