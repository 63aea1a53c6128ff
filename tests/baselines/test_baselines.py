"""Baselines: FOTD fits with known answers, rule formulas by hand, optimisers, reference optimum."""

from __future__ import annotations

import math
import warnings

import control
import numpy as np
import pytest

from gaintune.baselines import METHODS, run_baseline
from gaintune.baselines.optimizers import optimize
from gaintune.classical import NoModelError, auto_bounds, fit_fotd, rule_candidates, tune_classical
from gaintune.classical import rules as R
from gaintune.classical.fotd import Fotd
from gaintune.controllers.layout import GainLayout
from gaintune.evaluation.search_box import search_box, search_layout
from gaintune.plants import build_plant
from gaintune.spec import load_spec

s = control.tf("s")

#: The former fixed defaults, given explicitly: the figures below were worked out at dt 0.01 s over 20 s.
TIMING = {"scenario": {"dt": 0.01, "horizon": 20.0}}
PID3 = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pid"}], **TIMING}
CASCADE = {
    "plant": {
        "ss": {"A": [[0, 1], [0, -10]], "B": [[0], [10]], "C": [[1, 0], [0, 1]], "outputs": ["pos", "vel"]},
        "delay": 0.02,
    },
    "loops": [{"name": "pos", "measure": "pos", "type": "p"}, {"name": "vel", "measure": "vel", "type": "pi"}],
    **TIMING,
}


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


class SimEvaluator:
    """Stand-in for gaintune.evaluation.evaluator.Evaluator: weighted IAE-type cost from the real simulator."""

    def __init__(self, spec):
        from gaintune.sim import Simulator

        self.spec = spec
        self.plant = build_plant(spec.plant)
        self.layout = search_layout(spec, self.plant)
        self.sim = Simulator(spec, self.plant, self.layout)
        self.n_sims = 0

    def __call__(self, tuned):
        t = np.atleast_2d(tuned)
        full = self.layout.full(t)
        ob = self.spec.objective
        total = np.zeros(len(t))
        for i, sc in enumerate(self.spec.scenarios):
            m = self.sim.run(full, scenario=i).metrics
            self.n_sims += len(t)
            c = m[ob.measure] + ob.effort_weight * m["effort"] + ob.tv_weight * m["tv"]
            total += sc.weight * np.where(m["diverged"] | ~np.isfinite(c), np.inf, c)
        return total

    def evaluate(self, tuned):
        """Scores with no requirements: only a diverged run is infeasible."""
        from gaintune.evaluation.evaluator import DIVERGED_COST, DIVERGED_VIOLATION, Scores

        c = self(tuned)
        bad = ~np.isfinite(c)
        return Scores(np.where(bad, DIVERGED_COST, c), np.where(bad, DIVERGED_VIOLATION, 0.0), bad, np.zeros_like(bad), {}, [])


# ----------------------------------------------------------------- FOTD fit


@pytest.mark.parametrize("method", ["auto", "step_fit", "two_point"])
def test_fotd_of_an_fotd_plant_is_exact(method):
    m = fit_fotd(2 / (3 * s + 1), delay=0.7, method=method)
    tol = 1e-6 if method != "two_point" else 2e-3
    assert m.K == pytest.approx(2.0, rel=1e-9)
    assert m.T == pytest.approx(3.0, rel=tol)
    assert m.L == pytest.approx(0.7, rel=tol)
    assert not m.integrating


@pytest.mark.parametrize("n", [2, 3, 4, 8])
def test_half_rule_published_values_for_lag_chain(n):
    # Skogestad (2003): 1/(s+1)^n -> T = 1 + 1/2, L = 1/2 + (n - 2); n = 3 gives T = L = 1.5.
    m = fit_fotd(1 / (s + 1) ** n)
    assert m.method == "half_rule"
    assert m.T == pytest.approx(1.5, abs=1e-9)
    assert m.L == pytest.approx(n - 1.5, abs=1e-9)


def test_half_rule_second_order_model_and_rhp_zero():
    m = fit_fotd(1 / (s + 1) ** 3)
    assert (m.T1, m.T2, m.L2) == pytest.approx((1.0, 1.5, 0.5))
    # An inverse-response zero (1 - a s) adds a to the delay.
    m = fit_fotd((1 - 0.5 * s) / (s + 1) ** 3, delay=0.2)
    assert (m.T, m.L) == pytest.approx((1.5, 2.2))
    # Distinct lags: 1/((s+1)(0.2s+1)(0.04s+1)(0.008s+1)) -> T = 1.1, L = 0.1 + 0.04 + 0.008.
    m = fit_fotd(1 / ((s + 1) * (0.2 * s + 1) * (0.04 * s + 1) * (0.008 * s + 1)))
    assert (m.T, m.L) == pytest.approx((1.1, 0.148))


@pytest.mark.parametrize("method", ["auto", "step_fit"])
def test_integrating_path(method):
    m = fit_fotd(2 / (s * (s + 1)), delay=1.0, method=method)
    assert m.integrating
    assert m.K == pytest.approx(2.0, rel=1e-6)
    assert m.L == pytest.approx(1.5, rel=1e-6)  # delay + half the remaining lag
    assert m.T2 == pytest.approx(1.0, rel=1e-6)


def test_step_fit_when_half_rule_does_not_apply():
    # A left-half-plane zero: the least-squares fit is used and matches the response.
    m = fit_fotd((0.5 * s + 1) / (s + 1) ** 3)
    assert m.method == "step_fit"
    assert m.K == pytest.approx(1.0)
    assert m.fit_error < 0.03
    with pytest.raises(NoModelError):
        fit_fotd((0.5 * s + 1) / (s + 1) ** 3, method="half_rule")


@pytest.mark.parametrize(
    "g, words",
    [
        (1 / (s**2 - 1), "unstable"),
        (4 / ((s + 1) * (s**2 + 0.4 * s + 4)), "oscillatory"),
        (1 / s**2, "integrators"),
        (s / (s + 1), "zero static gain"),
    ],
)
def test_no_fotd_model(g, words):
    with pytest.raises(NoModelError, match=words):
        fit_fotd(g)


# ------------------------------------------------------------------- rules

K, T, L = 2.0, 3.0, 0.7
M = Fotd(K, T, L, T1=T, T2=0.0, L2=L)


def test_simc_pi_by_hand():
    p = R.simc(M, "pi")
    assert p.Kc == pytest.approx(T / (K * (L + L)))
    assert p.Ti == pytest.approx(min(T, 4 * (L + L)))
    assert R.simc(M, "pi", tau_c=2.0).Kc == pytest.approx(T / (K * (2.0 + L)))
    mi = Fotd(0.5, 0.0, 0.4, integrating=True, L2=0.4)
    assert R.simc(mi, "pi").Kc == pytest.approx(1 / (0.5 * 0.8))
    assert R.simc(mi, "pi").Ti == pytest.approx(3.2)


def test_simc_pid_second_order_series_to_ideal():
    m = Fotd(1.0, 1.5, 1.0, T1=2.0, T2=0.8, L2=0.5)  # T2 >= L2/3: second-order SIMC
    kc, ti, td = 2.0 / (1.0 * (0.5 + 0.5)), min(2.0, 4 * 1.0), 0.8
    p = R.simc(m, "pid")
    assert p.Kc == pytest.approx(kc * (1 + td / ti))
    assert p.Ti == pytest.approx(ti + td)
    assert p.Td == pytest.approx(ti * td / (ti + td))
    # Nearly first order: improved SIMC, tau_D = L/3.
    q = R.simc(M, "pid")
    t1 = T + L / 3
    assert q.Kc == pytest.approx(t1 / (K * 2 * L) * (1 + (L / 3) / min(t1, 8 * L)))


def test_amigo_by_hand():
    p = R.amigo(M, "pi")
    assert p.Kc == pytest.approx(0.15 / K + (0.35 - L * T / (L + T) ** 2) * T / (K * L))
    assert p.Ti == pytest.approx(0.35 * L + 13 * L * T**2 / (T**2 + 12 * L * T + 7 * L**2))
    q = R.amigo(M, "pid")
    assert q.Kc == pytest.approx((0.2 + 0.45 * T / L) / K)
    assert q.Ti == pytest.approx(L * (0.4 * L + 0.8 * T) / (L + 0.1 * T))
    assert q.Td == pytest.approx(0.5 * L * T / (0.3 * L + T))
    # The integrating rules are the T -> inf limits.
    big = Fotd(1000.0 * 0.5, 1000.0, 0.4)
    mi = Fotd(0.5, 0.0, 0.4, integrating=True)
    assert R.amigo(mi, "pid").Kc == pytest.approx(R.amigo(big, "pid").Kc, rel=1e-3)
    assert R.amigo(mi, "pi").Ti == pytest.approx(R.amigo(big, "pi").Ti, rel=1e-2)


def test_ziegler_nichols_by_hand():
    a = K * L / T
    assert R.zn_step(M, "p").Kc == pytest.approx(1 / a)
    pi = R.zn_step(M, "pi")
    assert (pi.Kc, pi.Ti) == pytest.approx((0.9 / a, 3 * L))
    pid = R.zn_step(M, "pid")
    assert (pid.Kc, pid.Ti, pid.Td) == pytest.approx((1.2 / a, 2 * L, L / 2))
    u = R.zn_ultimate(8.0, 3.6, "pid")
    assert (u.Kc, u.Ti, u.Td) == pytest.approx((4.8, 1.8, 0.45))
    u = R.zn_ultimate(8.0, 3.6, "pi")
    assert (u.Kc, u.Ti) == pytest.approx((3.6, 3.0))
    assert R.zn_ultimate(8.0, 3.6, "p").Kc == pytest.approx(4.0)


def test_imc_by_hand():
    lam = max(T, 2 * L)
    assert R.imc(M, "pi").Kc == pytest.approx(T / (K * (lam + L)))
    assert R.imc(M, "pi").Ti == pytest.approx(T)
    p = R.imc(M, "pid", lam=1.0)
    assert (p.Kc, p.Ti, p.Td) == pytest.approx(((2 * T + L) / (K * (2 + L)), T + L / 2, T * L / (2 * T + L)))


def test_ultimate_gain_known_cases():
    Ku, Pu = R.ultimate_gain(control.ss(1 / (s + 1) ** 3))
    assert Ku == pytest.approx(8.0, rel=1e-8)
    assert Pu == pytest.approx(2 * math.pi / math.sqrt(3), rel=1e-8)
    # e^{-s}/(s+1): w + atan(w) = pi.
    Ku, Pu = R.ultimate_gain(control.ss(1 / (s + 1)), delay=1.0)
    from scipy.optimize import brentq

    w = brentq(lambda x: x + math.atan(x) - math.pi, 0.1, 3)
    assert Pu == pytest.approx(2 * math.pi / w, rel=1e-8)
    assert Ku == pytest.approx(math.sqrt(1 + w * w), rel=1e-8)
    with pytest.raises(NoModelError, match="never reaches"):
        R.ultimate_gain(control.ss(1 / (s + 1) ** 2))


@pytest.mark.parametrize("g, delay", [
    (1 / (s + 1) ** 3, 0.0), (1 / (s + 1), 1.0), (1 / (s * (s + 1)), 0.3), ((1 - 0.5 * s) / (s + 1) ** 2, 0.0),
    (4 / ((s + 1) * (s**2 + 0.4 * s + 4)), 0.0), (1 / (10 * s + 1), 0.05), (1 / ((s + 1) * (0.01 * s + 1)), 2.0),
], ids=["lag3", "fotd", "integrating", "nmp", "oscillatory", "fast_delay", "long_delay"])
def test_ultimate_gain_matches_a_brent_root_of_the_phase(g, delay):
    """The crossing refined on finer grids (no scipy.optimize import) is the root Brent's method finds to 1e-12."""
    from scipy.optimize import brentq

    Ku, Pu = R.ultimate_gain(control.ss(g), delay=delay)
    wu = 2 * math.pi / Pu

    def phase(w):  # angle of -G(jw)e^{-jw delay}: 0 where the loop is negative real, no wrap near it
        return float(np.angle(-control.evalfr(g, 1j * w) * np.exp(-1j * w * delay)))

    ref = brentq(phase, 0.95 * wu, 1.05 * wu, xtol=1e-14, rtol=1e-14)
    assert wu == pytest.approx(ref, rel=1e-11)
    assert Ku == pytest.approx(1 / abs(control.evalfr(g, 1j * ref)), rel=1e-10)


def test_rule_output_in_loop_form():
    spec = load_spec({**PID3, "loops": [{"type": "pid", "form": "ideal"}]})
    g = R.to_loop_gains(R.IdealPid(2.0, 4.0, 0.5), spec.loops[0])
    assert g == {"Kp": 2.0, "Ti": 4.0, "Td": 0.5}
    spec = load_spec(PID3)
    g = R.to_loop_gains(R.IdealPid(2.0, 4.0, 0.5), spec.loops[0])
    assert g == pytest.approx({"Kp": 2.0, "Ki": 0.5, "Kd": 1.0})
    # a negative process gain gives the mirror-image controller (reverse-acting): same Ti, Kc negated
    neg, pos = R.simc(Fotd(-1.0, 1.0, 1.0), "pi"), R.simc(Fotd(1.0, 1.0, 1.0), "pi")
    assert neg.Kc == -pos.Kc < 0 and neg.Ti == pos.Ti
    pi_loop = load_spec({**PID3, "loops": [{"type": "pi"}]}).loops[0]
    assert R.to_loop_gains(neg, pi_loop) == pytest.approx({"Kp": neg.Kc, "Ki": neg.Kc / neg.Ti})
    with pytest.raises(NoModelError, match="nonzero"):
        R.simc(Fotd(0.0, 1.0, 1.0), "pi")


# ------------------------------------------------------- applied to a spec


@pytest.mark.parametrize("ctype", ["p", "pi", "pd", "pid"])
@pytest.mark.parametrize("method", ["zn_step", "zn_ultimate", "simc", "amigo", "imc"])
def test_every_rule_gives_positive_gains_in_loop_form(method, ctype):
    spec = load_spec({**PID3, "loops": [{"type": ctype}]})
    res = tune_classical(spec, build_plant(spec.plant), method)
    names = {"p": ["Kp"], "pi": ["Kp", "Ki"], "pd": ["Kp", "Kd"], "pid": ["Kp", "Ki", "Kd"]}[ctype]
    assert list(res.gains["loop0"]) == names
    assert all(v > 0 and math.isfinite(v) for v in res.gains["loop0"].values())


def test_simc_on_spec_uses_half_sample_delay():
    spec = load_spec(PID3 | {"loops": [{"type": "pi"}]})
    res = tune_classical(spec, build_plant(spec.plant), "simc")
    Lh = 1.5 + 0.005  # half rule + dt/2
    assert res.gains["loop0"]["Kp"] == pytest.approx(1.5 / (2 * Lh))
    assert res.gains["loop0"]["Ki"] == pytest.approx(1.5 / (2 * Lh) / 1.5)


def test_fixed_gain_is_kept():
    spec = load_spec({**PID3, "loops": [{"type": "pid", "gains": {"Kd": {"tune": False, "value": 0.3}}}]})
    plant = build_plant(spec.plant)
    gains = tune_classical(spec, plant, "simc").gains
    assert gains["loop0"]["Kd"] == 0.3
    assert ("loop0", "Kd") not in auto_bounds(spec, gains)


def test_cascade_inner_first():
    spec = load_spec(CASCADE)
    res = tune_classical(spec, build_plant(spec.plant), "simc")
    # Inner path 10/(s+10) e^{-0.02 s}: T = 0.1, L = 0.02 + dt/2 -> Kc = 0.1/(2 L), Ti = min(0.1, 8 L).
    Li = 0.025
    assert res.gains["vel"]["Kp"] == pytest.approx(0.1 / (2 * Li))
    assert res.gains["vel"]["Ki"] == pytest.approx(0.1 / (2 * Li) / min(0.1, 8 * Li))
    # The outer loop sees the closed velocity loop plus the position integrator.
    assert res.fotd["pos"].integrating
    assert res.fotd["pos"].K == pytest.approx(1.0, rel=1e-4)
    assert res.fotd["pos"].L > Li
    assert list(res.gains) == ["pos", "vel"]


def test_lq_and_unstable_have_no_rule():
    lq = load_spec({**PID3, "loops": [{"type": "lqr"}]})
    r = run_baseline(lq, "simc", evaluator=None)
    assert r.gains is None and "LQ" in r.reason
    unstable = load_spec({"plant": {"tf": {"num": [1], "den": [1, 0, -1]}}, "loops": [{"type": "pid"}]})
    plant = build_plant(unstable.plant)
    with pytest.raises(NoModelError, match="unstable"):
        tune_classical(unstable, plant, "amigo")
    assert rule_candidates(unstable, plant) == {}
    box = search_box(unstable, plant)  # no rule: a Sobol sample of the default bounds centres the box
    assert box.source.startswith(("grid", "zoom")) and box.centre is not None
    assert search_box(lq, build_plant(lq.plant)).centre is None  # LQ: the layout's Riccati-based defaults


def test_auto_bounds_centred_on_the_given_gains():
    spec = load_spec(PID3)
    plant = build_plant(spec.plant)
    g = tune_classical(spec, plant, "simc").gains
    b = auto_bounds(spec, g)
    for name, v in g["loop0"].items():
        lo, hi = b[("loop0", name)]
        assert math.sqrt(lo * hi) == pytest.approx(v)
        assert hi / lo == pytest.approx(900.0)
    GainLayout(spec, plant.states, auto_bounds=b)  # accepted by the layout


def test_search_box_centres_on_the_best_rule_by_the_requirements():
    """Regression: the box was centred on SIMC whatever it gave; on the fast/slow process every
    candidate the search saw was unstable (Ki pinned at the box's lower bound 34.8)."""
    spec = load_spec({"plant": {"tf": {"num": [150, 55], "den": "(s+10)^2*(s+1)*(s+0.05)"}},
                      "loops": [{"name": "main", "type": "pi"}],
                      "scenario": {"dt": 0.02, "horizon": 60, "reference": {"kind": "none"},
                                   "disturbance": {"kind": "step", "amplitude": 1, "entry": "input"}},
                      "objective": {"effort_weight": 0}, "requirements": {"gm_min_db": None, "pm_min_deg": None, "ms_max": 1.4}})
    plant = build_plant(spec.plant)
    box = search_box(spec, plant)
    assert box.feasible and box.candidates[box.source][0]
    assert not box.candidates["simc"][0]  # SIMC itself does not meet Ms <= 1.4 here
    lay = box.layout
    start = lay.to_dict(lay.full(lay.initial_tuned()))["main"]
    assert start == pytest.approx(box.centre["main"])


# --------------------------------------------------------------- optimisers


class FakeLayout:
    def __init__(self, d):
        self.n_tuned = d
        self.log_lo = np.log(np.full(d, 1e-2))
        self.log_hi = np.log(np.full(d, 1e2))

    def initial_tuned(self):
        return np.ones(self.n_tuned)


class Bowl:
    """Quadratic bowl in log space, optimum at ``opt`` with cost 1; counts calls and simulations."""

    def __init__(self, opt, sims_per_row=1):
        self.opt = np.log(np.asarray(opt, float))
        self.layout = FakeLayout(len(opt))
        self.n_sims = 0
        self.calls = 0
        self.rows = []
        self.k = sims_per_row

    def __call__(self, tuned):
        t = np.atleast_2d(tuned)
        self.calls += 1
        self.rows.append(len(t))
        self.n_sims += self.k * len(t)
        c = 1.0 + ((np.log(t) - self.opt) ** 2).sum(axis=1)
        c[np.log(t)[:, 0] > np.log(50.0)] = np.inf  # a "diverging" corner
        return c


@pytest.mark.parametrize("method, tol", [("cmaes", 1e-6), ("de", 1e-4), ("nelder_mead", 1e-6), ("random", 0.3)])
@pytest.mark.parametrize("d", [1, 3])
def test_optimisers_find_the_bowl_minimum(method, tol, d):
    opt = np.array([3.0, 0.2, 7.0])[:d]
    ev = Bowl(opt)
    r = optimize(ev, method, budget=2000, seed=1)
    assert r.cost == pytest.approx(1.0, abs=tol)
    assert r.n_sims <= 2000 and ev.n_sims == r.n_sims
    if method != "random":
        assert np.allclose(np.log(r.tuned), np.log(opt), atol=math.sqrt(tol) * 3)


def test_population_methods_batch_their_calls():
    ev = Bowl([3.0, 0.2, 7.0])
    optimize(ev, "cmaes", budget=640, popsize=32)
    assert ev.calls == 20 and set(ev.rows) == {32}
    ev = Bowl([3.0, 0.2, 7.0])
    optimize(ev, "de", budget=640)
    assert ev.calls <= 640 // 24 + 2 and max(ev.rows) == 24


def test_budget_counts_simulations_not_rows():
    ev = Bowl([3.0, 0.2, 7.0], sims_per_row=4)
    r = optimize(ev, "cmaes", budget=1000, popsize=16)
    assert ev.n_sims <= 1000 and r.n_sims == ev.n_sims and r.n_evals == ev.n_sims // 4


# ------------------------------------------------- simulator-backed checks


def test_casadi_closed_loop_matches_simulator():
    from gaintune.baselines.reference import casadi_closed_loop

    for extra, loop in [
        ({}, {"type": "pid"}),
        ({"delay": 0.537}, {"type": "pid", "b": 0.7, "c": 1.0}),
        ({"delay": 0.3}, {"type": "pi", "form": "ideal", "b": 0.5}),
    ]:
        spec = load_spec(
            {
                "plant": {"tf": {"num": [1], "den": "(s+1)^3"}, **extra},
                "loops": [loop],
                "scenario": {"horizon": 20, "dt": 0.01, "disturbance": {"kind": "step", "time": 10, "amplitude": 0.5}},
            }
        )
        ev = SimEvaluator(spec)
        tuned = np.array([1.0, 0.5, 0.8]) if loop.get("form") != "ideal" else np.array([1.0, 2.0])
        m = ev.sim.run(ev.layout.full(tuned[None, :])).metrics
        J = np.asarray(casadi_closed_loop(spec, ev.plant, ev.layout, eps=0.0)(np.log(tuned))).ravel()
        for i, name in enumerate(("iae", "ise", "itae", "effort")):
            assert J[i] == pytest.approx(float(m[name][0]), rel=1e-9), name


def test_run_baseline_rules_and_optimisers_on_lag_chain():
    spec = load_spec(PID3)
    ev = SimEvaluator(spec)
    simc = run_baseline(spec, "simc", evaluator=ev)
    assert simc.cost is not None and simc.n_sims == 1 and simc.fotd["loop0"]["method"] == "half_rule"
    cma = run_baseline(spec, "cmaes", evaluator=ev, budget=1500, seed=0, settle_answer=False)
    assert cma.n_sims <= 1500
    assert cma.cost < simc.cost
    assert cma.history and cma.history[-1][1] == pytest.approx(cma.cost)
    BaselineJson = type(cma).model_validate_json(cma.model_dump_json())
    assert BaselineJson.gains == cma.gains


def test_reference_optimum_polish_agrees_with_cmaes():
    from gaintune.baselines.reference import reference_optimum

    spec = load_spec(PID3)
    ev = SimEvaluator(spec)
    r = reference_optimum(spec, ev, restarts=1, sims_per_restart=2000, seed=0)
    pol = r.details["parts"]["casadi_polish"]
    assert pol["status"] == "Solve_Succeeded"
    # The gradient polish and CMA-ES find the same optimum (IAE + 0.01 int u^2 ~ 1.6025).
    assert pol["cost"] == pytest.approx(r.details["parts"]["cmaes_0"]["cost"], rel=1e-4)
    assert r.cost == pytest.approx(1.6025, abs=2e-3)
    assert r.cost <= min(pol["cost"], r.details["parts"]["cmaes_0"]["cost"])


def test_methods_listed():
    assert set(METHODS) == {"zn_step", "zn_ultimate", "simc", "amigo", "imc", "random", "cmaes", "de", "nelder_mead", "reference"}
    with pytest.raises(ValueError, match="unknown baseline"):
        run_baseline(load_spec(PID3), "pso")


@pytest.mark.skipif(
    __import__("importlib").util.find_spec("gaintune.evaluation.evaluator") is None, reason="gaintune.evaluation.evaluator not written yet"
)
def test_integration_with_objective_evaluator():
    from gaintune.evaluation.evaluator import Evaluator

    spec = load_spec(PID3)
    ev = Evaluator(spec)
    rule = run_baseline(spec, "simc", evaluator=ev)
    assert rule.cost is not None and math.isfinite(rule.cost)
    for method in ("cmaes", "de", "random", "nelder_mead"):
        r = run_baseline(spec, method, evaluator=ev, budget=600, seed=0)
        assert r.n_sims <= 600 and r.cost is not None
        assert r.cost <= rule.cost * 1.5
    assert run_baseline(spec, "cmaes", evaluator=ev, budget=1500).cost < rule.cost
