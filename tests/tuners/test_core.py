"""The tuner core: NumPy policy = torch policy, artefact round trip, query determinism, family scaling,
the boundary move from both sides, out-of-family contexts refused."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gaintune.errors import SpecError
from gaintune.evaluation.boundary_both import onto_boundary
from gaintune.evaluation.evaluator import Evaluator
from gaintune.tuners import artefact
from gaintune.tuners.families import family, problem_spec
from gaintune.tuners.mlp import NumpyPolicy, from_sb3
from gaintune.tuners.problems import FamilyProblem, SpecProblem
from gaintune.tuners.train import TrainSettings, train
from gaintune.tuners.tuner import OutsideFamilyError, Tuner
from gaintune.verification import verify

TINY = TrainSettings(episodes=512, n_envs=32, contexts_per_step=4, chunk=256, batch_size=64, validation=2,
                     curve_contexts=2)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("tuners") / "fotd_tiny"
    return train(FamilyProblem("fotd", "pi", 1.4), out, TINY)


def test_numpy_policy_equals_the_torch_policy_to_1e_6():
    from stable_baselines3 import PPO

    from gaintune.tuners.box import fit_box
    from gaintune.tuners.env import ContextBanditVecEnv

    p = FamilyProblem("fotd", "pi", 1.4)
    fit_box(p)
    agent = PPO("MlpPolicy", ContextBanditVecEnv(p, 8, 2), n_steps=4, batch_size=16, seed=3, device="cpu")
    with __import__("torch").no_grad():  # random weights, and a bias that pushes some actions past the clip
        agent.policy.action_net.bias.add_(0.7)
    x = np.random.default_rng(0).uniform(-3, 3, (500, 1)).astype(np.float32)
    ref = agent.predict(x, deterministic=True)[0]
    assert np.max(np.abs(from_sb3(agent)(x) - ref)) <= 1e-6


def test_numpy_policy_equals_the_torch_td3_actor_to_1e_6():
    from stable_baselines3 import TD3

    from gaintune.tuners.box import fit_box
    from gaintune.tuners.env import ContextBanditVecEnv

    p = FamilyProblem("sotd", "pid", 1.4)
    fit_box(p)
    agent = TD3("MlpPolicy", ContextBanditVecEnv(p, 8, 2), seed=4, device="cpu", policy_kwargs={"net_arch": [16, 16]})
    x = np.random.default_rng(1).uniform(-3, 3, (500, 2)).astype(np.float32)
    ref = agent.predict(x, deterministic=True)[0]
    pol = from_sb3(agent)
    assert pol.output == "tanh" and np.max(np.abs(pol(x) - ref)) <= 1e-6


def test_numpy_policy_refuses_layers_that_do_not_fit():
    with pytest.raises(ValueError, match="layer 1"):
        NumpyPolicy((np.zeros((4, 1)), np.zeros((2, 3))), (np.zeros(4), np.zeros(2)))


def test_tuner_artefact_round_trip_and_query_determinism(tiny):
    t1, t2 = Tuner.load(tiny), Tuner.load(tiny)
    assert np.allclose(t1.policy(np.array([[0.3]])), t2.policy(np.array([[0.3]])), rtol=0, atol=0)
    a, b = t1.query({"K": 2.0, "T": 60.0, "L": 10.0}), t2.query({"K": 2.0, "T": 60.0, "L": 10.0})
    assert a.gains == b.gains and a.cost == b.cost and a.verdict == b.verdict
    doc = json.loads((tiny / "tuner.json").read_text())
    assert doc["format"] == artefact.FORMAT and doc["version"] == artefact.VERSION
    assert doc["training"]["episodes"] == TINY.episodes and doc["validation"]["n"] == TINY.validation


def test_training_into_a_folder_of_other_files_is_refused_before_it_starts_and_deletes_nothing(tmp_path):
    """Regression: 'tuner train SPEC --out precious' replaced the folder atomically, moving the old one aside and
    deleting it: the user's files in it were gone."""
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "notes.txt").write_text("mine")
    for out in (precious, ""):
        with pytest.raises(SpecError) as e:
            train(FamilyProblem("fotd", "pi", 1.4), out, TINY)
        assert e.value.field == "out"
    assert (precious / "notes.txt").read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["precious"]


def test_a_tuner_folder_is_an_ordinary_folder_and_is_replaced_by_a_new_save(tiny, tmp_path):
    import shutil
    import stat

    copy = tmp_path / "copy"
    shutil.copytree(tiny, copy)
    artefact.save(copy, artefact.load(tiny))  # a tuner folder is replaced
    assert stat.S_IMODE(copy.stat().st_mode) == 0o755 and (copy / "tuner.json").is_file()  # mkdtemp's was 0700
    assert stat.S_IMODE(tiny.stat().st_mode) == 0o755


@pytest.mark.parametrize("key, value, needle", [
    ("slots", [["nope", "Kp"], ["main", "Ki"]], "names nope.Kp, which its spec does not tune"),
    ("slots", [["main", "Kp"], ["main", "Zz"]], "unknown gain(s) ['Zz']"),
    ("lo", [0.1], "one lo, hi (and scale_axis) value per slot"),
    ("lo", [[1, 2], [3, 4]], "one lo, hi (and scale_axis) value per slot"),
    ("lo", [0.0, -1.0], "finite with 0 < lo < hi"),
])
def test_a_damaged_gain_box_is_refused_naming_the_tuner(tmp_path, key, value, needle):
    """Regression: a tuner.json whose box named a gain its spec lacks, or had the wrong number of bounds, passed
    the hash check (the box is not in policy.npz) and ended in a KeyError, zip or log traceback."""
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(artefact.resolve("fotd_pi_ms1.4"), bad)
    doc = json.loads((bad / "tuner.json").read_text())
    doc["box"][key] = value
    (bad / "tuner.json").write_text(json.dumps(doc))
    with pytest.raises(SpecError) as e:
        Tuner.load(bad)
    assert e.value.field == "tuner" and "is damaged" in e.value.message and needle in e.value.message


def test_a_tuner_whose_spec_is_damaged_says_which_field_in_one_line(tmp_path):
    """Regression: a reversed randomize range in tuner.json's spec printed pydantic's whole report, with its URL."""
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(artefact.resolve("water_tank_h0"), bad)
    doc = json.loads((bad / "tuner.json").read_text())
    doc["problem"]["spec"]["randomize"]["params"]["H0"] = {"dist": "uniform", "low": 20, "high": 2}
    (bad / "tuner.json").write_text(json.dumps(doc))
    with pytest.raises(SpecError) as e:
        Tuner.load(bad)
    assert e.value.field == "tuner" and "is damaged (randomize.params.H0: " in e.value.message
    assert "\n" not in e.value.message and "errors.pydantic.dev" not in e.value.message


def test_tuner_of_another_format_version_is_refused_naming_version(tiny, tmp_path):
    import shutil

    bad = tmp_path / "old"
    shutil.copytree(tiny, bad)
    doc = json.loads((bad / "tuner.json").read_text())
    doc["version"] = artefact.VERSION + 1
    (bad / "tuner.json").write_text(json.dumps(doc))
    with pytest.raises(SpecError) as e:
        Tuner.load(bad)
    assert e.value.field == "version"


def test_tampered_policy_arrays_are_refused_by_their_hash(tiny, tmp_path):
    import shutil

    bad = tmp_path / "tampered"
    shutil.copytree(tiny, bad)
    arrays = dict(np.load(bad / "policy.npz"))
    arrays["b0"] = arrays["b0"] + 1.0
    np.savez(bad / "policy.npz", **arrays)
    with pytest.raises(SpecError, match="hash"):
        Tuner.load(bad)


def test_pickled_object_in_policy_npz_is_never_loaded(tiny, tmp_path):
    import hashlib
    import shutil

    bad = tmp_path / "pickled"
    shutil.copytree(tiny, bad)
    np.savez(bad / "policy.npz", W0=np.array([object()], dtype=object), b0=np.zeros(1))
    doc = json.loads((bad / "tuner.json").read_text())
    doc["policy"]["sha256"] = hashlib.sha256((bad / "policy.npz").read_bytes()).hexdigest()
    (bad / "tuner.json").write_text(json.dumps(doc))
    with pytest.raises(SpecError, match="damaged"):
        Tuner.load(bad)


def test_plant_outside_the_training_family_is_refused_naming_l_over_t(tiny):
    with pytest.raises(OutsideFamilyError) as e:
        Tuner.load(tiny).query({"K": 1.0, "T": 1.0, "L": 30.0})
    assert e.value.field == "params.tau" and "L/T = 30" in e.value.message


def test_unknown_or_missing_parameter_is_refused_naming_it(tiny):
    t = Tuner.load(tiny)
    with pytest.raises(SpecError) as e:
        t.query({"K": 1.0, "T": 1.0})
    assert e.value.field == "params.L"
    with pytest.raises(SpecError) as e:
        t.query({"K": 1.0, "T": 1.0, "L": 1.0, "Q": 2.0})
    assert e.value.field == "params.Q"
    with pytest.raises(SpecError) as e:
        t.query({"K": -1.0, "T": 1.0, "L": 1.0})
    assert e.value.field == "params.K"


def test_failing_verdict_releases_no_gains(tiny):
    a = Tuner.load(tiny).query({"K": 2.0, "T": 60.0, "L": 10.0})
    a.verdict = "fail"
    assert a.accepted_gains is None and a.as_dict()["accepted_gains"] is None


def test_family_gains_scale_with_the_plant_so_the_cost_scales_by_k_tc():
    """Self-similarity: the unit plant's gains scaled to K=2, T=60, L=10 give cost K*tc times the unit cost."""
    fam = family("fotd")
    unit = {"Kp": 0.9, "Ki": 0.9}
    params = {"K": 2.0, "T": 60.0, "L": 10.0}
    shape = fam.shape_of(params)
    ev_u = Evaluator(problem_spec(fam, fam.unit_params(shape)))
    ev_r = Evaluator(problem_spec(fam, params))
    c_u = ev_u.evaluate(np.array([[unit["Kp"], unit["Ki"]]])).cost[0]
    real = fam.scale_gains(unit, params)
    c_r = ev_r.evaluate(np.array([[real["Kp"], real["Ki"]]])).cost[0]
    assert c_r / (2.0 * 70.0) == pytest.approx(c_u, rel=2e-3)


def test_feasible_interior_gains_are_moved_out_onto_the_boundary_when_that_lowers_the_cost():
    spec = problem_spec(family("fotd"), {"K": 1.0, "T": 1.0, "L": 0.5})
    ev = Evaluator(spec)
    timid = np.array([[0.1, 0.05]])  # Ms ~ 1.05: feasible, far inside
    move = onto_boundary(ev, timid)
    before = ev.evaluate(timid).cost[0]
    assert move.repaired[0] and move.alpha[0] > 1.5 and move.scores.cost[0] < before
    rep = verify(ev.spec, ev.layout.to_dict(ev.layout.full(move.tuned[0])), cache=False)
    assert rep.verdict == "pass"
    assert rep.loops[0].ms == pytest.approx(1.4, rel=3e-3)  # on the boundary, not inside it


def test_infeasible_gains_are_moved_inward_onto_the_boundary():
    spec = problem_spec(family("fotd"), {"K": 1.0, "T": 1.0, "L": 0.5})
    ev = Evaluator(spec)
    move = onto_boundary(ev, np.array([[3.0, 3.0]]))
    assert move.repaired[0] and move.alpha[0] < 1 and bool(move.scores.feasible[0])


def test_spec_problem_context_is_the_randomised_parameters():
    from gaintune.spec import load_spec

    spec = load_spec({"plant": {"tf": {"num": ["K"], "den": "T*s+1"}, "delay": 1.0, "params": {"K": 1.0, "T": 5.0}},
                      "loops": [{"type": "pi"}], "randomize": {"params": {"K": [0.5, 2.0]}}})
    p = SpecProblem(spec)
    assert [v.name for v in p.variables] == ["K"]
    at = p.spec_at({"K": 1.7})
    assert at.plant.params["K"] == 1.7 and not at.randomize.params
    with pytest.raises(SpecError) as e:
        p.context_of({"T": 3.0})
    assert e.value.field == "params.T"


def test_spec_without_randomize_cannot_train_a_tuner():
    from gaintune.spec import load_spec

    spec = load_spec({"plant": {"tf": {"num": [1], "den": "s+1"}}, "loops": [{"type": "pi"}]})
    with pytest.raises(SpecError) as e:
        SpecProblem(spec)
    assert e.value.field == "randomize.params"


def test_a_spec_tuner_over_a_parameter_the_plant_does_not_have_is_refused_naming_it():
    """Regression: 'tuner train' trained a tuner over randomize.params.Zq, which the plant does not have ('tune'
    refused the same spec), and querying it ended in a KeyError traceback."""
    from gaintune.spec import load_spec

    spec = load_spec({"plant": {"tf": {"num": ["K"], "den": "s+1"}, "params": {"K": 1.0}}, "loops": [{"type": "pi"}],
                      "randomize": {"params": {"Zq": [1.0, 2.0]}}})
    with pytest.raises(SpecError) as e:
        SpecProblem(spec)
    assert e.value.field == "randomize.params.Zq"


def test_a_context_range_with_a_negative_end_contains_both_its_ends():
    """Regression: the rounding tolerance was relative with the wrong sign below zero: H0 = -5 was outside -5 to 20."""
    from gaintune.tuners.problems import ContextVar

    v = ContextVar("x", -5.0, 20.0, False)
    assert v.contains(-5.0) and v.contains(20.0) and v.contains(0.0)
    assert not v.contains(-5.01) and not v.contains(20.01)


def test_refine_spends_at_most_n_simulations_and_none_when_n_is_1():
    """Regression: '--refine 1' ran 2 simulations (one of CMA-ES, one of the move), although N is the most."""
    tuner = Tuner.load("fotd_pi_ms1.4")
    for n in (1, 2, 5, 40):
        a = tuner.query({"K": 1.0, "T": 1.0, "L": 0.7}, refine=n)
        assert a.refined <= n and (a.refined == 0) == (n == 1)


def test_an_l_over_t_just_past_the_range_is_not_printed_as_the_ranges_end():
    """Regression: L = 601 s, T = 60 s was refused as 'L/T = 10 is outside ... (L/T from 0.05 to 10)'."""
    with pytest.raises(OutsideFamilyError) as e:
        Tuner.load("fotd_pi_ms1.4").query({"K": 1.0, "T": 60.0, "L": 601.0})
    assert "L/T = 10.02 is outside" in e.value.message
    with pytest.raises(OutsideFamilyError) as e:
        Tuner.load("fotd_pi_ms1.4").query({"K": 1.0, "T": 1e-300, "L": 10.0})
    assert "L/T = 1e+301 is outside" in e.value.message  # it was inf: L/T was recovered from the rounded tau


def test_the_optimum_of_a_reverse_acting_context_comes_from_the_search_when_migo_has_none():
    """Regression: 'tuner train' over K in [-5, -0.5] ended in MIGO's ValueError ('static gain must be positive')
    while validating; the validation's reference is then the search's, as for any problem MIGO does not cover."""
    from gaintune.spec import load_spec
    from gaintune.tuners.validation import context_optimum

    ev = Evaluator(load_spec({"plant": {"tf": {"num": [-2], "den": "5*s+1"}, "delay": 1}, "loops": [{"type": "pi"}],
                              "requirements": {"ms_max": 1.4}}))
    cost, how = context_optimum(ev)
    assert how == "reference search" and 0 < cost < float("inf")


def test_unstable_gains_are_scaled_to_a_stable_start_and_moved_onto_the_boundary():
    """onto_boundary_estimate leaves an unstable candidate as it is; a tuner's answer must not."""
    spec = problem_spec(family("fotd"), {"K": 1.0, "T": 1.0, "L": 0.5})
    ev = Evaluator(spec)
    wild = np.array([[40.0, 40.0]])
    assert ev.requirement_scores(wild)[0][0] >= 10  # unstable
    move = onto_boundary(ev, wild)
    assert bool(move.scores.feasible[0]) and move.alpha[0] < 0.1 and move.repaired[0]


def test_action_along_the_loop_gain_scale_changes_nothing_the_actor_could_drift_into():
    p = FamilyProblem("fotd", "pi", 1.4)
    from gaintune.tuners.box import fit_box

    box = fit_box(p)
    assert box.scale_axis is not None and box.scale_axis.tolist() == [1.0, 1.0]
    a = np.array([[0.1, -0.2]])
    along = 2 * 0.4 / (box.log_hi - box.log_lo)  # the same log-scale shift on every gain of the loop
    np.testing.assert_allclose(box.to_tuned(a), box.to_tuned(a + along), rtol=1e-12)
    ratio = box.to_tuned(a)[0]
    assert ratio[1] / ratio[0] != pytest.approx(box.to_tuned(np.array([[0.1, 0.4]]))[0][1]
                                                / box.to_tuned(np.array([[0.1, 0.4]]))[0][0])


def test_curve_every_adds_points_between_chunks_and_leaves_the_training_as_it_was(tiny, tmp_path):
    """``curve_every`` is a measurement: the same run with a point every 64 episodes trains the same policy."""
    import dataclasses

    fine = train(FamilyProblem("fotd", "pi", 1.4), tmp_path / "fine", dataclasses.replace(TINY, curve_every=64))
    doc = json.loads((fine / "tuner.json").read_text())
    coarse = json.loads((tiny / "tuner.json").read_text())
    assert [p["episodes"] for p in coarse["training"]["curve"]] == [0, 256, 512]
    assert [p["episodes"] for p in doc["training"]["curve"]] == [0, 64, 128, 192, 256, 320, 384, 448, 512]
    assert [p["sims"] for p in doc["training"]["curve"]][4::4] == [p["sims"] for p in coarse["training"]["curve"]][1:]
    a, b = Tuner.load(tiny).policy, Tuner.load(fine).policy
    assert all(np.array_equal(x, y) for x, y in zip(a.weights, b.weights, strict=True))


def test_curve_points_draw_no_random_numbers_the_training_uses(tiny):
    """The exploration noise (SB3's NormalActionNoise) draws from NumPy's global generator: a curve point
    taken between rollouts must leave it alone, so extra points never change the trained policy."""
    from gaintune.tuners.train import _curve_point

    tuner = Tuner.load(tiny)
    ctx = tuner.problem.centre()
    np.random.seed(5)
    before = np.random.get_state()[1].copy()
    _curve_point(tuner.problem, tuner.policy, [(ctx, 1.0)])
    assert np.array_equal(np.random.get_state()[1], before)


def test_curve_every_below_one_is_refused_naming_it():
    with pytest.raises(SpecError, match="curve_every"):
        TrainSettings(curve_every=0)


@pytest.mark.parametrize("params", [{"K": 1e8, "T": 1.0, "L": 1.0}, {"K": 1.0, "T": 1e7, "L": 1e7},
                                    {"K": 1e4, "T": 100.0, "L": 100.0}, {"K": 1e-10, "T": 1e-9, "L": 1e-9}])
def test_plants_far_from_the_unit_plant_get_the_unit_answer_scaled_and_verified(params):
    """Regression: K = 1e8 or T = L = 1e7 s failed ("simulation diverged": a signal past the default divergence
    bound of 1e6), and K = 1e4 passed with the cost 1e6 (a real cost called divergence). The family is
    self-similar: the answer is the unit plant's, scaled, its cost scaled by K tc, and it passes."""
    tuner = Tuner.load("fotd_pi_ms1.4")
    unit = tuner.query({"K": 1.0, "T": 1.0, "L": 1.0})
    a = tuner.query(params)
    K, tc = params["K"], params["T"] + params["L"]
    assert a.verdict == "pass"
    assert a.gains["main"]["Kp"] == pytest.approx(unit.gains["main"]["Kp"] / K, rel=1e-6)
    assert a.gains["main"]["Ki"] == pytest.approx(unit.gains["main"]["Ki"] * 2.0 / (K * tc), rel=1e-6)
    assert a.cost == pytest.approx(unit.cost * K * tc / 2.0, rel=1e-6)


def test_integrating_plant_on_a_time_scale_of_days_keeps_its_states_inside_the_divergence_bound():
    """Regression: an integrating plant's position state grows as the time scale squared; with T = L = 1e6 s
    and K = 1e-8 it passed a bound scaled by the time scale only, and the stable answer "diverged"."""
    tuner = Tuner.load("ipd_pi_ms1.4")
    unit, a = tuner.query({"K": 1.0, "T": 1.0, "L": 1.0}), tuner.query({"K": 1e-8, "T": 1e6, "L": 1e6})
    assert a.verdict == "pass", a.as_dict()["failures"]
    assert a.gains["main"]["Kp"] == pytest.approx(unit.gains["main"]["Kp"] * 2.0 / (1e-8 * 2e6), rel=1e-6)


def test_integrating_plant_with_a_small_velocity_gain_gets_the_unit_answer_scaled_and_passes():
    """Regression: K = 1e-6 with T = L = 1e3 s gave a C row of 1e-9, the observability test called the
    integrator unmeasured, and the stable answer failed as unstable (gaintune.lti.modes.observable_split)."""
    tuner = Tuner.load("ipd_pi_ms1.4")
    unit, a = tuner.query({"K": 1.0, "T": 1.0, "L": 1.0}), tuner.query({"K": 1e-6, "T": 1e3, "L": 1e3})
    assert a.verdict == "pass"
    # the integrating family's gain unit is K tc: 2 here against 2e-3 there
    assert a.gains["main"]["Kp"] == pytest.approx(unit.gains["main"]["Kp"] * 2.0 / 2e-3, rel=1e-6)


def test_a_failing_answer_says_why_in_its_json():
    """Regression: ``failures`` read an attribute the report does not have, so it was always empty; a JSON
    reader of a FAIL got no reason while the table printed one."""
    tuner = Tuner.load("fotd_pi_ms1.4")
    a = tuner.query({"K": 1.0, "T": 1.0, "L": 1.0})
    assert a.as_dict()["failures"] == []
    a.verdict, a.verification.reasons = "fail", ["closed loop unstable"]
    assert a.as_dict()["failures"] == ["closed loop unstable"] and a.as_dict()["accepted_gains"] is None


def test_second_order_plant_with_microsecond_lags_passes_with_the_unit_answer_scaled():
    """Regression: at T1 = 1 us the companion form's coupling looked like rounding to the observability
    test, a lag was split off as unmeasured and the stable answer failed as unstable."""
    tuner = Tuner.load("sotd_pi_ms1.4")
    unit = tuner.query({"K": 1.0, "T1": 1.0, "T2": 0.3, "L": 0.4})
    a = tuner.query({"K": 1.0, "T1": 1e-6, "T2": 0.3e-6, "L": 0.4e-6})
    assert a.verdict == "pass", a.as_dict()["failures"]
    assert a.gains["main"]["Ki"] == pytest.approx(unit.gains["main"]["Ki"] * 1e6, rel=1e-6)


def test_a_query_without_a_variable_whose_default_is_in_the_model_file_takes_that_default():
    """Regression: ``gaintune tuner query water_tank_h0`` without ``-p H0=...`` ended in a KeyError traceback: the
    nominal value was read from the spec's own plant params, and H0's (10 m) lives in models/water_tank.yaml."""
    tuner = Tuner.load("water_tank_h0")
    a = tuner.query({})
    assert a.context == {"H0": 10.0} and a.verdict == "pass"
    assert a.gains == tuner.query({"H0": 10.0}).gains
