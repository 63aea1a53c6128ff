"""Bugs a fuzzer found in spec loading (tenth session): each raised a bare TypeError/OverflowError (HTTP 500 or
a CLI traceback). Now a ValidationError or SpecError whose message names the field."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from gaintune.errors import SpecError
from gaintune.spec import MAX_BUDGET, MAX_DELAY_STEPS, load_spec

BASE = {"plant": {"tf": {"num": [1], "den": "(s+1)^2"}}, "loops": [{"type": "pi"}], "scenario": {"dt": 0.05, "horizon": 5}}


def _invalid(data, *needles: str) -> str:
    with pytest.raises(ValidationError) as info:
        load_spec(data)
    text = str(info.value)
    for n in needles:
        assert n in text, text
    return text


@pytest.mark.parametrize("requirements", [[1, 2], 5, "x"])
def test_design_shortcut_with_non_mapping_requirements_names_requirements(requirements) -> None:
    _invalid({**BASE, "design": {"phase_margin": 60}, "requirements": requirements}, "requirements")


@pytest.mark.parametrize("key, design", [("pm_min_deg", {"phase_margin": 60}), ("wc_min", {"crossover": 1.0})])
def test_design_shortcut_with_non_number_requirement_names_it(key: str, design: dict) -> None:
    _invalid({**BASE, "design": design, "requirements": {key: [1]}}, f"requirements.{key} must be a number")


def test_design_shortcut_still_takes_a_numeric_string_requirement() -> None:
    spec = load_spec({**BASE, "design": {"phase_margin": 60}, "requirements": {"pm_min_deg": "60"}})
    assert spec.requirements.pm_min_deg == 60


def test_design_crossover_with_non_list_loops_names_loops() -> None:
    _invalid({**BASE, "design": {"crossover": 1.0}, "loops": 5}, "loops")


@pytest.mark.parametrize("where", ["name", "description", "loops.0.name"])
def test_lone_surrogate_in_a_spec_string_names_the_field(where: str) -> None:
    data = {**BASE, "loops": [{"type": "pi"}]}
    if where == "loops.0.name":
        data["loops"] = [{"type": "pi", "name": "a\ud800"}]
    else:
        data[where] = "x\ud800"
    _invalid(data, where, "not valid Unicode")


@pytest.mark.parametrize("seed", [-1, 2**32, 2**70])
def test_seed_outside_numpys_range_names_search_seed(seed: int) -> None:
    _invalid({**BASE, "search": {"seed": seed}}, "search.seed")
    assert load_spec({**BASE, "search": {"seed": 2**32 - 1}}).search.seed == 2**32 - 1


@pytest.mark.parametrize("data, where", [
    ({**BASE, "plant": {**BASE["plant"], "delay": 1e300}}, "plant.delay"),
    ({**BASE, "plant": {**BASE["plant"], "delay": 0.05 * MAX_DELAY_STEPS * 1.01}}, "plant.delay"),
    ({**BASE, "plant": {**BASE["plant"], "delay": "1e300"}}, "plant.delay"),
    ({**BASE, "randomize": {"delay": [0.0, 1e6]}}, "randomize.delay"),
])
def test_delay_of_more_samples_than_the_limit_names_the_delay(data: dict, where: str) -> None:
    """The delay buffer holds delay/dt samples per simulated lane: 1e300 s overflowed, 1e7 s took ~5 GB."""
    _invalid(data, where, f"over the limit of {MAX_DELAY_STEPS}")
    at_limit = 0.05 * MAX_DELAY_STEPS
    assert load_spec({**BASE, "plant": {**BASE["plant"], "delay": at_limit}}).plant.delay == at_limit


def test_non_utf8_spec_file_is_a_spec_error(tmp_path) -> None:
    p = tmp_path / "latin1.yaml"
    p.write_bytes("name: caf\xe9\n".encode("latin-1"))
    with pytest.raises(SpecError, match="not UTF-8"):
        load_spec(p)


@pytest.mark.parametrize("source", [None, 123, b"plant: {}"])
def test_load_spec_of_a_wrong_type_is_a_spec_error(source) -> None:
    with pytest.raises(SpecError, match="expected a file path, a YAML/JSON string or a dict"):
        load_spec(source)


def test_deeply_nested_yaml_string_is_a_spec_error() -> None:
    with pytest.raises(SpecError, match="nested too deeply"):
        load_spec("a: " + "[" * 100_000 + "]" * 100_000 + "\n")


@pytest.mark.parametrize("weight", ["b", "c"])
def test_infinite_setpoint_weight_from_yaml_names_the_weight(weight: str) -> None:
    """YAML's .inf passed ``ge=0``; the verification then met inf * 0 = NaN (a NaN Nyquist count)."""
    _invalid(f"plant: {{tf: {{num: [1], den: [1, 1]}}}}\nloops: [{{type: pid, {weight}: .inf}}]\n",
             f"loops.0.{weight}", "finite number")


@pytest.mark.parametrize("field", ["outputs", "states"])
def test_duplicate_state_space_names_are_rejected_not_merged(field: str) -> None:
    """Two states or outputs of one name were accepted and merged in the report."""
    ss = {"A": [[-1, 0], [0, -2]], "B": [[1], [1]], "C": [[1, 0], [0, 1]], field: ["a", "a"]}
    _invalid({**BASE, "plant": {"ss": ss}}, f"plant.ss.{field}", "must be unique")


def test_budget_beyond_max_budget_is_refused_not_trained_for_ever() -> None:
    # search.budget 1e23 was accepted: the search trained until killed, and SAC/TD3/DDPG sized their
    # replay buffer from it (numpy asked for terabytes and raised a MemoryError traceback)
    _invalid({**BASE, "search": {"budget": 10**23}}, "search.budget", "less than or equal to")
    assert load_spec({**BASE, "search": {"budget": MAX_BUDGET}}).search.budget == MAX_BUDGET


@pytest.mark.parametrize("design, needle", [({"phase_margin": 200}, "design.phase_margin"),
                                            ({"phase_margin": "abc"}, "design.phase_margin"),
                                            ({"focus": "fast"}, "design.focus"), (5, "design")])
def test_invalid_design_shortcut_error_names_design_field_not_top_level(design, needle: str) -> None:
    # the shortcut's errors were reported at the top level ("phase_margin: ..."), not under design
    text = _invalid({**BASE, "design": design}, needle)
    assert "\nphase_margin" not in text


@pytest.mark.parametrize("randomize, needle", [
    ({"delay": [-1, -0.5]}, "randomize.delay\n  Value error, low must be >= 0 s"),
    ({"delay": {"dist": "normal", "mean": -0.1, "std": 0.1}}, "randomize.delay\n  Value error, mean must be >= 0 s"),
    ({"actuator_scale": [0, 1]}, "randomize.actuator_scale\n  Value error, low must be > 0"),
])
def test_randomised_range_with_no_physical_meaning_is_refused_not_silently_clipped(randomize, needle) -> None:
    # randomize.delay: [-1, -0.5] passed and every draw was clipped to a delay of 0 (actuator scale: 1e-6)
    _invalid({**BASE, "randomize": randomize}, needle)


def test_uniform_distribution_without_low_high_says_what_is_missing() -> None:
    text = _invalid({**BASE, "randomize": {"params": {}, "delay": {"dist": "uniform", "mean": 1, "std": 0.1}}},
                    "needs low and high; low and high missing", "set dist: normal")
    assert "low <= high" not in text


def test_mks_max_of_no_accepted_form_is_one_message_not_union_internals() -> None:
    text = _invalid({**BASE, "requirements": {"mks_max": "zz"}}, "requirements.mks_max", "give a number, 'auto', null")
    assert "literal" not in text and "dict[" not in text
    assert load_spec({**BASE, "requirements": {"mks_max": "12"}}).requirements.mks_max == 12.0


def test_problem_details_drop_pydantics_value_error_prefix() -> None:
    from gaintune.errors import problem_details

    with pytest.raises(ValidationError) as info:
        load_spec({**BASE, "randomize": {"delay": [-1, 0]}})
    assert problem_details(info.value) == [{"loc": "randomize.delay", "msg": "low must be >= 0 s, got -1.0"}]
