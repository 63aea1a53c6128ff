"""Gain schedules: the grid, the interpolation, the file, the closed loop against the simulator, the verification."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gaintune.classical.tuning import tune_classical
from gaintune.errors import SpecError
from gaintune.plants import build_plant
from gaintune.plants.library import load_model
from gaintune.spec import TuningSpec, load_spec
from gaintune.tuners.schedule import (
    SCHEDULE_VERSION,
    GainSchedule,
    ScheduleModel,
    build_schedule,
    compare_fixed,
    fit_midpoints,
    gains_between,
    grid_and_midpoints,
    load_schedule,
    parse_grid,
    spec_at,
    verify_schedule,
)
from gaintune.tuners.schedule.compare import constant_table, level_step

GRID = [2.0, 11.0, 20.0]


def _tank(**changes) -> TuningSpec:
    d = load_model("water_tank").example_spec()
    d.update(changes)
    return load_spec(d)


def _imc(spec: TuningSpec) -> dict:
    return tune_classical(spec, build_plant(spec.plant), "imc").gains


@pytest.fixture(scope="module")
def imc_schedule() -> GainSchedule:
    """The IMC rule at each of 2, 11 and 20 m: far inside every requirement, slow (Ti up to 90 s)."""
    return build_schedule(_tank(), "H0", GRID, _imc, method="imc")


def _with_gains(schedule: GainSchedule, gains: list[dict]) -> GainSchedule:
    return schedule.model_copy(update={"gains": gains})


# ------------------------------------------------------------------------------------------------ grid


def test_parse_grid_start_stop_count_and_comma_list() -> None:
    assert parse_grid("2:20:10") == [2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0, 16.0, 18.0, 20.0]
    assert parse_grid(" 2, 5 ,10 ") == [2.0, 5.0, 10.0]
    assert parse_grid("0.5:1:2") == [0.5, 1.0]


@pytest.mark.parametrize("text", ["", "2:20", "2:20:1", "2:20:x", "20:2:5", "2:inf:5", "a,b", "5,2", "3,3",
                                  "1", "2:20:100000", "nan,1"])
def test_parse_grid_errors_name_grid(text: str) -> None:
    with pytest.raises(SpecError) as exc:
        parse_grid(text)
    assert exc.value.field == "grid"


# ------------------------------------------------------------------------------------------ interpolation


def test_gains_between_exact_at_grid_points_linear_between_clamped_outside(imc_schedule) -> None:
    s = imc_schedule
    kp = s.table("Kp")
    for v, g in zip(s.grid, s.gains, strict=True):
        assert gains_between(s, v)["level"] == g  # exact, not approximately
    for w in (0.25, 0.5, 0.9):
        v = s.grid[0] + w * (s.grid[1] - s.grid[0])
        assert gains_between(s, v)["level"]["Kp"] == pytest.approx(kp[0] + w * (kp[1] - kp[0]), rel=1e-12)
    assert gains_between(s, -5.0)["level"] == s.gains[0]
    assert gains_between(s, 1e6)["level"] == s.gains[-1]
    assert np.interp(7.3, s.grid, kp) == pytest.approx(gains_between(s, 7.3)["level"]["Kp"], rel=1e-12)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), "3", None, True])
def test_gains_between_rejects_a_value_that_is_not_a_finite_number(imc_schedule, value) -> None:
    with pytest.raises(SpecError) as exc:
        gains_between(imc_schedule, value)
    assert exc.value.field == "value"


# ------------------------------------------------------------------------------------------------ file


def test_schedule_json_round_trip(imc_schedule, tmp_path) -> None:
    path = tmp_path / "schedule.json"
    path.write_text(imc_schedule.to_json())
    back = load_schedule(path)
    assert back.model_dump() == imc_schedule.model_dump()
    assert load_schedule(imc_schedule.to_json()).model_dump() == imc_schedule.model_dump()
    assert back.tuning_spec.scenarios[0].dt == imc_schedule.dt == 0.1


@pytest.mark.parametrize("version", [0, 2, "1", None])
def test_schedule_of_another_version_is_refused_naming_version(imc_schedule, version) -> None:
    data = json.loads(imc_schedule.to_json())
    assert data["version"] == SCHEDULE_VERSION
    data["version"] = version
    with pytest.raises(SpecError) as exc:
        load_schedule(data)
    assert exc.value.field == "version"


def test_schedule_file_with_a_bad_field_names_it(imc_schedule) -> None:
    data = json.loads(imc_schedule.to_json())
    data["grid"] = [2.0, 1.0, 20.0]
    with pytest.raises(SpecError) as exc:
        load_schedule(data)
    assert exc.value.field == "grid"
    data = json.loads(imc_schedule.to_json())
    data["gains"] = data["gains"][:2]
    with pytest.raises(SpecError) as exc:
        load_schedule(data)
    assert exc.value.field == "gains"
    for bad in ("{not json", "[1, 2]", "/no/such/schedule.json"):
        with pytest.raises(SpecError) as exc:
            load_schedule(bad)
        assert exc.value.field == "schedule", bad


def test_build_schedule_refuses_what_cannot_be_scheduled() -> None:
    with pytest.raises(SpecError) as exc:
        build_schedule(_tank(), "H1", GRID, _imc)
    assert exc.value.field == "var" and "H0" in exc.value.message
    with pytest.raises(SpecError) as exc:
        build_schedule(_tank(), "H0", [2.0, 2.0], _imc)
    assert exc.value.field == "grid"
    d = _tank().model_dump()
    d["loops"][0].update(form="ideal", gains={})
    with pytest.raises(SpecError) as exc:
        build_schedule(load_spec(d), "H0", GRID, _imc)
    assert exc.value.field == "loops.0.form"
    with pytest.raises(SpecError) as exc:
        build_schedule(_tank(), "H0", GRID, lambda spec: {"level": {"Kp": float("nan"), "Ki": 1.0}})
    assert exc.value.field == "gains"


def test_spec_at_freezes_the_parameter_and_stops_randomising_it() -> None:
    d = _tank().model_dump()
    d["randomize"]["params"]["H0"] = [2.0, 20.0]
    frozen = spec_at(load_spec(d), "H0", 7.5)
    assert build_plant(frozen.plant).params["H0"] == 7.5
    assert "H0" not in frozen.randomize.params and "a" in frozen.randomize.params


# ------------------------------------------------------------------------------------ the closed loop


def test_constant_table_reproduces_the_simulator_on_the_nonlinear_plant(imc_schedule) -> None:
    """The schedule's own closed loop (casadi RK4, the exported law) is the simulator's, sample for sample."""
    from gaintune.sim import Simulator

    model = ScheduleModel(imc_schedule)
    gains = {"Kp": 5.0, "Ki": 0.1}  # saturates the pump at the step: clamping is exercised
    run = level_step(model, constant_table(model.table, gains), 11.0)
    spec = spec_at(imc_schedule.tuning_spec, "H0", 11.0)
    sim = Simulator(spec)
    res = sim.run(sim.layout.from_dict({"level": gains})[None], traces=True)
    assert np.any(res.traces["u"][0] >= 10.0)
    assert np.max(np.abs(res.traces["u"][0] - run.u)) < 1e-9
    assert np.max(np.abs(res.traces["y.level"][0] - run.y)) < 1e-9
    assert run.iae == pytest.approx(float(res.metrics["iae"][0]), rel=1e-9)


def test_scheduled_gains_follow_the_measured_level(imc_schedule) -> None:
    model = ScheduleModel(imc_schedule)
    assert model.table.schedule_on == "measurement"
    run = level_step(model, model.table, 2.0, step=9.0)
    assert run.x.tolist() == run.y.tolist()  # scheduled on the measurement, sample by sample
    assert run.x[0] == 2.0 and run.x.max() > 10.0  # the gains moved from the 2 m entry toward the 11 m one


# ------------------------------------------------------------------------------------------ verification


def test_verify_schedule_three_points_passes_with_the_imc_rule_per_point(imc_schedule) -> None:
    v = verify_schedule(imc_schedule, hold=1000.0)
    assert v.passed, v.reasons
    assert v.count("grid") == (3, 3) and v.count("midpoint") == (2, 2)
    assert v.sweep.ran and not v.sweep.tripped and not v.sweep.diverged
    assert [s.level for s in v.sweep.segments] == [2.0, 11.0, 20.0, 11.0, 2.0]
    assert all(s.settled for s in v.sweep.segments) and all(s.iae > 0 for s in v.sweep.segments[1:])


def test_a_bad_table_entry_fails_at_its_grid_point(imc_schedule) -> None:
    gains = [dict(g) for g in imc_schedule.gains]
    gains[1] = {k: 50 * x for k, x in gains[1].items()}
    v = verify_schedule(_with_gains(imc_schedule, gains), sweep=False)
    bad = {p.value: p.verdict for p in v.points}
    assert bad[11.0] == "fail" and bad[2.0] == bad[20.0] == "pass"
    assert not v.passed and any(r.startswith("H0 = 11 (grid)") for r in v.reasons)


def test_sweep_reports_levels_a_slow_schedule_has_not_settled_at(imc_schedule) -> None:
    v = verify_schedule(imc_schedule)  # the spec's 200 s per level: too short for Ti = 90 s
    assert not v.passed and not v.sweep.passed and not v.sweep.tripped
    assert any("not settled" in r for r in v.reasons)


def test_sweep_reports_a_safety_trip() -> None:
    spec = _tank(safety={"state_bounds": {"h": 15.0}})
    s = build_schedule(spec, "H0", [2.0, 8.0, 14.0, 20.0], _imc)
    v = verify_schedule(s, hold=50.0)
    assert v.sweep.tripped and not v.passed
    assert "tripped" in v.sweep.note


def test_fit_midpoints_scales_the_neighbours_of_a_failing_midpoint() -> None:
    from gaintune.evaluation.search_box import search_box

    def rule_at(spec: TuningSpec) -> dict:  # the best classical rule, scaled until it meets the requirements
        return search_box(spec, build_plant(spec.plant)).centre

    s = build_schedule(_tank(), "H0", GRID, rule_at)
    assert verify_schedule(s, sweep=False).count("midpoint")[0] < 2  # Kp ~ 1/sqrt(H0) is convex
    fitted, notes = fit_midpoints(s)
    assert notes and fitted.fitted is not None and min(fitted.fitted) < 1.0
    v = verify_schedule(fitted, sweep=False)
    assert v.passed, v.reasons


# ------------------------------------------------------------------------------------------ comparison


def test_best_fixed_pi_meets_the_noise_limit_of_every_level(imc_schedule) -> None:
    """The robust spec alone resolves ``mks_max: auto`` at the nominal 10 m; a PI meeting only that failed
    verification at every level above it. The fixed PI is held to each level's own requirements."""
    from gaintune.tuners.schedule import best_fixed_pi
    from gaintune.verification import verify

    fixed = best_fixed_pi(imc_schedule, budget=150 * 5)
    assert fixed.feasible and fixed.levels == [2.0, 6.5, 11.0, 15.5, 20.0]
    for v in fixed.levels:
        rep = verify(spec_at(imc_schedule.tuning_spec, "H0", v), fixed.gains)
        assert rep.verdict == "pass", (v, rep.reasons)


def test_compare_fixed_levels_and_figures(imc_schedule) -> None:
    fixed = imc_schedule.gains[-1]  # the 20 m gains everywhere
    c = compare_fixed(imc_schedule, {"level": fixed})
    assert [(lv.level, lv.kind) for lv in c.levels] == grid_and_midpoints(imc_schedule)
    by = {lv.level: lv for lv in c.levels}
    assert by[20.0].iae_scheduled == pytest.approx(by[20.0].iae_fixed, rel=1e-12)  # same gains there
    assert by[2.0].better and by[2.0].ratio < 1.0


def test_docstring_examples_of_the_schedule_run() -> None:
    import doctest

    import gaintune.tuners.schedule.table as table

    result = doctest.testmod(table, verbose=False)
    assert result.attempted > 0 and result.failed == 0
