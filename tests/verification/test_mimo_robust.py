"""The MIMO verdict's robust set: a spec randomising plant parameters is judged on every drawn plant
(the single-loop robust set: box corners + seeded Monte-Carlo draws), worst case beside nominal."""

from __future__ import annotations

import copy

import pytest
import yaml

from gaintune.errors import SpecError
from gaintune.plants.library import load_model, models_dir
from gaintune.spec import load_spec
from gaintune.verification import verify

#: PI gains on Wood-Berry whose MIMO Ms is ~1.95 nominally and ~2.08 when the R -> xD gain drops to 10.
GAINS = {"xD": {"Kp": 0.4, "Ki": 0.02}, "xB": {"Kp": -0.05, "Ki": -0.003}}


def wood_berry_k11(k11: float = 12.8, randomize: dict | None = None, **requirements) -> dict:
    """The Wood-Berry example spec with its R -> xD gain written as the parameter K11."""
    tfm = copy.deepcopy(yaml.safe_load((models_dir() / "wood_berry.yaml").read_text())["plant"]["tf_matrix"])
    tfm["entries"][0][0]["num"] = ["K11"]
    data = load_model("wood_berry").example_spec()
    data["plant"] = {"tf_matrix": tfm, "params": {"K11": k11}}
    data["requirements"] = {**data["requirements"], **requirements}
    if randomize is not None:
        data["randomize"] = randomize
    return data


RANDOM_K11 = {"params": {"K11": {"low": 10.0, "high": 16.0}}}


def test_mimo_verdict_fails_on_a_drawn_plant_naming_the_worst_case_and_its_draw() -> None:
    rep = verify(load_spec(wood_berry_k11(randomize=RANDOM_K11, mimo_ms_max=2.0)), GAINS, nonlinear=False)
    nominal = [q for q in rep.requirements if q.case == "nominal"]
    worst = [q for q in rep.requirements if q.case == "worst"]
    assert [q.requirement for q in nominal] == [q.requirement for q in worst] == ["mimo_ms_max"]
    assert nominal[0].passed and nominal[0].value < 2.0 and nominal[0].draw is None
    assert not worst[0].passed and worst[0].value > 2.0 and worst[0].draw == {"K11": 10.0}
    assert rep.verdict == "fail" and len(rep.reasons) == 1
    assert rep.reasons[0].startswith("mimo_ms_max: ms = ") and rep.reasons[0].endswith(
        "at input (worst case, draw K11=10)")
    rob = rep.robust
    assert rob is not None and (rob.n_samples, rob.n_corners, rob.n_monte_carlo, rob.n_unstable) == (18, 2, 16, 0)
    side = {s.side: s for s in rob.sides}
    assert side["input"].ms == worst[0].value and side["input"].where["ms"] == {"K11": 10.0}
    assert [(w.loop, w.break_point) for w in rob.worst] == [(f.loop, f.break_point) for f in rep.loops]
    # the worst case is the verdict of that drawn plant, judged as a nominal plant
    alone = verify(load_spec(wood_berry_k11(k11=10.0, mimo_ms_max=2.0)), GAINS, nonlinear=False)
    assert alone.mimo is not None and alone.mimo.ms == pytest.approx(worst[0].value, rel=1e-12)


def test_mimo_robust_set_is_the_seeded_single_loop_set() -> None:
    """The same spec draws the same set; the seed is search.seed, reported with the set."""
    data = wood_berry_k11(randomize=RANDOM_K11, mimo_ms_max=2.5)
    data["verify"] = {"robust_samples": 3}
    a = verify(load_spec(data), GAINS, nonlinear=False)
    b = verify(load_spec(data), GAINS, nonlinear=False)
    assert a.verdict == "pass" and a.robust is not None and a.robust.n_samples == 2 + 3
    assert a.requirements == b.requirements
    data["search"] = {"seed": 7}
    c = verify(load_spec(data), GAINS, nonlinear=False)
    assert c.robust is not None and c.robust.seed == 7 and c.requirements[0] == a.requirements[0]


def test_mimo_spec_without_randomize_keeps_the_nominal_verdict_and_figures() -> None:
    plain = verify(load_spec(wood_berry_k11(mimo_ms_max=2.0, gm_min_db=3.0)), GAINS, nonlinear=False)
    assert plain.robust is None and all(q.case == "nominal" and q.draw is None for q in plain.requirements)
    assert not any("robust set" in n for n in plain.notes)
    rand = verify(load_spec(wood_berry_k11(randomize=RANDOM_K11, mimo_ms_max=2.0, gm_min_db=3.0)), GAINS,
                  nonlinear=False)
    assert [q for q in rand.requirements if q.case == "nominal"] == plain.requirements
    assert rand.mimo == plain.mimo and rand.loops == plain.loops and rand.stability == plain.stability
    off = verify(load_spec(wood_berry_k11(randomize=RANDOM_K11, mimo_ms_max=2.0, gm_min_db=3.0)), GAINS,
                 nonlinear=False, robust=False)
    assert off.robust is None and off.requirements == plain.requirements and off.verdict == plain.verdict == "pass"


def test_mimo_randomize_on_a_parameter_the_plant_lacks_is_refused_naming_the_field() -> None:
    data = load_model("wood_berry").example_spec()  # numeric entries: no parameters at all
    data["randomize"] = {"params": {"K11": {"low": 10.0, "high": 16.0}}}
    with pytest.raises(SpecError, match=r"randomize\.params\.K11") as exc:
        verify(load_spec(data), GAINS, nonlinear=False)
    assert "no parameter 'K11'" in str(exc.value)
    data = wood_berry_k11(randomize={"params": {"K12": {"low": 1.0, "high": 2.0}}})
    with pytest.raises(SpecError, match=r"randomize\.params\.K12") as exc:
        verify(load_spec(data), GAINS, nonlinear=False)
    assert "parameters: K11" in str(exc.value)
    data = wood_berry_k11(randomize={"delay": {"low": 0.5, "high": 1.0}})
    with pytest.raises(SpecError, match=r"randomize\.delay"):
        verify(load_spec(data), GAINS, nonlinear=False)


def test_mimo_robust_set_of_the_continuous_loop_judges_every_draw() -> None:
    data = wood_berry_k11(randomize=RANDOM_K11, mimo_ms_max=2.0)
    data["verify"] = {"sampled": False, "robust_samples": 2}
    rep = verify(load_spec(data), GAINS, nonlinear=False)
    worst = [q for q in rep.requirements if q.case == "worst"]
    assert not rep.sampled and rep.robust is not None and rep.robust.n_samples == 4
    assert worst[0].draw == {"K11": 10.0} and worst[0].value > [q for q in rep.requirements][0].value


def test_loop_graph_on_a_single_input_plant_judges_each_drawn_parameter_not_the_nominal() -> None:
    """A single-input plant in a loop graph is viewed as a one-input MIMO plant: a draw must change it."""
    spec = {"plant": {"tf": {"num": ["K"], "den": [1.0, 1.0]}, "params": {"K": 1.0}, "delay": 0.1},
            "loops": [{"name": "l", "drives": "u", "type": "pi"}],
            "scenarios": [{"dt": 0.01, "horizon": 5.0, "reference": {"loop": "l", "kind": "step"}}],
            "randomize": {"params": {"K": {"low": 1.0, "high": 3.0}}}, "verify": {"robust_samples": 0},
            "requirements": {"gm_min_db": 3.0, "ms_max": None, "pm_min_deg": None, "mks_max": None}}
    rep = verify(load_spec(spec), {"l": {"Kp": 1.0, "Ki": 1.0}}, nonlinear=False)
    nominal, worst = (next(q for q in rep.requirements if q.case == c) for c in ("nominal", "worst"))
    assert worst.draw == {"K": 3.0} and worst.value == pytest.approx(nominal.value - 20 * 0.47712125472, abs=1e-6)


def test_mimo_verdict_fails_when_a_drawn_closed_loop_is_unstable() -> None:
    data = wood_berry_k11(randomize={"params": {"K11": {"low": 12.8, "high": 80.0}}}, mimo_ms_max=3.0)
    data["verify"] = {"robust_samples": 2}
    rep = verify(load_spec(data), GAINS, nonlinear=False)
    assert rep.stability.stable and rep.verdict == "fail"
    assert rep.reasons == ["robust: 1 of 4 sampled plants give an unstable closed loop"]
    assert rep.robust is not None and rep.robust.unstable_samples == [{"K11": 80.0}]
    nominal, worst = rep.requirements
    assert nominal.passed and nominal.applicable and worst.case == "worst" and not worst.applicable
    alone = verify(load_spec(wood_berry_k11(k11=80.0, mimo_ms_max=3.0)), GAINS, nonlinear=False)
    assert not alone.stability.stable


def test_mimo_robust_set_with_no_stable_draw_gives_lines_not_applicable_and_no_worst_figures() -> None:
    data = wood_berry_k11(randomize={"params": {"K11": {"low": 80.0, "high": 200.0}}}, mimo_ms_max=3.0)
    data["verify"] = {"robust_samples": 2}
    rep = verify(load_spec(data), GAINS, nonlinear=False)
    assert rep.reasons == ["robust: 4 of 4 sampled plants give an unstable closed loop"]
    assert rep.robust is not None and rep.robust.worst == [] and rep.robust.sides == []
    assert [(q.case, q.applicable) for q in rep.requirements] == [("nominal", True), ("worst", False)]


def test_mimo_robust_set_of_a_nonlinear_plant_linearises_each_draw() -> None:
    """quadruple_tank is an ODE: each drawn plant is linearised at its own parameters (a corner's worst
    case equals that plant verified on its own)."""
    data = load_model("quadruple_tank").example_spec()
    data["randomize"] = {"params": {"gamma1": {"low": 0.65, "high": 0.75}, "k1": {"low": 3.2, "high": 3.4}}}
    data["verify"] = {"robust_samples": 0}
    gains = {"y1": {"Kp": 3.0, "Ki": 0.1}, "y2": {"Kp": 2.7, "Ki": 0.0675}}
    rep = verify(load_spec(data), gains, nonlinear=False)
    nominal, worst = rep.requirements
    assert rep.robust is not None and rep.robust.n_samples == 4 and worst.draw is not None
    assert worst.value != pytest.approx(nominal.value, rel=1e-3)
    data.pop("randomize")
    data["plant"] = {"model": {"name": "quadruple_tank", "params": worst.draw}}
    alone = verify(load_spec(data), gains, nonlinear=False)
    assert alone.requirements[0].value == pytest.approx(worst.value, rel=1e-12)
