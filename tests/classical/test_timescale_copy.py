"""Scenario defaults fill dt/horizon into a copy of the validated spec, running only the checks that read them:
the resolved spec equals the one a full re-validation gives, field for field and by hash, and a filled
scenario the checks reject raises the full validation's located error."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from gaintune.bench.standard import standard_problems
from gaintune.classical.timescale import _with_scenarios, scenario_defaults
from gaintune.spec import MAX_STEPS, TuningSpec, load_spec
from gaintune.tuners.tuner import Tuner

ROOT = Path(__file__).resolve().parents[2]
#: The spec files of the repository (examples, benchmarks, tuner specs).
FILES = sorted(p for d in ("docs/examples", "bench/horizon", "gaintune/tuners/specs")
               for p in (ROOT / d).rglob("*.yaml"))
#: Inline specs: the README's FOTD, a delay-dominant plant, a design shortcut, a load step after a reference step.
INLINE = [
    {"plant": {"tf": {"num": [2], "den": "60*s + 1"}, "delay": 10}, "loops": [{"type": "pi"}]},
    {"plant": {"tf": {"num": [1], "den": "s + 1"}, "delay": 10}, "loops": [{"type": "pid"}]},
    {"plant": {"tf": {"num": [1], "den": "s*(s + 1)"}}, "loops": [{"type": "pi"}], "design": {"phase_margin": 60}},
    {"plant": {"tf": {"num": [1], "den": "5*s + 1"}, "delay": 0.5}, "loops": [{"type": "pi"}],
     "scenarios": [{"name": "both", "reference": {"kind": "step", "time": 1},
                    "disturbance": {"kind": "step", "time": 40, "amplitude": 0.5}},
                   {"name": "given", "dt": 0.01, "horizon": 30}]},
]


def _specs() -> list[tuple[str, TuningSpec]]:
    out = []
    for p in FILES:
        try:
            out.append((p.relative_to(ROOT).as_posix(), load_spec(p)))
        except Exception:  # a file this environment cannot load (an optional backend): nothing to compare
            continue
    out += [(f"inline{i}", load_spec(d)) for i, d in enumerate(INLINE)]
    for name, spec in standard_problems(lambda name, title, spec, family, **kw: (name, spec)):
        # the standard suite's plants (lag, delay, non-minimum phase, integrating, unstable, oscillatory),
        # their scenarios' dt and horizon left to the plant
        scenarios = [{k: v for k, v in sc.items() if k not in ("dt", "horizon")} for sc in spec["scenarios"]]
        out.append((name, load_spec({**spec, "scenarios": scenarios})))
    tuner = Tuner.load("fotd_pi_ms1.4")
    out += [(f"tuner{i}", tuner.problem.physical_spec(p))
            for i, p in enumerate([{"K": 2.0, "T": 60.0, "L": 10.0}, {"K": 0.3, "T": 1.0, "L": 0.05}])]
    return out


SPECS = _specs()


def test_the_specs_cover_files_inline_and_tuner_specs():
    names = [n for n, _ in SPECS]
    assert len(names) >= 40 and any(n.startswith("docs/examples/") for n in names) and "inline2" in names


@pytest.mark.parametrize(("name", "spec"), SPECS, ids=[n for n, _ in SPECS])
def test_scenario_defaults_without_revalidation_equal_the_fully_validated_spec(name, spec):
    try:
        out, records = scenario_defaults(spec)
    except Exception as exc:  # a plant this environment cannot build: nothing to compare
        pytest.skip(f"{name}: {type(exc).__name__}")
    if not records:
        assert out is spec
        return
    full = TuningSpec.model_validate(spec.model_copy(update={"scenarios": out.scenarios}).model_dump())
    assert out.model_dump() == full.model_dump()
    assert out.content_hash() == full.content_hash()
    assert out == full and all(sc.resolved for sc in out.scenarios)


def test_a_filled_scenario_over_the_step_limit_raises_the_full_validations_error():
    spec = load_spec(INLINE[0])
    bad = spec.scenarios[0].model_copy(update={"dt": 1e-3, "horizon": 10.0 * MAX_STEPS})
    with pytest.raises(ValidationError) as fast:
        _with_scenarios(spec, [bad])
    with pytest.raises(ValidationError) as full:
        TuningSpec.model_validate(spec.model_copy(update={"scenarios": [bad]}).model_dump())
    assert str(fast.value) == str(full.value) and "exceeds the limit" in str(fast.value)


def test_a_filled_dt_too_short_for_the_delay_raises_the_full_validations_error():
    spec = load_spec(INLINE[1])  # delay 10 s
    bad = spec.scenarios[0].model_copy(update={"dt": 1e-6, "horizon": 1e-6 * 1000})
    with pytest.raises(ValidationError) as fast:
        _with_scenarios(spec, [bad])
    with pytest.raises(ValidationError) as full:
        TuningSpec.model_validate(spec.model_copy(update={"scenarios": [bad]}).model_dump())
    assert str(fast.value) == str(full.value) and "plant.delay" in str(fast.value)
