"""Searching a MIMO spec: the per-loop classical start, the search box, CMA-ES through the one Evaluator."""

from __future__ import annotations

import numpy as np

from gaintune.baselines import run_baseline
from gaintune.classical.mimo_rules import loop_rule_candidates
from gaintune.evaluation.search_box import search_box
from gaintune.plants import build_plant
from gaintune.plants.library import load_model
from gaintune.spec import load_spec


def wood_berry(**extra):
    return load_spec({**load_model("wood_berry").example_spec(), **extra})


def test_wood_berry_rules_loop_by_loop_carry_each_loops_sign() -> None:
    spec = wood_berry()
    rules = loop_rule_candidates(spec, build_plant(spec.plant))
    assert {"simc", "amigo"} <= set(rules)
    for gains in rules.values():
        assert gains["xD"]["Kp"] > 0 and gains["xB"]["Kp"] < 0 and gains["xB"]["Ki"] < 0
    # SIMC on G11 = 12.8 e^{-s}/(16.7 s + 1), theta = 1 min + dt/2 (the sample-and-hold), tau_c = theta:
    # Kc = tau / (K (tau_c + theta)), Ti = min(tau, 8 theta)
    theta = 1.0 + 0.1 / 2
    np.testing.assert_allclose(rules["simc"]["xD"]["Kp"], 16.7 / (12.8 * 2 * theta), rtol=1e-9)
    np.testing.assert_allclose(rules["simc"]["xD"]["Kp"] / rules["simc"]["xD"]["Ki"], 8 * theta, rtol=1e-9)


def test_ties_have_no_per_loop_rules() -> None:
    spec = wood_berry(ties=[["xD.Ki", "xB.Ki"]])
    assert loop_rule_candidates(spec, build_plant(spec.plant)) == {}


def test_chains_get_the_single_input_cascade_rules_so_the_search_box_needs_no_sobol_sample() -> None:
    """Before, a chain of loops had no rule candidates: the 54-gain arm's search box spent 12,808 of a tune's
    20,000 simulations on a Sobol sample, and RL alone found nothing feasible in the rest."""
    spec = load_spec(load_model("robot_arm6_lin").example_spec())
    plant = build_plant(spec.plant)
    rules = loop_rule_candidates(spec, plant)
    assert rules and all(set(g) == set(spec.loop_names) for g in rules.values())
    box = search_box(spec, plant)
    assert box.source is not None and box.source.split()[0] in rules
    assert box.sims < 1000  # rules x scales x scenarios, not 1,024 Sobol points and zoom stages


def test_search_box_centres_on_a_scaled_rule() -> None:
    spec = wood_berry()
    box = search_box(spec, build_plant(spec.plant))
    assert box.source is not None and box.source.split()[0] in {"simc", "amigo", "imc", "zn_step", "zn_ultimate"}
    assert box.feasible and box.sims < 500  # rules x scales x 2 scenarios, not a Sobol sample


def test_cmaes_tunes_every_wood_berry_gain_jointly() -> None:
    spec = wood_berry()
    amigo = run_baseline(spec, "amigo")  # the rule loop by loop, scored on the whole plant
    assert amigo.gains == loop_rule_candidates(spec, build_plant(spec.plant))["amigo"]
    # loop by loop the rule ignores the interaction: its MIMO Ms is above the example's 2.1 (a graded violation)
    assert not amigo.feasible and 0 < amigo.violation < 1
    res = run_baseline(spec, "cmaes", budget=300, seed=0)
    assert res.n_sims <= 300 and res.feasible
    assert set(res.gains) == {"xD", "xB"} and res.gains["xB"]["Kp"] < 0
    box = search_box(spec, build_plant(spec.plant))
    centre_cost = box.candidates[box.source][2]
    assert res.cost <= centre_cost


def test_repair_trial_points_skip_the_sampled_stability_and_the_answer_is_checked_in_full() -> None:
    """The repair's trial scales skip the closed-loop eigenvalues (over half of a 110-gain check); their
    margins are the full check's, an unstable trial point is not caught there, and the repaired answer is."""
    from gaintune.evaluation.boundary_estimate import onto_boundary_estimate
    from gaintune.evaluation.evaluator import mimo_requirement_scores
    from gaintune.evaluation.search_box import make_evaluator
    from gaintune.verification.quick import UNSTABLE_VIOLATION

    spec = wood_berry()
    ev = make_evaluator(spec)
    x0 = ev.layout.initial_tuned()
    rows = x0 * np.array([[1.0], [1.6], [2.5], [40.0]])  # feasible, beyond the boundary, ..., unstable
    full_v, _ = mimo_requirement_scores(ev, rows, stability=True)
    lean_v, _ = mimo_requirement_scores(ev, rows, stability=False)
    stable = full_v < UNSTABLE_VIOLATION
    assert stable[:2].all() and not stable[-1]
    np.testing.assert_array_equal(lean_v[stable], full_v[stable])
    assert lean_v[-1] < UNSTABLE_VIOLATION  # the trial point's instability goes unseen ...
    moved = onto_boundary_estimate(ev, rows)
    # ... and every repaired answer passed the full check, stability included
    assert moved.repaired.any()
    assert (mimo_requirement_scores(ev, moved.tuned[moved.repaired], stability=True)[0] <= 0).all()


def test_chains_on_a_transfer_function_matrix_get_the_cascade_rules() -> None:
    """A chain on a transfer-function matrix had no rule candidates (only state space had a chain path): the
    110-gain process train's search box spent 641 s on a Sobol sample of 3,202 simulations, most of them
    unstable, before the search began."""
    spec = load_spec(load_model("process_train").example_spec())
    rules = loop_rule_candidates(spec, build_plant(spec.plant))
    assert {"simc", "amigo"} <= set(rules)
    for gains in rules.values():
        assert set(gains) == set(spec.loop_names)
        assert all(v > 0 for g in gains.values() for v in g.values())


def test_mimo_checks_on_threads_equal_the_checks_one_at_a_time(monkeypatch) -> None:
    """A batch's MIMO checks run on a thread per CPU (LAPACK outside the GIL). Each row's violation and
    shortfall must not depend on that: the same floats as one thread, rows repeated in the batch included,
    on both stability settings."""
    from gaintune.evaluation import evaluator as evmod

    spec = wood_berry()
    rows = []
    for run in range(2):
        ev = evmod.Evaluator(spec)
        base = ev.layout.initial_tuned()
        cand = base[None] * np.exp(np.random.default_rng(4).normal(0.0, 0.4, (6, base.size)))
        cand = np.concatenate([cand, cand[:2]])  # repeated rows: one check each, the same answer
        monkeypatch.setattr(evmod, "cpus_here", lambda run=run: 1 if run == 0 else 2)
        rows.append([evmod.mimo_requirement_scores(ev, cand, stability=s) for s in (True, False)])
    for (v1, g1), (v2, g2) in zip(rows[0], rows[1], strict=True):
        assert np.array_equal(v1, v2) and np.array_equal(g1, g2)
        assert np.array_equal(v1[-2:], v1[:2])


def test_mimo_memo_cleared_when_full_keeps_the_batchs_earlier_hits() -> None:
    """The memo of MIMO checks is cleared when it would pass 4,096 entries. A batch mixing a remembered row
    with new ones, at that size, must still answer every row (a clear between the lookup and the read lost
    the remembered row: KeyError)."""
    from gaintune.evaluation import evaluator as evmod

    ev = evmod.Evaluator(wood_berry())
    base = ev.layout.initial_tuned()
    rows = base[None] * np.array([[1.0], [0.9]])
    first, _ = evmod.mimo_requirement_scores(ev, rows[:1])
    ev._mimo_memo.update({bytes([i % 256, i // 256]): (0.0, 0.0) for i in range(4096 - len(ev._mimo_memo))})
    both, _ = evmod.mimo_requirement_scores(ev, rows)
    assert both[0] == first[0] and len(ev._mimo_memo) <= 4096
