"""The MIMO requirement check reuses the plant-only work (gaintune.verification.mimo_plant, mimo_spec.loop_frame)
and its sparse loop gains, with the same figures as a fresh computation and as the full report."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from gaintune.evaluation.evaluator import Evaluator, mimo_requirement_scores
from gaintune.plants.library import load_model
from gaintune.spec import load_spec
from gaintune.verification.mimo import mimo_report
from gaintune.verification.mimo_loop import MimoLoop
from gaintune.verification.mimo_sampled_report import sampled_margins
from gaintune.verification.mimo_spec import graded, loop_frame, spec_margins


def _same(a: Any, b: Any, where: str = "report") -> None:
    """Assert a == b exactly, through dataclasses, lists and arrays (NaN equal to NaN)."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            _same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{k}]")
    elif isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        assert np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True), where
    elif isinstance(a, float) and np.isnan(a):
        assert isinstance(b, float) and np.isnan(b), where
    else:
        assert a == b, where


def _arm_gains() -> dict:
    g: dict = {}
    for k in range(1, 7):
        kv = 14.0 if k <= 3 else 0.85
        g |= {f"q{k}": {"Kp": 10.0, "Ki": 1.0, "Kd": 1e-3}, f"w{k}": {"Kp": kv, "Ki": 10 * kv, "Kd": 1e-3},
              f"i{k}": {"Kp": 5.0, "Ki": 1000.0, "Kd": 1e-5}}
    return g


def _candidates(name: str, ev: Evaluator, n: int) -> np.ndarray:
    """n gain sets (tuned) near the model's working gains: a search's candidates."""
    rng = np.random.default_rng(3)
    if name == "robot_arm6":
        base = ev.layout.from_dict(_arm_gains())[ev.layout.tuned_idx]
    else:
        base = ev.layout.action_to_tuned(np.zeros(ev.dim))
    return base[None] * np.exp(rng.normal(0.0, 0.3, (n, base.size)))


@pytest.mark.parametrize("name", ["wood_berry", "robot_arm6"])
def test_mimo_requirement_check_reuses_plant_work_with_identical_figures(name: str) -> None:
    """Regression: the search's aimed MIMO check rebuilt the plant's delays, Padé realisation, eigenvalues and
    hidden modes for every candidate (~1.4 s a candidate at 110 gains). They are now built once per plant; the
    report of a candidate checked after others on one evaluator equals, figure for figure, the report of a
    fresh spec and plant object (nothing shared), and the evaluator's violation is that report's grade."""
    spec = load_spec(load_model(name).example_spec())
    ev = Evaluator(spec)
    tuned = _candidates(name, ev, 4)
    violation, _ = mimo_requirement_scores(ev, tuned)  # warms the plant work on this evaluator
    frame = loop_frame(ev.spec, ev.plant)
    assert ev.mimo_constraint_plants == [(ev.plant, frame)] and frame.plant is loop_frame(ev.spec, ev.plant).plant
    for b, t in enumerate(tuned):
        full = ev.layout.full(t[None])[0]
        _, cached, lines = spec_margins(ev.spec, ev.plant, ev.layout, full, aimed=True, frame=frame)
        fresh_ev = Evaluator(load_spec(load_model(name).example_spec()))  # new spec and plant objects
        assert fresh_ev.plant is not ev.plant
        _, fresh, fresh_lines = spec_margins(fresh_ev.spec, fresh_ev.plant, fresh_ev.layout, full, aimed=True)
        _same(cached, fresh)
        _same(lines, fresh_lines, "lines")
        # the evaluator's violation grades the loop the verdict judges: by default the exact sampled loop
        _, sampled, s_lines = sampled_margins(ev.spec, ev.plant, ev.layout, full, aimed=True, frame=frame)
        assert graded(sampled, s_lines)[0] == violation[b]


def test_lean_mimo_check_figures_equal_the_full_report() -> None:
    """The figures the lean check computes (Wood-Berry's MIMO Ms) are the full report's, bit for bit."""
    spec = load_spec(load_model("wood_berry").example_spec())
    ev = Evaluator(spec)
    for t in _candidates("wood_berry", ev, 3):
        full = ev.layout.full(t[None])[0]
        sl, lean, _ = spec_margins(ev.spec, ev.plant, ev.layout, full, aimed=True)
        rep = mimo_report(sl.plant, sl.controller, sl.pairing, pade_order=spec.verify.pade_order)
        _same(lean.stability, rep.stability, "stability")
        if rep.stability.stable:
            assert (lean.ms_input, lean.ms_output) == (rep.ms_input, rep.ms_output)


def test_cascade_loop_gains_from_nonzero_entries_match_the_dense_product() -> None:
    """The sparse Ks Gs and Gs Ks of the arm's 18 cascaded loops (6 inputs) are the dense products, and a
    point on an integrator's pole (s = 0) keeps the dense product's NaN."""
    spec = load_spec(load_model("robot_arm6").example_spec())
    ev = Evaluator(spec)
    sl, _, _ = spec_margins(ev.spec, ev.plant, ev.layout, ev.layout.full(_candidates("robot_arm6", ev, 1))[0],
                            aimed=True)
    loop = MimoLoop.build(sl.plant, sl.controller, sl.pairing)
    assert not loop.diagonal_controller()
    s = np.concatenate([[0.0], 1j * np.logspace(-2, 4, 200)])
    Gs, Ks = loop.channels(s)
    with np.errstate(all="ignore"):
        dense = {"input": Ks @ Gs, "output": Gs @ Ks}
    for side, want in dense.items():
        got = loop.loop_gains(s, side)
        assert got.shape == want.shape
        assert np.array_equal(np.isnan(got[0]), np.isnan(want[0])) and np.isnan(want[0]).any()
        np.testing.assert_allclose(got[1:], want[1:], rtol=1e-12, atol=1e-12 * np.abs(want[1:]).max())


def test_cascade_output_break_zoom_on_the_input_side_matches_the_output_sensitivity() -> None:
    """The loop-at-a-time zoom of an output break of a cascade (18 outputs, 6 inputs) solves on the input side
    (S_o = I - Gs S_i Ks), as do the grid's rows: the same L_k = 1/S_o[k, k] - 1 as the output sensitivity's
    inverse, to rounding (both lose digits in 1/S - 1 where |L_k| is small: ~1e-10 absolute here)."""
    from gaintune.verification.mimo_margins import _RowsEvaluator, lat_rows

    spec = load_spec(load_model("robot_arm6").example_spec())
    ev = Evaluator(spec)
    sl, _, _ = spec_margins(ev.spec, ev.plant, ev.layout, ev.layout.full(_candidates("robot_arm6", ev, 1))[0],
                            aimed=True)
    loop = MimoLoop.build(sl.plant, sl.controller, sl.pairing)
    w = np.logspace(-1, 3, 50)
    So = loop.sensitivity(1j * w, "output")
    for k in (0, 7, 17):
        got = _RowsEvaluator(loop, True).rows_at(w, np.full(w.size, loop.n_in + k))
        np.testing.assert_allclose(got, 1.0 / So[:, k, k] - 1.0, rtol=1e-6, atol=1e-8)
    rows = lat_rows(loop, 1j * w)  # the grid's rows take the same input-side form
    np.testing.assert_allclose(rows[loop.n_in:], (1.0 / np.diagonal(So, axis1=1, axis2=2) - 1.0).T, rtol=1e-6,
                               atol=1e-8)
    with np.errstate(all="ignore"):  # at s = 0 (integrators) both forms give NaN, as the figures expect
        So0 = np.linalg.inv(np.eye(loop.n_out) + loop.loop_gains(np.zeros(1), "output"))
        assert np.array_equal(np.isnan(lat_rows(loop, np.zeros(1))[loop.n_in:, 0]),
                              np.isnan(1.0 / np.diagonal(So0, axis1=1, axis2=2)[0] - 1.0))


def test_plant_memo_computes_a_plant_figure_once_and_a_controller_figure_every_time() -> None:
    """plant_memo keeps a figure of a kept plant realisation (same arrays: computed once) and never one of
    any other realisation (a controller's, new every candidate)."""
    from gaintune.lti.mimo import DelayedSS
    from gaintune.verification.mimo_plant import plant_memo, plant_parts

    plant = DelayedSS(-np.eye(2), np.eye(2), np.eye(2), np.zeros((2, 2)), inputs=("u0", "u1"), outputs=("y0", "y1"))
    A, B, C, _ = plant_parts(plant, (0, 1), (0, 1)).realisation(0)
    calls: list[int] = []

    def figure() -> np.ndarray:
        calls.append(1)
        return np.array([1.0])

    for _ in range(3):
        assert plant_memo(A, B, C, "x", figure).tolist() == [1.0]
    assert len(calls) == 1
    for _ in range(2):
        plant_memo(A.copy(), B, C, "x", figure)
    assert len(calls) == 3


def test_loop_subclass_with_its_own_responses_keeps_them_for_output_breaks() -> None:
    """Regression: the input-side shortcut for a cascade's output breaks read the continuous entries directly,
    so a loop class with its own loop gains (the sampled-data loop) had its output breaks judged on the
    continuous loop. Such a class now keeps its own responses; the plain loop takes the shortcut."""
    spec = load_spec(load_model("robot_arm6").example_spec())
    ev = Evaluator(spec)
    sl, _, _ = spec_margins(ev.spec, ev.plant, ev.layout, ev.layout.full(_candidates("robot_arm6", ev, 1))[0],
                            aimed=True)

    class Scaled(MimoLoop):  # its own responses: the plant doubled
        def channels(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            Gs, Ks = super().channels(s)
            return 2.0 * Gs, Ks

        def loop_gains(self, s: np.ndarray, side: str) -> np.ndarray:
            return 2.0 * super().loop_gains(s, side)

    plain = MimoLoop.build(sl.plant, sl.controller, sl.pairing)
    own = Scaled.build(sl.plant, sl.controller, sl.pairing)
    assert plain.outputs_by_inputs() and not own.outputs_by_inputs()
    L, Gs, _ = own.input_side(1j * np.array([1.0, 10.0]))
    np.testing.assert_array_equal(L, 2.0 * plain.loop_gains(1j * np.array([1.0, 10.0]), "input"))
    np.testing.assert_array_equal(Gs, 2.0 * plain.channels(1j * np.array([1.0, 10.0]))[0])
