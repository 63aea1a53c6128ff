"""Named benchmark suites: the problems ``gaintune bench search|compare`` run.

Every problem is a complete spec dict (inline plant or ``plant: {model: ...}``
with the model's example loops), with

* stated **requirements** (checked by :func:`gaintune.verification.verify`, reported
  as the verdict; they are not part of the cost),
* the **objective** IAE + 0.01 int u^2 unless the problem calls for another,
* a fixed **search budget** (at most 5,000 simulations) and ``search.n_envs`` 32,
* a horizon/dt of at most 4,000 steps, so that the budget fits in about a minute.

Benchmarks measure an optimiser against the optimum of a *deterministic*
cost, so the built-in models' domain randomisation is dropped (the nominal
plant is the problem). The processes follow Astrom & Hagglund, "Benchmark
Systems for PID Control" (2000).

Suites: ``default`` (10 problems), ``quick`` (3 tiny problems for tests) and
``full`` (default plus more A&H processes and the 3-loop DC-motor cascade).
The reference optima the benchmarks score against (and their cache) are in
:mod:`gaintune.bench.references`.

>>> [p.name for p in get_suite("quick")]
['q_lag2_pi', 'q_delay_pi', 'q_lq_msd']
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from gaintune.spec import TuningSpec, load_spec

__all__ = [
    "BenchCase",
    "SUITES",
    "MAX_BUDGET",
    "get_suite",
    "suite_names",
    "select",
    "suite_markdown",
    "describe_problems",
    "timed_row",
]

#: Largest search budget (simulations) a suite problem may set (5,000 everywhere except the
#: cascades suite's six-loop problem, whose 20,000 is the budget issue 12 states).
MAX_BUDGET = 20000
#: Largest number of steps (horizon / dt) of one scenario in a suite problem.
MAX_SUITE_STEPS = 4000

#: Default objective: IAE + 0.01 int u^2.
IAE_EFFORT = {"measure": "iae", "effort_weight": 0.01}
#: Textbook margins.
GM_PM = {"gm_min_db": 6.0, "pm_min_deg": 45.0, "ms_max": None}


def _ms(ms: float) -> dict[str, Any]:
    return {"gm_min_db": None, "pm_min_deg": None, "ms_max": ms}


@dataclass(frozen=True)
class BenchCase:
    """One benchmark problem.

    Attributes
    ----------
    name
        Short identifier (used on the command line and as a table row).
    title
        Plant and controller in words, e.g. ``1/(s+1)^3, PID``.
    spec
        Complete spec dict (validated by :meth:`tuning_spec`).
    family
        lag, nmp, delay, oscillatory, integrating, unstable, cascade, nonlinear, lq.
    reference
        Options of :func:`gaintune.baselines.reference.reference_optimum`.
    exact
        ``"dlqr"`` when the exact optimum is known (discrete Riccati), else None.
    note
        Anything a reader should know (why the reference is exact or not).
    """

    name: str
    title: str
    spec: dict[str, Any]
    family: str
    reference: dict[str, Any] = field(default_factory=dict)
    exact: str | None = None
    note: str = ""

    def tuning_spec(self, budget: int | None = None, seed: int | None = None) -> TuningSpec:
        """The validated spec, with the search budget and seed optionally replaced."""
        d = copy.deepcopy(self.spec)
        d.setdefault("name", self.name)
        s = d.setdefault("search", {})
        if budget is not None:
            s["budget"] = int(budget)
        if seed is not None:
            s["seed"] = int(seed)
        return load_spec(d)

    @property
    def budget(self) -> int:
        """The problem's own search budget (simulations; 3,000 when its spec gives none)."""
        return int(self.spec.get("search", {}).get("budget", 3000))

    @property
    def requirements(self) -> dict[str, float]:
        """The requirements that are set (None ones dropped), as the verdict checks them."""
        req = self.tuning_spec().requirements.model_dump()
        return {k: v for k, v in req.items() if v is not None}

    def requirements_text(self) -> str:
        """The set requirements in words, e.g. ``GM >= 6 dB, PM >= 45 deg, Mks auto``."""
        names = {"gm_min_db": "GM >= {:g} dB", "pm_min_deg": "PM >= {:g} deg", "ms_max": "Ms <= {:g}",
                 "mt_max": "Mt <= {:g}", "dm_min": "DM >= {:g} s", "wc_min": "wc >= {:g} rad/s",
                 "wc_max": "wc <= {:g} rad/s"}
        out = [names[k].format(v) for k, v in self.requirements.items() if k in names]
        mks = self.requirements.get("mks_max")
        if isinstance(mks, dict):
            out += [f"Mks({loop}) <= {v:g}" for loop, v in mks.items() if v is not None]
        elif mks is not None:
            out.append(f"Mks {mks}" if isinstance(mks, str) else f"Mks <= {mks:g}")
        return ", ".join(out)

    def objective_text(self) -> str:
        """The objective in words, e.g. ``IAE + 0.01 int u^2``."""
        ob = self.tuning_spec().objective
        txt = f"{ob.measure.upper()} + {ob.effort_weight:g} int u^2"
        return txt


def _tf(num: Any, den: Any, delay: float = 0.0) -> dict[str, Any]:
    p: dict[str, Any] = {"tf": {"num": num, "den": den}}
    if delay:
        p["delay"] = delay
    return p


def _pid(kind: str = "pid", **gains: tuple[float, float]) -> list[dict[str, Any]]:
    loop: dict[str, Any] = {"name": "main", "type": kind}
    if gains:
        loop["gains"] = {k: {"bounds": list(v)} for k, v in gains.items()}
    return [loop]


def _step(dt: float, horizon: float, **extra: Any) -> list[dict[str, Any]]:
    sc = {"name": "step", "dt": dt, "horizon": horizon, "reference": {"kind": "step", "amplitude": 1.0, "time": 0.0}}
    sc.update(extra)
    return [sc]


def _spec(plant, loops, scenarios, requirements, budget=3000, objective=None, **more) -> dict[str, Any]:
    d = {
        "plant": plant,
        "loops": loops,
        "scenarios": scenarios,
        "objective": dict(objective or IAE_EFFORT),
        "requirements": dict(requirements),
        "search": {"budget": budget, "n_envs": 32},
    }
    d.update(more)
    return d


def _model(name: str, budget: int, requirements: dict[str, Any] | None = None, **edits: Any) -> dict[str, Any]:
    """A built-in model's example spec, without randomisation, with a budget."""
    from gaintune.plants.library import load_model

    d = copy.deepcopy(load_model(name).example_spec())
    d.pop("description", None)
    d.pop("randomize", None)
    if requirements is not None:
        d["requirements"] = dict(requirements)
    d.update(edits)
    d["search"] = {"budget": budget, "n_envs": 32}
    return d


def _lq_msd(dt: float, horizon: float, budget: int) -> dict[str, Any]:
    """Mass-spring-damper, LQR in gains mode, regulation after an input impulse, ISE + 0.01 int u^2."""
    return {
        "plant": {"model": "mass_spring_damper"},
        "loops": [{
            "name": "lqr", "measure": "position", "type": "lqr", "lq_mode": "gains",
            "gains": {"k_x": {"bounds": [0.1, 100.0]}, "k_v": {"bounds": [0.01, 100.0]}},
        }],
        "scenarios": [{
            "name": "impulse", "dt": dt, "horizon": horizon,
            "reference": {"kind": "none"},
            "disturbance": {"kind": "impulse", "entry": "input", "amplitude": 1.0, "time": 0.0},
        }],
        "objective": {"measure": "ise", "effort_weight": 0.01},
        "requirements": dict(GM_PM),
        "search": {"budget": budget, "n_envs": 32},
    }


_LQ_NOTE = (
    "ISE + w int u^2 after a unit input impulse (x(dt) = Bd/dt, u(0) = 0) with u = -K x: the sampled cost is "
    "x1' P x1 with the discrete Riccati P for Q = C'C dt, R = w dt on the exact ZOH model, minimised over all K by "
    "the DARE gain for every x1. The exact optimum (up to the 10 s truncation) is that gain, scored by the simulator."
)

_REF_QUICK = {"restarts": 1, "sims_per_restart": 400, "polish": False}


def _default() -> list[BenchCase]:
    return [
        BenchCase("lag3_pid", "1/(s+1)^3, PID", _spec(_tf([1], "(s+1)^3"), _pid(), _step(0.01, 20.0), _ms(2.0)),
                  "lag"),
        BenchCase(
            "lags4_pid", "1/((1+s)(1+0.2s)(1+0.04s)(1+0.008s)), PID",
            _spec(_tf([1], "(s+1)*(0.2*s+1)*(0.04*s+1)*(0.008*s+1)"), _pid(), _step(0.005, 10.0), _ms(2.0)), "lag",
        ),
        BenchCase("nmp_pid", "(1-2s)/(s+1)^3, PID", _spec(_tf([-2, 1], "(s+1)^3"), _pid(), _step(0.02, 40.0), GM_PM),
                  "nmp"),
        BenchCase(
            "delay_pi", "e^{-s}/(1+0.1s), PI",
            _spec(_tf([1], [0.1, 1], delay=1.0), _pid("pi"), _step(0.01, 20.0), _ms(1.6)), "delay",
        ),
        BenchCase(
            "osc_pid", "4/((s+1)(s^2+0.4s+4)), PID (w0 = 2, zeta = 0.1)",
            _spec(_tf([4], "(s+1)*(s^2+0.4*s+4)"), _pid(), _step(0.01, 30.0), _ms(2.0)), "oscillatory",
            note="Oscillatory path: the FOTD rules do not apply, so the search box is the layout's default.",
        ),
        BenchCase(
            "integ_pid", "e^{-s}/(s(1+0.5s)), PID, setpoint step then load step",
            _spec(
                _tf([1], "s*(0.5*s+1)", delay=1.0), _pid(), _step(
                    0.02, 60.0, disturbance={"kind": "step", "entry": "input", "amplitude": -0.1, "time": 30.0}
                ), _ms(2.0),
            ), "integrating",
        ),
        BenchCase(
            "unstable_pid", "1/(s^2-1), PID",
            _spec(_tf([1], [1, 0, -1]), _pid(Kp=(1.2, 200.0), Ki=(0.01, 200.0), Kd=(0.05, 50.0)), _step(0.01, 10.0),
                  GM_PM),
            "unstable", note="Unstable plant: no rule applies; explicit bounds keep Kp > 1.",
        ),
        BenchCase(
            "quadrotor_cascade", "quadrotor_axis example: angle P -> rate PID (2 loops), saturated",
            _model("quadrotor_axis", 4000, GM_PM), "cascade",
        ),
        BenchCase(
            "water_tank", "water_tank example (nonlinear, sqrt outflow), PI, pump 0..10 V",
            _model("water_tank", 3000, GM_PM), "nonlinear",
        ),
        BenchCase(
            "lq_msd", "mass_spring_damper, LQR state feedback k_x, k_v (gains mode), input-impulse regulation",
            _lq_msd(0.01, 10.0, 2000), "lq", exact="dlqr", note=_LQ_NOTE,
        ),
    ]


def _extra() -> list[BenchCase]:
    """More Astrom & Hagglund processes and the 3-loop cascade (``full`` suite only)."""
    return [
        BenchCase("lag4_pid", "1/(s+1)^4, PID", _spec(_tf([1], "(s+1)^4"), _pid(), _step(0.01, 30.0), _ms(2.0)),
                  "lag"),
        BenchCase("lag8_pid", "1/(s+1)^8, PID", _spec(_tf([1], "(s+1)^8"), _pid(), _step(0.02, 60.0), _ms(2.0)),
                  "lag"),
        BenchCase(
            "lags_a05_pid", "1/((1+s)(1+0.5s)(1+0.25s)(1+0.125s)), PID",
            _spec(_tf([1], "(s+1)*(0.5*s+1)*(0.25*s+1)*(0.125*s+1)"), _pid(), _step(0.01, 20.0), _ms(2.0)), "lag",
        ),
        BenchCase("nmp05_pid", "(1-0.5s)/(s+1)^3, PID",
                  _spec(_tf([-0.5, 1], "(s+1)^3"), _pid(), _step(0.01, 30.0), GM_PM), "nmp"),
        BenchCase("nmp2_pi", "(1-2s)/(s+1)^3, PI",
                  _spec(_tf([-2, 1], "(s+1)^3"), _pid("pi"), _step(0.02, 60.0), GM_PM), "nmp"),
        BenchCase(
            "delay_fotd5_pi", "e^{-5s}/(s+1), PI",
            _spec(_tf([1], [1, 1], delay=5.0), _pid("pi"), _step(0.05, 100.0), _ms(1.6)), "delay",
        ),
        BenchCase(
            "delay_sotd_pid", "e^{-s}/(1+s)^2, PID",
            _spec(_tf([1], "(s+1)^2", delay=1.0), _pid(), _step(0.01, 30.0), _ms(2.0)), "delay",
        ),
        BenchCase(
            "osc_w1_pid", "1/((s+1)(s^2+0.2s+1)), PID (w0 = 1)",
            _spec(_tf([1], "(s+1)*(s^2+0.2*s+1)"), _pid(), _step(0.02, 60.0), _ms(2.0)), "oscillatory",
        ),
        BenchCase(
            "unstable_delay_pid", "e^{-0.2s}/(s-1), PID",
            _spec(_tf([1], [1, -1], delay=0.2), _pid(Kp=(1.05, 50.0), Ki=(0.01, 50.0), Kd=(0.001, 5.0)),
                  _step(0.01, 15.0), GM_PM),
            "unstable",
        ),
        BenchCase(
            "thermal_fotd", "thermal_fotd example: 2e^{-10s}/(60s+1), PI, setpoint and load scenarios",
            _model("thermal_fotd", 3000, _ms(1.6)), "delay",
        ),
        BenchCase(
            "dc_motor_cascade", "dc_motor example: position P -> speed PI -> current PI (3 loops)",
            _model("dc_motor", 5000, GM_PM), "cascade",
        ),
    ]


def _quick() -> list[BenchCase]:
    """Three small problems with tiny budgets (tests and smoke runs)."""
    lag = _spec(_tf([1], "(s+1)^2"), _pid("pi"), _step(0.05, 10.0), _ms(2.0), budget=160)
    dly = _spec(_tf([1], [1, 1], delay=0.5), _pid("pi"), _step(0.05, 10.0), GM_PM, budget=160)
    lq = _lq_msd(0.02, 8.0, 160)
    return [
        BenchCase("q_lag2_pi", "1/(s+1)^2, PI (quick)", lag, "lag", reference=dict(_REF_QUICK)),
        BenchCase("q_delay_pi", "e^{-0.5s}/(s+1), PI (quick)", dly, "delay", reference=dict(_REF_QUICK)),
        BenchCase("q_lq_msd", "mass_spring_damper LQR gains (quick)", lq, "lq", reference=dict(_REF_QUICK),
                exact="dlqr", note=_LQ_NOTE),
    ]


def _standard() -> list[BenchCase]:
    from gaintune.bench.standard import standard_problems

    return standard_problems(BenchCase)


def _cascades() -> list[BenchCase]:
    from gaintune.bench.standard import cascade_problems

    return cascade_problems(BenchCase, _model)


SUITES: dict[str, Any] = {
    "default": _default,
    "quick": _quick,
    "full": lambda: _default() + _extra(),
    "standard": _standard,
    "cascades": _cascades,
}


def suite_names() -> list[str]:
    """Names of the benchmark suites."""
    return list(SUITES)


def get_suite(name: str = "default") -> list[BenchCase]:
    """The problems of suite ``name``; unknown names raise ValueError listing the known ones."""
    if name not in SUITES:
        raise ValueError(f"unknown suite {name!r}; choose from {', '.join(SUITES)}")
    return SUITES[name]()


def select(problems: list[BenchCase], names: list[str] | None) -> list[BenchCase]:
    """Keep the named problems (in the order given); unknown names raise ValueError."""
    if not names:
        return problems
    by = {p.name: p for p in problems}
    unknown = [n for n in names if n not in by]
    if unknown:
        raise ValueError(f"unknown problem(s) {unknown}; this suite has {', '.join(by)}")
    return [by[n] for n in names]


def suite_markdown(problems: list[BenchCase]) -> str:
    """Markdown table of a suite: problem, plant/controller, objective, requirements, budget, steps."""
    lines = ["| problem | plant, controller | objective | requirements | budget | dt, horizon (steps) |",
             "|---|---|---|---|---|---|"]
    for p in problems:
        spec = p.tuning_spec()
        sc = ", ".join(f"{s.dt:g} s, {s.horizon:g} s ({s.n_steps})" for s in spec.scenarios)
        lines.append(f"| {p.name} | {p.title} | {p.objective_text()} | {p.requirements_text()} | {p.budget} | {sc} |")
    return "\n".join(lines)


def describe_problems(problems, budget: int | None = None) -> list[dict[str, Any]]:
    """The problem descriptions stored with every benchmark result (JSON-able)."""
    return [{"name": p.name, "title": p.title, "family": p.family, "budget": budget or p.budget,
             "requirements": p.requirements_text(), "objective": p.objective_text()} for p in problems]


def timed_row(run: Callable[[], dict[str, Any]], on_error: dict[str, Any]) -> tuple[dict[str, Any], float]:
    """Run one benchmark cell; a crash becomes a row (``on_error`` + ``error``), never a lost table."""
    t0 = time.perf_counter()
    try:
        row = run()
    except Exception as exc:  # one broken method or run must not lose the whole table
        row = {**on_error, "error": f"{type(exc).__name__}: {exc}"}
    return row, time.perf_counter() - t0
