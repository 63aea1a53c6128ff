"""The query's shortcuts change no answer: the answers on held-out plants are the ones recorded before them,
and each remembered piece (the estimate's frequency grid, a repeated simulation) equals a fresh computation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gaintune.evaluation.evaluator import Evaluator
from gaintune.tuners.tuner import Tuner
from gaintune.verification import cascade, quick

DATA = json.loads((Path(__file__).parent / "data" / "held_out_answers.json").read_text())


def _unhex(d: dict) -> dict:
    return {k: _unhex(v) if isinstance(v, dict) else float.fromhex(v) for k, v in d.items()}


@pytest.mark.parametrize("row", DATA["answers"], ids=lambda r: f"{r['tuner']}-{r['params']['L'][:10]}")
def test_query_answers_on_held_out_plants_are_the_recorded_ones(row):
    ans = Tuner.load(row["tuner"]).query(_unhex(row["params"]))
    want = _unhex(row["gains"])
    assert ans.verdict == row["verdict"]
    assert set(ans.gains) == set(want)
    for lp, gains in want.items():
        assert set(ans.gains[lp]) == set(gains)
        for g, x in gains.items():  # equal on the machine that recorded them; 1e-12 leaves room for another CPU's
            assert ans.gains[lp][g] == pytest.approx(x, rel=1e-12, abs=0.0)  # BLAS/LAPACK rounding
    assert ans.cost == pytest.approx(float.fromhex(row["cost"]), rel=1e-12, abs=0.0)


def _estimate_rows(ev: Evaluator) -> np.ndarray:
    lay = ev.layout
    rows = np.array([[0.05, 0.002], [0.1, 0.004], [0.3, 0.02]])
    return lay.full(rows)


def test_remembered_frequency_grid_gives_the_estimate_computed_afresh():
    spec = Tuner.load("fotd_pi_ms1.4").problem.physical_spec({"K": 2.0, "T": 60.0, "L": 10.0})
    ev = Evaluator(spec)
    lin = ev.constraint_models[0]
    full = _estimate_rows(ev)
    quick._FREQ_CACHE.clear()
    cascade._SAMPLED_SIDE.clear()
    fresh = quick.quick_margins(ev.spec, ev.plant, ev.layout, full, lin)
    again = quick.quick_margins(ev.spec, ev.plant, ev.layout, full, lin)  # grid and plant responses remembered
    assert len(quick._FREQ_CACHE) == 1 and len(cascade._SAMPLED_SIDE) == 1
    for name in ("gm_db", "pm_deg", "delay_margin", "ms", "mt", "mks", "wc", "stable", "max_real", "omega"):
        np.testing.assert_array_equal(getattr(again, name), getattr(fresh, name))
    assert not again.omega.flags.writeable  # shared between calls: read-only


def test_frequency_grid_is_remembered_per_model_object():
    spec = Tuner.load("fotd_pi_ms1.4").problem.physical_spec({"K": 2.0, "T": 60.0, "L": 10.0})
    other = Tuner.load("fotd_pi_ms1.4").problem.physical_spec({"K": 2.0, "T": 6.0, "L": 1.0})
    a, b = Evaluator(spec), Evaluator(other)
    qa = quick.quick_margins(a.spec, a.plant, a.layout, _estimate_rows(a), a.constraint_models[0])
    qb = quick.quick_margins(b.spec, b.plant, b.layout, _estimate_rows(b), b.constraint_models[0])
    assert not np.array_equal(qa.omega, qb.omega)  # ten times faster plant: its own grid


def test_plant_input_column_has_the_values_and_layout_of_concatenate_and_moveaxis():
    x = np.arange(12.0).reshape(3, 4) * np.pi
    got, want = quick._with_plant_input(x), np.moveaxis(np.concatenate([x, x[-1:]]), 0, -1)
    np.testing.assert_array_equal(got, want)
    assert got.shape == want.shape == (4, 4) and got.strides == want.strides and got.dtype == want.dtype
    flags = np.array([[True, False], [False, True]])
    want = np.moveaxis(np.concatenate([flags, flags[-1:]]), 0, -1)
    np.testing.assert_array_equal(quick._with_plant_input(flags), want)


def test_sampled_plant_side_is_remembered_only_for_a_read_only_grid():
    spec = Tuner.load("fotd_pi_ms1.4").problem.physical_spec({"K": 2.0, "T": 60.0, "L": 10.0})
    ev = Evaluator(spec)
    sp = quick.sample_plant(ev.constraint_models[0], ev.spec.scenarios[0].dt)
    s = 1j * np.logspace(-3, 0, 50)
    cascade._SAMPLED_SIDE.clear()
    cascade._sampled_plant_side(s, sp)
    assert not cascade._SAMPLED_SIDE  # a writable array may change: never remembered
    s.setflags(write=False)
    X, P, integ, _ = cascade._sampled_plant_side(s, sp)
    X2, P2, integ2, _ = cascade._sampled_plant_side(s, sp)
    assert X2 is X and P2 is P and integ2 is integ and not X.flags.writeable
    Xf, Pf = sp.responses(np.exp(s * sp.dt))
    np.testing.assert_array_equal(X, Xf)
    np.testing.assert_array_equal(P, Pf)


def record(commit: str) -> dict:
    """The answers this test compares with: ``Tuner.query`` on the first 8 held-out plants of ``gaintune bench
    tuners`` for the FOTD PI and PID tuners at Ms 1.4 (float.hex). Re-record only when the answers change on
    purpose (a retrained tuner, a changed move): ``python tests/tuners/test_query_speed_paths.py COMMIT``."""
    from gaintune.bench.tuners_refs import held_out_plants

    rows = []
    for name in ("fotd_pi_ms1.4", "fotd_pid_ms1.4"):
        tuner = Tuner.load(name)
        for params in held_out_plants(8):
            a = tuner.query(params)
            rows.append({"tuner": name, "params": {k: float(v).hex() for k, v in params.items()},
                         "gains": {lp: {g: float(x).hex() for g, x in gs.items()} for lp, gs in a.gains.items()},
                         "cost": float(a.cost).hex(), "verdict": a.verdict})
    return {"about": "Tuner.query answers on the first 8 held-out plants of gaintune bench tuners (seed 12345), "
                     f"recorded at commit {commit} (float.hex)", "answers": rows}


if __name__ == "__main__":
    import sys

    out = Path(__file__).parent / "data" / "held_out_answers.json"
    out.write_text(json.dumps(record(sys.argv[1]), indent=1) + "\n")
