"""The ``standard`` suite: constrained PI/PID tuning on the Åström–Hägglund test batch.

Two sets, both with requirements that bind (the suite separates methods only when
the unconstrained optimum lies beyond a limit):

* **load**: a unit load step at the plant input, cost = load-disturbance IAE (no
  effort term), requirement **Ms <= 1.4** (MIGO/AMIGO; **2.0** for the unstable
  process), PI and PID on the processes of Åström & Hägglund, "Benchmark systems
  for PID control" (2000): lags, spread lags, non-minimum phase, FOTD with L/T
  0.1 to 10, oscillatory, integrating, unstable, the fast/slow process of
  issue 12 and the thermal FOTD 2e^{-10s}/(60s+1).
* **track**: a unit setpoint step, cost = IAE + 0.01 int u^2, requirement
  **PM >= 60 deg** (pidtune's default target), PI.

The reference of every PI problem with an Ms limit is the constrained **MIGO
optimum** (:mod:`gaintune.classical.migo`): max ki subject to Ms <= limit, then the
load IAE minimised along the constraint boundary ``ki = ki_max(kp)``, computed on
the same loop as verification (the sampled loop: ZOH plant with its delay and the
backward-Euler integral; the continuous loop plus dt/2 when ``verify.sampled`` is off)
and scored by the simulator. It is independent of the searches; the multistart reference search
runs as well and the better of the two (feasibility first) is the reference.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from gaintune.baselines.migo_reference import migo_reference

__all__ = [
    "standard_problems", "cascade_problems", "six_lag_cascade", "migo_reference", "STANDARD_MS",
    "STANDARD_MS_UNSTABLE",
]

#: The sensitivity limit of the load set (MIGO / AMIGO).
STANDARD_MS = 1.4
#: The limit for the open-loop unstable process.
STANDARD_MS_UNSTABLE = 2.0

#: (name, title, num, den, delay, dt, horizon, family)
_PROCESSES: list[tuple[str, str, Any, Any, float, float, float, str]] = [
    ("lag3", "1/(s+1)^3", [1], "(s+1)^3", 0.0, 0.05, 40.0, "lag"),
    ("lag8", "1/(s+1)^8", [1], "(s+1)^8", 0.0, 0.1, 120.0, "lag"),
    ("lags02", "1/((1+s)(1+0.2s)(1+0.04s)(1+0.008s))", [1], "(s+1)*(0.2*s+1)*(0.04*s+1)*(0.008*s+1)", 0.0, 0.004,
     12.0, "lag"),
    ("nmp05", "(1-0.5s)/(s+1)^3", [-0.5, 1], "(s+1)^3", 0.0, 0.05, 40.0, "nmp"),
    ("fotd01", "e^{-s}/(1+10s) (L/T = 0.1)", [1], [10, 1], 1.0, 0.05, 60.0, "delay"),
    ("fotd1", "e^{-s}/(1+s) (L/T = 1)", [1], [1, 1], 1.0, 0.02, 30.0, "delay"),
    ("fotd10", "e^{-s}/(1+0.1s) (L/T = 10)", [1], [0.1, 1], 1.0, 0.01, 30.0, "delay"),
    ("osc2", "4/((s+1)(s^2+0.4s+4)) (w0 = 2, zeta = 0.1)", [4], "(s+1)*(s^2+0.4*s+4)", 0.0, 0.02, 60.0,
     "oscillatory"),
    ("integ", "e^{-s}/(s(1+0.5s))", [1], "s*(0.5*s+1)", 1.0, 0.02, 60.0, "integrating"),
    ("unstable", "e^{-0.1s}/(s-1)", [1], [1, -1], 0.1, 0.005, 15.0, "unstable"),
    ("fastslow", "(100(s+0.05)+50(s+1))/((s+10)^2(s+1)(s+0.05))", [150, 55], "(s+10)^2*(s+1)*(s+0.05)", 0.0, 0.02,
     60.0, "lag"),
    ("thermal", "2e^{-10s}/(60s+1)", [2], [60, 1], 10.0, 0.5, 600.0, "delay"),
]

#: Processes of the tracking set (PM >= 60 deg).
_TRACK = ("lag3", "nmp05", "fotd1", "thermal")


def _plant(num: Any, den: Any, delay: float) -> dict[str, Any]:
    p: dict[str, Any] = {"tf": {"num": num, "den": den}}
    if delay:
        p["delay"] = delay
    return p


def standard_problems(problem_cls: Callable[..., Any]) -> list[Any]:
    """The suite's problems as ``problem_cls(name, title, spec, family, reference=..., exact=..., note=...)``."""
    out: list[Any] = []
    ref_opts = {"restarts": 3, "sims_per_restart": 4000, "polish": False}
    for name, title, num, den, delay, dt, horizon, family in _PROCESSES:
        ms = STANDARD_MS_UNSTABLE if family == "unstable" else STANDARD_MS
        for kind in ("pi", "pid"):
            spec = {
                "plant": _plant(num, den, delay),
                "loops": [{"name": "main", "type": kind}],
                "scenarios": [{"name": "load", "dt": dt, "horizon": horizon, "reference": {"kind": "none"},
                               "disturbance": {"kind": "step", "entry": "input", "amplitude": 1.0, "time": 0.0}}],
                "objective": {"measure": "iae", "effort_weight": 0.0},
                "requirements": {"gm_min_db": None, "pm_min_deg": None, "ms_max": ms},
                "search": {"budget": 5000, "n_envs": 32},
            }
            exact = "migo" if kind == "pi" and family != "unstable" else None
            out.append(problem_cls(f"std_{name}_{kind}", f"{title}, {kind.upper()}, load step, Ms <= {ms:g}", spec,
                                   family, reference=dict(ref_opts), exact=exact,
                                   note="reference: MIGO boundary optimum vs multistart search" if exact else ""))
    for name, title, num, den, delay, dt, horizon, family in _PROCESSES:
        if name not in _TRACK:
            continue
        spec = {
            "plant": _plant(num, den, delay),
            "loops": [{"name": "main", "type": "pi"}],
            "scenarios": [{"name": "step", "dt": dt, "horizon": horizon,
                           "reference": {"kind": "step", "amplitude": 1.0, "time": 0.0}}],
            "objective": {"measure": "iae", "effort_weight": 0.01},
            "requirements": {"gm_min_db": None, "pm_min_deg": 60.0, "ms_max": None},
            "search": {"budget": 5000, "n_envs": 32},
        }
        out.append(problem_cls(f"std_{name}_pi_track", f"{title}, PI, setpoint step, PM >= 60 deg", spec, family,
                               reference=dict(ref_opts)))
    return out


def six_lag_cascade(budget: int = 20000) -> dict[str, Any]:
    """Six PI loops in cascade on six first-order lags (time constants 0.1 to 3.2 s), 12 gains (issue 12).

    The innermost loop measures the fastest lag; a unit setpoint step on the outermost output,
    IAE + 0.01 int u^2, dt 0.01 s, 30 s; the default requirements (GM >= 6 dB, PM >= 45 deg, Ms <= 2).
    """
    taus = [0.1, 0.2, 0.4, 0.8, 1.6, 3.2]
    n = len(taus)
    A = [[0.0] * n for _ in range(n)]
    for i, tau in enumerate(taus):
        A[i][i] = -1.0 / tau
        if i:
            A[i][i - 1] = 1.0 / tau
    return {
        "name": "six_lag_cascade",
        "plant": {"ss": {"A": A, "B": [[1.0 / taus[0]]] + [[0.0]] * (n - 1),
                         "C": [[1.0 if j == i else 0.0 for j in range(n)] for i in range(n)],
                         "outputs": [f"y{i + 1}" for i in range(n)], "states": [f"x{i + 1}" for i in range(n)]}},
        "loops": [{"name": f"loop_y{i}", "measure": f"y{i}", "type": "pi"} for i in range(n, 0, -1)],
        "scenarios": [{"name": "step", "dt": 0.01, "horizon": 30.0, "reference": {"kind": "step", "amplitude": 1.0}}],
        "objective": {"measure": "iae", "effort_weight": 0.01},
        "search": {"budget": budget, "n_envs": 32},
    }


def cascade_problems(problem_cls: Callable[..., Any], model_spec: Callable[[str, int], dict[str, Any]]) -> list[Any]:
    """The ``cascades`` suite: the six-lag cascade (20,000 simulations), the DC-motor and quadrotor cascades."""
    ref = {"restarts": 2, "sims_per_restart": 5000, "polish": False}
    return [
        problem_cls("six_lag_cascade", "six PI loops on six lags 0.1..3.2 s (12 gains), setpoint step",
                    six_lag_cascade(), "cascade", reference=dict(ref)),
        problem_cls("dc_motor_cascade", "dc_motor example: position P -> speed PI -> current PI",
                    model_spec("dc_motor", 5000), "cascade", reference=dict(ref)),
        problem_cls("quadrotor_cascade", "quadrotor_axis example: angle P -> rate PID",
                    model_spec("quadrotor_axis", 5000), "cascade", reference=dict(ref)),
    ]
