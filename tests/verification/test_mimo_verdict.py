"""The MIMO verdict of a spec (gaintune.verify on a Wood-Berry spec) and the Evaluator's MIMO violation."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from gaintune.errors import SpecError
from gaintune.evaluation.evaluator import Evaluator
from gaintune.plants.library import load_model
from gaintune.spec import load_spec
from gaintune.verification import coerce_gains, verify


def wood_berry(**requirements):
    data = load_model("wood_berry").example_spec()
    data["requirements"] = {**data["requirements"], **requirements}
    return load_spec(data)


def blt(factor: float = 1.0) -> dict:
    """Luyben's BLT PI on Wood-Berry (Kc 0.375, Ti 8.29; Kc -0.075, Ti 23.6), gains times ``factor``."""
    k1, k2 = 0.375 * factor, -0.075 * factor
    return {"xD": {"Kp": k1, "Ki": k1 / 8.29}, "xB": {"Kp": k2, "Ki": k2 / 23.6}}


def test_wood_berry_blt_passes_its_own_ms_and_disk_margin() -> None:
    rep = verify(wood_berry(mimo_ms_max=2.6, disk_margin_min=0.5), blt(), nonlinear=False)
    assert rep.verdict == "pass", rep.reasons
    m = rep.mimo
    assert m is not None and rep.stability.stable
    assert 2.1 < m.ms < 2.6 and 0.5 < m.disk_input.alpha < 1  # dt/2 of hold delay included
    assert {(f.loop, f.break_point) for f in rep.loops} == {(n, b) for n in ("xD", "xB")
                                                            for b in ("plant_input", "plant_output")}
    assert [q.requirement for q in rep.requirements] == ["mimo_ms_max", "disk_alpha_min"]


def test_wood_berry_verdict_fails_naming_the_requirement_and_where() -> None:
    rep = verify(wood_berry(), blt(), nonlinear=False)  # the example's MIMO Ms <= 2.1: BLT's Ms is above
    assert rep.verdict == "fail"
    assert rep.reasons[0].startswith("mimo_ms_max: ms = ") and rep.reasons[0].endswith("at input")
    spec = wood_berry(mimo_ms_max=3.0, targets={"gm_min_db": {"xD": 20.0}, "disk_margin_min": {"output": 0.3}})
    rep = verify(spec, blt(), nonlinear=False)
    assert rep.verdict == "fail" and len(rep.reasons) == 1
    assert rep.reasons[0].startswith("gm_min_db[xD]: gm_db = ") and rep.reasons[0].endswith("at xD/plant_input")


def test_unstable_wood_berry_loop_fails_with_every_line_not_applicable() -> None:
    rep = verify(wood_berry(), blt(6.0), nonlinear=False)
    assert rep.verdict == "fail" and not rep.stability.stable
    assert rep.reasons[0] == "closed loop unstable (all loops closed)"
    assert all(not q.applicable and not q.passed for q in rep.requirements)


def test_mimo_requirement_target_that_is_not_a_loop_is_refused_naming_the_field() -> None:
    with pytest.raises(SpecError, match="requirements.targets") as exc:
        verify(wood_berry(targets={"gm_min_db": {"nope": 3.0}}), blt(), nonlinear=False)
    assert "nope" in str(exc.value) and "xD" in str(exc.value)
    with pytest.raises(ValidationError, match="wc_min"):
        wood_berry(targets={"wc_min": {"xD": 1.0}})


def test_evaluator_violation_is_zero_exactly_when_verify_passes() -> None:
    spec = wood_berry(mimo_ms_max=2.3, disk_margin_min=0.55, backoff=0)
    ev = Evaluator(spec)
    factors = [0.3, 0.6, 0.9, 1.0, 1.3, 2.0, 3.0, 6.0]
    tuned = np.array([ev.layout.tuned_of(coerce_gains(ev.layout, blt(f))) for f in factors])
    viol = ev.requirement_violation(tuned)
    passed = [verify(spec, blt(f), nonlinear=False).passed for f in factors]
    assert any(passed) and not all(passed)
    assert [bool(v == 0) for v in viol] == passed
    assert np.all(viol[~np.array(passed)] > 0) and viol[-1] >= 10  # unstable: graded from 10 up


def test_quadrotor_verify_with_integrators_on_the_frequency_grid_gives_a_verdict_not_linalgerror():
    """The quadrotor's integrators put plant poles exactly at s = 0, a point of the analysis grid: numpy's
    batched solve raised LinAlgError (Singular matrix) for the whole grid, crashing verify and the search."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "plants"))
    from test_big_models import _quad_gains

    rep = verify(load_spec(load_model("quadrotor").example_spec()), _quad_gains())
    assert rep.verdict in ("pass", "fail") and rep.reasons is not None
