"""Reference optimum: the best cost we can find with a large budget, to measure search gaps against.

Built in up to three parts, each scored by the evaluator (the same cost the
RL search sees); the best one is the reference:

1. **Multistart CMA-ES**: ``restarts`` runs (default 4) of ``sims_per_restart``
   simulations (default 5,000), the first from the layout's initial point
   (the classical rule when auto bounds are in use), the others from random
   points, sigma0 = 0.3, population 32.
2. **Gradient polish** (only when the problem is differentiable: LTI plant,
   one PID loop, no saturation, rate limit, noise, randomisation, safety
   monitor or non-smooth penalties, no direct feedthrough): single shooting
   with casadi + IPOPT (L-BFGS Hessian) over the log-gains, from the CMA-ES
   best, through a casadi model of the SAME discrete closed loop the simulator
   runs (matrices, delay buffer, signals and metric sums are taken from
   :class:`gaintune.sim.build.SimSetup`): exact ZOH with fractional delay
   ``x[k+1] = Ad x[k] + G0 u[k-d] + G1 u[k-d-1]``, backward-Euler PID
   ``I[k] = I[k-1] + Ki dt e[k]``,
   ``D[k] = (Tf D[k-1] + Kd (ed[k] - ed[k-1]))/(Tf + dt)``, ``u = Kp (b r - y) + I + D``.
   |e| and |du| are smoothed as ``sqrt(x^2 + eps^2)`` for the gradient phase;
   the result is re-scored with the evaluator.
3. **Riccati candidate** for an LQ loop in ``weights`` mode: Q = C'C/effort_weight
   (diagonal part), R = 1 - the exact LQR optimum of the regulation problem
   with the objective's quadratic weights; exact for ``measure: ise`` only in
   that sense, and scored like the rest.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from gaintune.baselines.optimizers import BAD_COST, OptResult, cmaes_search
from gaintune.evaluation.evaluator import merit
from gaintune.spec import TuningSpec

__all__ = ["reference_optimum", "differentiable_reason", "casadi_closed_loop", "casadi_polish", "riccati_candidate"]


def differentiable_reason(spec: TuningSpec, plant: Any) -> str | None:
    """None when the gradient polish applies, else why not."""
    if plant.kind != "lti":
        return "nonlinear plant"
    if len(spec.loops) != 1:
        return "cascade (gradient polish covers one loop)"
    loop = spec.loops[0]
    if loop.is_lq:
        return "LQ loop"
    if spec.actuator.limits is not None or spec.actuator.rate_limit is not None or loop.output_limits is not None:
        return "saturation or rate limit"
    if any(sc.noise_std > 0 for sc in spec.scenarios):
        return "measurement noise"
    if spec.randomize.active or spec.search.robust.samples > 1:
        return "randomised plant or scenarios"
    ob = spec.objective
    if ob.overshoot_weight > 0 or ob.settling_weight > 0:
        return "non-smooth overshoot/settling penalties"
    sf = spec.safety
    if sf.max_abs_error is not None or sf.max_abs_output is not None or sf.state_bounds:
        return "safety monitor"
    lin = plant.linearize()
    m = lin.output_index(loop.measure) if loop.measure else 0
    if np.any(lin.D[m] != 0):
        return "direct feedthrough"
    return None


def _signals(sg: dict[str, np.ndarray], n_steps: int, dt: float) -> np.ndarray:
    """(3, n_steps) reference, input and output disturbance, as the kernel's ``_signal`` builds them."""
    k = np.arange(n_steps)
    out = np.zeros((3, n_steps))
    for s in range(3):
        for p in range(sg["sk0"].shape[1]):
            k0, k1 = sg["sk0"][s, p, 0], sg["sk1"][s, p, 0]
            on = (k >= k0) & (k < k1)
            out[s] += on * (sg["soff"][s, p, 0] + sg["sslope"][s, p, 0] * (k - k0) * dt)
    return out


@dataclass(frozen=True)
class _DiscreteLoop:
    """The simulator's discrete closed-loop data for one scenario on the nominal draw (see :class:`SimSetup`)."""

    Ad: np.ndarray  # (n, n) exact ZOH state matrix
    G0: np.ndarray  # (n,) input of u[k-d]
    G1: np.ndarray  # (n,) input of u[k-d-1] (fractional delay)
    Cm: np.ndarray  # (n,) measured output row
    dly: int  # whole delay steps
    n_steps: int
    dt: float
    sig: np.ndarray  # (3, n_steps) reference, input and output disturbance


def _discrete_loop(spec: TuningSpec, plant: Any, layout: Any, scenario: int) -> _DiscreteLoop:
    """Matrices, delay and signals of scenario ``scenario``, taken from the simulator's own setup."""
    from gaintune.sim import draws as draws_mod
    from gaintune.sim.build import SimSetup

    sc = spec.scenarios[scenario]
    pb = SimSetup.build(spec, plant, layout)
    d0 = draws_mod.nominal(spec, plant, 1, seed=spec.search.seed)
    pa = pb.plant_arrays(d0, sc)
    sg = pb.signal_arrays(d0, sc)
    N = sc.n_steps  # raises unless the scenario's dt and horizon are resolved
    assert sc.dt is not None
    dt = sc.dt
    return _DiscreteLoop(
        pa["Ad"][:, :, 0], pa["G0"][:, 0], pa["G1"][:, 0], pa["Cm"][0, :, 0], int(pa["dsteps"][0]), N, dt,
        _signals(sg, N, dt),
    )


def _pid_parameters(loop: Any, layout: Any, w: Any) -> Any:
    """casadi vector (Kp, Ki, Kd, Tf) of the loop's parallel PID as functions of the log-gains ``w``."""
    import casadi as ca

    full: list[Any] = [float(v) if not np.isnan(v) else 0.0 for v in layout.fixed]
    signs = getattr(layout, "tuned_signs", np.ones(layout.n_tuned))
    for j, k in enumerate(layout.tuned_idx):
        # the search works on magnitudes; a reverse-acting loop's gains are negative
        full[k] = (-1.0 if signs[j] < 0 else 1.0) * ca.exp(w[j])
    g = {s.name: full[k] for k, s in enumerate(layout.slots)}
    t = loop.type
    kp = g.get("Kp", 0.0)
    if loop.form == "ideal":
        ki = kp / g["Ti"] if "i" in t[1:] else 0.0
        kd = kp * g["Td"] if "d" in t[1:] else 0.0
    else:
        ki = g["Ki"] if "i" in t[1:] else 0.0
        kd = g["Kd"] if "d" in t[1:] else 0.0
    if "d" in t[1:]:
        tf = loop.filter.Tf if loop.filter.Tf is not None else kd / kp / (loop.filter.N or 10.0)
    else:
        tf = 0.0
    return ca.vertcat(kp, ki, kd, tf)


def _step_function(dl: _DiscreteLoop, b: float, c: float, eps: float) -> Any:
    """casadi ``step(state, input, (Kp, Ki, Kd, Tf)) -> next state`` of the closed loop.

    State: [x (n), ubuf (dly+1), I, D, edp, uprev, J (5)]; input: [r, din, dout, t, tvflag].
    """
    import casadi as ca

    n, dly, dt = dl.Ad.shape[0], dl.dly, dl.dt
    nb = dly + 1
    ns = n + nb + 4 + 5
    s = ca.SX.sym("s", ns)
    u_in = ca.SX.sym("in", 5)
    p = ca.SX.sym("p", 4)
    x, ubuf = s[:n], s[n : n + nb]
    integ, deriv, edp, uprev = s[n + nb], s[n + nb + 1], s[n + nb + 2], s[n + nb + 3]
    J = s[n + nb + 4 :]
    r, din, dout, tk, tvf = (u_in[i] for i in range(5))
    Kp, Ki, Kd, Tf = (p[i] for i in range(4))
    y = ca.dot(ca.DM(dl.Cm), x) + dout
    e = r - y
    ed = c * r - y
    deriv_n = (Tf * deriv + Kd * (ed - edp)) / (Tf + dt)
    integ_n = integ + Ki * dt * e
    u = Kp * (b * r - y) + integ_n + deriv_n
    ua = u if dly == 0 else ubuf[dly - 1]
    ub = ubuf[dly]
    xn = ca.mtimes(ca.DM(dl.Ad), x) + ca.DM(dl.G0) * (ua + din) + ca.DM(dl.G1) * (ub + din)
    ubn = ca.vertcat(u, ubuf[: nb - 1]) if nb > 1 else u
    ae = ca.sqrt(e**2 + eps**2) if eps > 0 else ca.fabs(e)
    du = u - uprev
    adu = ca.sqrt(du**2 + eps**2) if eps > 0 else ca.fabs(du)
    Jn = J + ca.vertcat(ae * dt, e**2 * dt, tk * ae * dt, u**2 * dt, tvf * adu)
    return ca.Function("step", [s, u_in, p], [ca.vertcat(xn, ubn, integ_n, deriv_n, ed, u, Jn)])


def casadi_closed_loop(
    spec: TuningSpec, plant: Any, layout: Any, scenario: int = 0, eps: float | None = None, rel_eps: float = 1e-4
) -> Any:
    """casadi Function ``J(log_tuned) -> [iae, ise, itae, effort, tv]`` (smoothed |.|) for one scenario.

    Mirrors :func:`gaintune.sim.kernel.simulate_kernel` for one LTI PID loop on
    the nominal draw. |x| is smoothed as sqrt(x^2 + eps^2) with ``eps`` (default
    ``rel_eps`` times the largest signal value); ``eps=0`` gives the exact sums.

    Parameters
    ----------
    spec, plant, layout
        The problem, its built plant and gain layout (the evaluator's).
    scenario
        Index of the scenario in ``spec.scenarios`` (its dt and horizon resolved).
    eps, rel_eps
        Absolute smoothing of |.|, or (when ``eps`` is None) relative to the largest signal.

    Returns
    -------
    casadi.Function
        ``J(w)`` of the log tuned gains ``w`` (``layout.n_tuned``), a 5-vector.
    """
    import casadi as ca

    loop = spec.loops[0]
    dl = _discrete_loop(spec, plant, layout, scenario)
    sig, N = dl.sig, dl.n_steps
    if eps is None:
        eps = rel_eps * max(float(np.max(np.abs(sig[0]))), float(np.max(np.abs(sig[1:]))), 1e-9)
    w = ca.MX.sym("w", layout.n_tuned)
    par = _pid_parameters(loop, layout, w)
    step = _step_function(dl, loop.b, loop.c, eps)
    roll = step.mapaccum("roll", N)
    inputs = np.vstack([sig, np.arange(N) * dl.dt, np.ones(N)])  # TV counts the first move from u0 too
    n, nb = dl.Ad.shape[0], dl.dly + 1
    s0 = np.zeros(n + nb + 4 + 5)
    s0[n + nb + 2] = loop.c * sig[0, 0] - sig[2, 0]  # ed at k = 0: no derivative kick
    traj = roll(ca.DM(s0), ca.DM(inputs), par)
    Jend = traj[n + nb + 4 :, N - 1]
    return ca.Function("J", [w], [Jend], ["w"], ["J"])


def _scalar_cost(spec: TuningSpec, plant: Any, layout: Any, rel_eps: float) -> tuple[Any, Any]:
    import casadi as ca

    ob = spec.objective
    w = ca.MX.sym("w", layout.n_tuned)
    idx = {"iae": 0, "ise": 1, "itae": 2}[ob.measure]
    total = 0
    for i, sc in enumerate(spec.scenarios):
        if sc.weight == 0:
            continue
        Jf = casadi_closed_loop(spec, plant, layout, i, rel_eps=rel_eps)
        J = Jf(w)
        total = total + sc.weight * (J[idx] + ob.effort_weight * J[3] + ob.tv_weight * J[4])
    return w, total


#: Smoothing continuation for |.|: eps relative to the largest signal, warm-started stage by stage.
EPS_STAGES = (1e-3, 1e-5, 1e-7)


def casadi_polish(
    spec: TuningSpec,
    plant: Any,
    layout: Any,
    tuned0: np.ndarray,
    max_iter: int = 150,
    eps_stages: tuple[float, ...] = EPS_STAGES,
) -> tuple[np.ndarray, dict[str, Any]]:
    """IPOPT single shooting from ``tuned0`` over the log-gains; returns (tuned, info).

    |e| is smoothed as sqrt(e^2 + eps^2) with eps shrinking over ``eps_stages``
    (relative to the largest reference/disturbance value), each stage started
    from the previous answer.
    """
    import casadi as ca

    t0 = time.perf_counter()
    x = np.clip(np.log(np.asarray(tuned0, float)), layout.log_lo, layout.log_hi)
    stats: dict = {}
    for rel in eps_stages:
        w, J = _scalar_cost(spec, plant, layout, rel)
        solver = ca.nlpsol(
            "polish",
            "ipopt",
            {"x": w, "f": J},
            {
                "ipopt.print_level": 0,
                "print_time": False,
                "ipopt.max_iter": max_iter,
                "ipopt.hessian_approximation": "limited-memory",
                "ipopt.tol": 1e-10,
                "ipopt.acceptable_tol": 1e-7,
                "ipopt.sb": "yes",
            },
        )
        sol = solver(x0=x, lbx=layout.log_lo, ubx=layout.log_hi)
        stats = solver.stats()
        xn = np.asarray(sol["x"], float).ravel()
        if np.all(np.isfinite(xn)):
            x = xn
    return np.exp(x), {
        "status": stats.get("return_status"),
        "iterations": stats.get("iter_count"),
        "smoothed_cost": float(sol["f"]),
        "wall_time": time.perf_counter() - t0,
    }


def riccati_candidate(spec: TuningSpec, plant: Any, layout: Any) -> np.ndarray | None:
    """Tuned vector of the LQR weights Q = diag(C'C)/effort_weight, R = 1, or None when not applicable."""
    loop = spec.loops[-1]
    if not loop.is_lq or loop.lq_mode != "weights" or plant.kind != "lti" or len(spec.loops) != 1:
        return None
    lin = plant.linearize()
    m = lin.output_index(loop.measure) if loop.measure else 0
    ew = max(spec.objective.effort_weight, 1e-9)
    q = np.diag(lin.C[m : m + 1].T @ lin.C[m : m + 1]) / ew
    vals = {f"q_{s}": max(float(v), 1e-12) for s, v in zip(lin.states, q, strict=True)}
    vals["q_int"] = 1.0 / ew
    vals["r"] = 1.0
    out = []
    for slot in layout.tuned_slots:
        lo, hi = slot.bounds
        out.append(min(max(vals.get(slot.name, math.sqrt(lo * hi)), lo), hi))
    return np.array(out)


@dataclass
class _Best:
    """The best-ranked candidate so far: feasibility first, like every search (:func:`merit`)."""

    tuned: np.ndarray | None = None
    merit: float = math.inf
    cost: float = math.inf
    violation: float = math.inf
    source: str | None = None

    def offer(self, tuned: np.ndarray, m: float, cost: float, violation: float, source: str) -> None:
        """Keep ``tuned`` when its merit ``m`` beats the best so far."""
        if m < self.merit:
            self.tuned, self.merit, self.cost, self.violation, self.source = tuned, m, cost, violation, source


def _multistart_cmaes(
    ev: Any, best: _Best, parts: dict[str, Any], restarts: int, sims_per_restart: int, seed: int, popsize: int
) -> list[tuple[int, float]]:
    """Part 1: ``restarts`` CMA-ES runs (the first from the initial point); returns the joined history."""
    rng = np.random.default_rng(seed)
    layout = ev.layout
    history: list[tuple[int, float]] = []
    for i in range(restarts):
        x0 = None
        if i > 0:
            z = rng.uniform(size=layout.n_tuned)
            x0 = np.exp(layout.log_lo + z * (layout.log_hi - layout.log_lo))
        r = cmaes_search(ev, sims_per_restart, seed=seed + i, popsize=popsize, sigma0=0.3, x0=x0, restarts=False)
        parts[f"cmaes_{i}"] = {"cost": r.cost, "feasible": r.feasible}
        offset = history[-1][0] if history else 0
        history.extend((offset + u, c) for u, c in r.history)
        best.offer(r.tuned, float(merit(np.asarray(r.cost), np.asarray(r.violation))), r.cost, r.violation,
                   f"cmaes_{i}")
    return history


def _polish_part(
    spec: TuningSpec, plant: Any, layout: Any, best: _Best, parts: dict[str, Any],
    score: Callable[[np.ndarray], tuple[float, float, float]],
) -> None:
    """Part 2: the casadi/IPOPT polish from the best so far, when the problem is differentiable."""
    why = differentiable_reason(spec, plant)
    if why is not None or best.tuned is None:
        parts["casadi_polish"] = {"skipped": why or "no finite CMA-ES result"}
        return
    try:
        tuned, info = casadi_polish(spec, plant, layout, best.tuned)
        m, c, v = score(tuned)
        info["cost"] = c if math.isfinite(c) else BAD_COST
        info["feasible"] = v <= 0
        parts["casadi_polish"] = info
        best.offer(tuned, m, c, v, "casadi_polish")
    except Exception as exc:  # IPOPT/casadi failures must not lose the CMA-ES answer
        parts["casadi_polish"] = {"error": f"{type(exc).__name__}: {exc}"}


def reference_optimum(
    spec: TuningSpec,
    evaluator: Any = None,
    *,
    restarts: int = 4,
    sims_per_restart: int = 5000,
    seed: int = 0,
    popsize: int = 32,
    polish: bool = True,
) -> OptResult:
    """Best cost found by multistart CMA-ES, a casadi/IPOPT polish and (LQ) the Riccati candidate.

    ``evaluator`` defaults to ``gaintune.evaluation.search_box.make_evaluator(spec)``. The result's
    ``details`` list every part's cost and which one won.
    """
    t0 = time.perf_counter()
    ev = evaluator
    if ev is None:
        from gaintune.evaluation.search_box import make_evaluator

        ev = make_evaluator(spec)
    start = int(getattr(ev, "n_sims", 0))
    layout = ev.layout
    parts: dict[str, Any] = {}
    best = _Best()

    def score(tuned: np.ndarray) -> tuple[float, float, float]:
        s = ev.evaluate(tuned[None, :])
        return float(s.merit[0]), float(s.cost[0]), float(s.violation[0])

    history = _multistart_cmaes(ev, best, parts, restarts, sims_per_restart, seed, popsize)
    plant = getattr(ev, "plant", None)
    if plant is None:
        from gaintune.plants import build_plant

        plant = build_plant(spec.plant)
    cand = riccati_candidate(spec, plant, layout)
    if cand is not None:
        m, c, v = score(cand)
        parts["riccati"] = {"cost": c, "feasible": v <= 0}
        best.offer(cand, m, c, v, "riccati")
    if polish:
        _polish_part(spec, plant, layout, best, parts, score)
    used = int(getattr(ev, "n_sims", 0)) - start
    best_t = best.tuned if best.tuned is not None else layout.initial_tuned()
    return OptResult(
        "reference", np.asarray(best_t, float), float(best.cost), used, used, time.perf_counter() - t0, history,
        {"parts": parts, "winner": best.source, "restarts": restarts, "sims_per_restart": sims_per_restart},
        feasible=best.violation <= 0, violation=float(best.violation),
    )
