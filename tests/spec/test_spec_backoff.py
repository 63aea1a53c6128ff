"""The ``requirements.backoff`` schema and its aimed limits (gaintune.spec.backoff)."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from gaintune.spec import RequirementsSpec, load_spec
from gaintune.spec.backoff import BackoffSpec

BASE = {"plant": {"tf": {"num": [1], "den": [1, 1]}}, "loops": [{"type": "pi"}]}


def test_default_backoff_moves_every_limit_inside_except_the_crossover_band():
    b = BackoffSpec()
    assert b.aim("ms_max", 1.4) == pytest.approx(1.386)
    assert b.aim("mt_max", 1.2) == pytest.approx(1.188)
    assert b.aim("mks_max", 0.6325) == pytest.approx(0.6325 * 0.99)
    assert b.aim("pm_min_deg", 45.0) == 45.5
    assert b.aim("gm_min_db", 6.0) == pytest.approx(6.1)
    assert b.aim("dm_min", 2.0) == pytest.approx(2.02)
    assert b.aim("wc_min", 1.0) == 1.0 and b.aim("wc_max", 2.0) == 2.0
    assert b.aim("ms_max", 1.01) == pytest.approx(1.005)  # never below halfway between 1 and the limit
    with pytest.raises(ValueError, match="no back-off"):
        b.aim("overshoot", 5.0)


def test_aimed_requirements_move_numbers_and_per_loop_mks_but_keep_auto():
    req = RequirementsSpec(ms_max=1.4, mt_max=1.3, dm_min=1.0, mks_max={"a": 2.0, "b": None})
    aimed = req.aimed()
    assert (aimed.ms_max, aimed.mt_max, aimed.pm_min_deg) == (pytest.approx(1.386), pytest.approx(1.287), 45.5)
    assert aimed.mks_max == {"a": pytest.approx(1.98), "b": None}
    assert not aimed.backoff.active  # no second back-off
    assert RequirementsSpec().aimed().mks_max == "auto"  # resolved per plant, then aimed (gaintune.evaluation.evaluator)
    assert RequirementsSpec(mks_max=2).aimed().mks_max == pytest.approx(1.98)


def test_backoff_zero_turns_every_part_off():
    spec = load_spec({**BASE, "requirements": {"backoff": 0}})
    b = spec.requirements.backoff
    assert not b.active and spec.requirements.aimed() is spec.requirements
    for name, limit in (("ms_max", 1.4), ("pm_min_deg", 45.0), ("gm_min_db", 6.0), ("dm_min", 0.3), ("mks_max", 0.5)):
        assert b.aim(name, limit) == limit
    again = load_spec(spec.model_dump(mode="json"))  # round trip: backoff 0 is kept
    assert not again.requirements.backoff.active


@pytest.mark.parametrize("bad, fix", [(0.02, "can only be 0"), (True, "give 0"), ("1%", "give 0"),
                                      ({"peaks": 0.6}, "less than 0.5"), ({"pm_deg": -1}, "greater than or equal")])
def test_bad_backoff_is_refused_naming_the_field(bad, fix):
    with pytest.raises(ValidationError, match=fix) as e:
        load_spec({**BASE, "requirements": {"backoff": bad}})
    assert "requirements.backoff" in str(e.value)


def test_default_backoff_is_left_out_of_dumps_so_stored_hashes_hold():
    """Specs and stored results written before the field existed keep their hash (and the benchmark
    references their keys); a spec that sets the default explicitly is the same spec."""
    plain = load_spec(BASE)
    assert "backoff" not in plain.model_dump()["requirements"]
    explicit = load_spec({**BASE, "requirements": {"backoff": {"peaks": 0.01, "pm_deg": 0.5}}})
    assert explicit.content_hash() == plain.content_hash()
    assert load_spec({**BASE, "requirements": {"backoff": 0}}).content_hash() != plain.content_hash()


def test_design_shortcut_phase_margin_is_aimed_like_any_requirement():
    """``design: {phase_margin: 60}`` fills requirements.pm_min_deg: the search aims at 60.5 deg, the verdict judges 60."""
    spec = load_spec({**BASE, "design": {"phase_margin": 60}})
    assert spec.requirements.pm_min_deg == 60
    assert spec.requirements.aimed().pm_min_deg == 60.5
