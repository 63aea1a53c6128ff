"""Tunable static blocks of a MIMO architecture: decoupler entries and reference feedforward gains.

The spec refuses bad blocks naming the field; the layout appends tuned entries after the loops' gains
(specs without tuned entries keep their layout); the simulator gives every candidate of a batch its own
``W`` and ``F``; the verification's controller has the candidate's ``W`` in front, and a feedforward
changes the setpoint response but none of the loop's figures."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError

from gaintune.controllers.layout import GainLayout
from gaintune.errors import GainError, SpecError
from gaintune.plants import build_plant
from gaintune.plants.library import load_model
from gaintune.sim import Simulator
from gaintune.spec import load_spec
from gaintune.verification.mimo_spec import spec_loop, spec_margins

A = [[-1.0, 0.2], [0.0, -0.5]]
B = [[1.0, 0.3], [0.4, 1.0]]
GAINS = {"a": {"Kp": 1.5, "Ki": 1.0}, "b": {"Kp": 0.8, "Ki": 0.5}}


def two_by_two(**extra: Any) -> dict[str, Any]:
    """A 2 x 2 state-space plant with two PI loops side by side (a steps, b holds)."""
    d: dict[str, Any] = {
        "plant": {"ss": {"A": A, "B": B, "C": [[1, 0], [0, 1]], "inputs": ["u1", "u2"], "outputs": ["y1", "y2"]}},
        "loops": [{"name": "a", "measure": "y1", "drives": "u1", "type": "pi", "direction": "direct"},
                  {"name": "b", "measure": "y2", "drives": "u2", "type": "pi", "direction": "direct"}],
        "scenarios": [{"name": "s", "dt": 0.05, "horizon": 10.0, "reference": {"loop": "a"}}],
        "requirements": {"mks_max": None, "gm_min_db": None, "pm_min_deg": None, "ms_max": None},
    }
    d.update(extra)
    return d


TUNED_DEC = {"inputs": ["u1", "u2"],
             "matrix": [[1.0, {"value": -0.3, "bounds": [-1.0, -0.05]}], [{"bounds": [0.05, 1.0]}, 1.0]]}


def _loc(exc: ValidationError) -> str:
    return ".".join(str(x) for x in exc.errors()[0]["loc"])


@pytest.mark.parametrize("change, field, words", [
    ({"decoupler": {"inputs": ["u1", "u2"], "matrix": [[1, {"bounds": [-1, 2]}], [0, 1]]}},
     "decoupler.matrix.0.1.entry.bounds", "cannot contain 0"),
    ({"decoupler": {"inputs": ["u1", "u2"], "matrix": [[1, {"value": 3, "bounds": [0.1, 2]}], [0, 1]]}},
     "decoupler.matrix.0.1.entry.value", "outside bounds"),
    ({"decoupler": {"inputs": ["u1", "u2"], "matrix": [[1, {"value": 0.5}], [0, 1]]}},
     "decoupler.matrix.0.1.entry.bounds", "needs bounds"),
    ({"decoupler": {"inputs": ["u1", "u2"], "matrix": [[1, {"tune": False}], [0, 1]]}},
     "decoupler.matrix.0.1.entry.value", "needs a value"),
    ({"decoupler": {"inputs": ["u1", "u2"], "matrix": [[1, {"bounds": [0.1, 2]}]]}}, "decoupler.matrix", "2x2"),
    ({"decoupler": {"inputs": ["u1", "u2"], "matrix": [[1, True], [0, 1]]}}, "decoupler.matrix.0.1", "number"),
    ({"decoupler": {"inputs": ["u1", "u9"], "matrix": [[1, 0], [0, 1]]}}, "decoupler.inputs.1", "no input 'u9'"),
    ({"feedforward": [{"loop": "c", "input": "u2", "gain": 0.1}]}, "feedforward.0.loop", "no loop named 'c'"),
    ({"feedforward": [{"loop": "a", "input": "u9", "gain": 0.1}]}, "feedforward.0.input", "no input 'u9'"),
    ({"feedforward": [{"loop": "a", "input": "u2", "gain": {"bounds": [0, 1]}}]},
     "feedforward.0.gain.entry.bounds", "one sign"),
    ({"feedforward": [{"loop": "a", "input": "u2", "gain": 0.1}, {"loop": "a", "input": "u2", "gain": 0.2}]},
     "feedforward.1", "one gain per pair"),
])
def test_bad_block_specs_are_refused_naming_the_field(change: dict, field: str, words: str) -> None:
    with pytest.raises(ValidationError) as exc:
        load_spec(two_by_two(**change))
    assert _loc(exc.value) == field and words in str(exc.value)


def test_feedforward_from_a_loop_that_takes_another_loops_output_is_refused() -> None:
    d = two_by_two(feedforward=[{"loop": "b", "input": "u1", "gain": 0.1}])
    d["loops"][0]["drives"] = "loop:b"  # a cascade: a sets b's setpoint
    with pytest.raises(ValidationError) as exc:
        load_spec(d)
    assert _loc(exc.value) == "feedforward.0.loop" and "outer loop of the chain" in str(exc.value)


def test_loop_named_like_a_tuned_block_is_refused() -> None:
    d = two_by_two(decoupler=TUNED_DEC)
    d["loops"][1]["name"] = "decoupler"
    with pytest.raises(ValidationError) as exc:
        load_spec(d)
    assert _loc(exc.value) == "loops.1.name" and "rename this loop" in str(exc.value)


def test_decoupler_input_a_built_in_model_lacks_is_a_spec_error_at_build() -> None:
    """A model's inputs are known once it is built: the simulator names the field then (no ValueError)."""
    d = load_model("wood_berry").example_spec()
    d["decoupler"] = {"inputs": ["R", "Q"], "matrix": [[1, 0], [0, 1]]}
    with pytest.raises(SpecError) as exc:
        Simulator(load_spec(d))
    assert exc.value.field == "decoupler.inputs[1]" and "no input 'Q'" in str(exc.value)


@pytest.mark.parametrize("blocks", [
    {},
    {"decoupler": {"inputs": ["u1", "u2"], "matrix": [[1.0, -0.3], [{"value": 0.2, "tune": False}, 1.0]]}},
    {"feedforward": [{"loop": "a", "input": "u2", "gain": 0.4}]},
])
def test_layout_without_tuned_blocks_is_the_loops_layout(blocks: dict) -> None:
    """Fixed block entries add no slot: the same gains in the same order, bounds and signs as the plain spec."""
    plain = load_spec(two_by_two())
    spec = load_spec(two_by_two(**blocks))
    a, b = (GainLayout(s, [], plant=build_plant(s.plant)) for s in (plain, spec))
    assert b.slots == a.slots and [(s.loop_name, s.name) for s in b.slots] == [
        ("a", "Kp"), ("a", "Ki"), ("b", "Kp"), ("b", "Ki")]
    np.testing.assert_array_equal(b.log_lo, a.log_lo)
    np.testing.assert_array_equal(b.full(b.initial_tuned()), a.full(a.initial_tuned()))


def test_tuned_entries_follow_the_loop_gains_with_the_sign_of_their_bounds() -> None:
    spec = load_spec(two_by_two(decoupler=TUNED_DEC, feedforward=[
        {"loop": "a", "input": "u2", "gain": {"value": 0.2, "bounds": [0.01, 1.0]}}]))
    lay = GainLayout(spec, [], plant=build_plant(spec.plant))
    assert [(s.loop_name, s.name, s.sign, s.bounds) for s in lay.slots[4:]] == [
        ("decoupler", "d_u1_u2", -1, (0.05, 1.0)), ("decoupler", "d_u2_u1", 1, (0.05, 1.0)),
        ("feedforward", "ff_a_u2", 1, (0.01, 1.0))]
    assert [s.spec_field for s in lay.slots[4:]] == ["decoupler.matrix[0][1]", "decoupler.matrix[1][0]",
                                                     "feedforward[0].gain"]
    full = lay.full(lay.initial_tuned())
    np.testing.assert_allclose(full[4:], [-0.3, np.sqrt(0.05), 0.2])  # value, else the bounds' centre
    gains = {**GAINS, "decoupler": {"d_u1_u2": -0.5, "d_u2_u1": 0.1}, "feedforward": {"ff_a_u2": 0.3}}
    np.testing.assert_array_equal(lay.from_dict(gains)[4:], [-0.5, 0.1, 0.3])
    with pytest.raises(GainError) as exc:
        lay.from_dict({**gains, "decoupler": {"d_u1_u2": 0.5, "d_u2_u1": 0.1}})
    assert exc.value.field == "gains.decoupler.d_u1_u2" and "decoupler.matrix[0][1] are negative" in str(exc.value)


def _dec_gains(d12: float, d21: float, ff: float | None = None) -> dict:
    out = {**GAINS, "decoupler": {"d_u1_u2": d12, "d_u2_u1": d21}}
    return out if ff is None else {**out, "feedforward": {"ff_a_u2": ff}}


def test_batch_with_different_decouplers_gives_each_candidate_its_own_response() -> None:
    """Five decouplers in one call: each lane equals its own single-candidate run, and they differ."""
    spec = load_spec(two_by_two(decoupler=TUNED_DEC, feedforward=[
        {"loop": "a", "input": "u2", "gain": {"bounds": [0.01, 1.0]}}]))
    sim = Simulator(spec)
    rows = [(-0.05, 0.05, 0.01), (-0.2, 0.3, 0.1), (-0.5, 0.5, 0.5), (-1.0, 0.9, 1.0), (-0.3, 0.05, 0.2)]
    full = np.array([sim.layout.from_dict(_dec_gains(*r)) for r in rows])
    batch = sim.run(full, traces=True)
    for i in range(len(rows)):
        one = sim.run(full[i:i + 1], traces=True)
        for name in ("iae", "ise", "effort", "overshoot"):
            np.testing.assert_array_equal(batch.metrics[name][i], one.metrics[name][0], err_msg=name)
        for name in ("u.u1", "u.u2", "y.a", "y.b"):
            np.testing.assert_array_equal(batch.traces[name][i], one.traces[name][0], err_msg=name)
    assert len(set(np.round(batch.metrics["iae"], 12))) == len(rows)


def test_tuned_decoupler_runs_as_the_fixed_decoupler_at_the_same_entries() -> None:
    tuned = Simulator(load_spec(two_by_two(decoupler=TUNED_DEC)))
    fixed = Simulator(load_spec(two_by_two(decoupler={"inputs": ["u1", "u2"], "matrix": [[1.0, -0.4], [0.2, 1.0]]})))
    a = tuned.run(tuned.layout.from_dict(_dec_gains(-0.4, 0.2))[None], traces=True)
    b = fixed.run(fixed.layout.from_dict(GAINS)[None], traces=True)
    for name in ("u.u1", "u.u2", "y.a", "y.b"):
        np.testing.assert_array_equal(a.traces[name], b.traces[name], err_msg=name)


def test_feedforward_adds_gain_times_reference_to_its_input() -> None:
    """At the first step (y = 0, r = 1) u2 is the feedforward alone on top of loop b's zero output;
    later u2 differs from the run without feedforward by what the loops make of it."""
    ff = Simulator(load_spec(two_by_two(feedforward=[{"loop": "a", "input": "u2", "gain": 0.25}])))
    plain = Simulator(load_spec(two_by_two()))
    a = ff.run(ff.layout.from_dict(GAINS)[None], traces=True)
    b = plain.run(plain.layout.from_dict(GAINS)[None], traces=True)
    assert a.traces["u.u2"][0, 0] == pytest.approx(0.25, abs=1e-15) and b.traces["u.u2"][0, 0] == 0.0
    np.testing.assert_array_equal(a.traces["u.u1"][0, 0], b.traces["u.u1"][0, 0])
    assert a.metrics["iae"][0] != b.metrics["iae"][0]


def test_feedforward_changes_the_setpoint_response_but_not_the_margins() -> None:
    """The feedforward is outside the loop: the same verification figures, another response."""
    d = two_by_two()
    d["requirements"] = {"mimo_ms_max": 3.0, "mks_max": None, "gm_min_db": 3.0, "pm_min_deg": 20.0, "ms_max": None}
    plain = load_spec(d)
    withff = load_spec({**copy.deepcopy(d), "feedforward": [
        {"loop": "a", "input": "u2", "gain": {"value": -0.3, "bounds": [-1, -0.01]}}]})
    out = []
    for spec, gains in ((plain, GAINS), (withff, {**GAINS, "feedforward": {"ff_a_u2": -0.3}})):
        plant = build_plant(spec.plant)
        lay = GainLayout(spec, [], plant=plant)
        _, rep, lines = spec_margins(spec, plant, lay, lay.from_dict(gains))
        sim = Simulator(spec)
        out.append(([(q.requirement, q.target, q.value) for q in lines], rep.ms_input.value, rep.stability.stable,
                    sim.run(sim.layout.from_dict(gains)[None]).metrics["iae"][0]))
    assert out[0][:3] == out[1][:3] and out[0][0]
    assert out[0][3] != out[1][3]


def test_verification_controller_includes_the_tuned_decoupler() -> None:
    """K = W diag(C_a, C_b) (PI laws Kp + Ki/s) for the candidate's W, against a hand-built 2 x 2."""
    spec = load_spec(two_by_two(decoupler=TUNED_DEC))
    plant = build_plant(spec.plant)
    lay = GainLayout(spec, [], plant=plant)
    W = np.array([[1.0, -0.6], [0.35, 1.0]])
    K = spec_loop(spec, plant, lay, lay.from_dict(_dec_gains(-0.6, 0.35))).controller
    w = np.array([0.01, 0.3, 1.0, 7.0])
    s = 1j * w
    C = np.zeros((w.size, 2, 2), dtype=complex)
    C[:, 0, 0] = GAINS["a"]["Kp"] + GAINS["a"]["Ki"] / s
    C[:, 1, 1] = GAINS["b"]["Kp"] + GAINS["b"]["Ki"] / s
    np.testing.assert_allclose(K.freqresp(w), W[None] @ C, rtol=1e-12)


def test_search_box_from_loop_rules_keeps_the_tuned_feedforward_entries() -> None:
    """The loop-by-loop rules tune the loops only: their candidates carry the tuned feedforward gain at its
    spec value instead of failing as a gain set that misses it."""
    from gaintune.evaluation.search_box import search_box

    ff = {"loop": "a", "input": "u2", "gain": {"value": 0.2, "bounds": [0.01, 1]}}
    spec = load_spec(two_by_two(feedforward=[ff]))
    box = search_box(spec, build_plant(spec.plant))
    assert box.source is not None and box.centre is not None and box.centre["feedforward"] == {"ff_a_u2": 0.2}
    assert [(s.loop_name, s.name) for s in box.layout.tuned_slots][-1] == ("feedforward", "ff_a_u2")


def test_decoupled_pi_loop_that_settles_is_judged_stable() -> None:
    """Wood-Berry behind its steady-state decoupler with moderate PI gains: the simulated steps settle and
    the Pade closed-loop poles are all in the left half-plane, so the verification must call it stable.
    Before, the stability count dropped all 4 integrators of W diag(PI, PI), realised entry by entry, as
    hidden where 2 are, and judged it unstable."""
    d = load_model("wood_berry").example_spec()
    d["decoupler"] = {"inputs": ["R", "S"], "matrix": [[1.0, 18.9 / 12.8], [6.6 / 19.4, 1.0]]}
    spec = load_spec(d)
    plant = build_plant(spec.plant)
    lay = GainLayout(spec, plant.states, plant=plant)
    full = lay.from_dict({"xD": {"Kp": 0.2, "Ki": 0.02}, "xB": {"Kp": -0.05, "Ki": -0.005}})
    sim = Simulator(spec)
    assert all(sim.run(full[None], scenario=k).metrics["sse"][0] < 1e-2 for k in (0, 1))  # settled within 1 %
    _, rep, _ = spec_margins(spec, plant, lay, full)
    assert rep.stability.max_real_pole < 0
    assert rep.stability.stable
