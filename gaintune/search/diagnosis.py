"""Say what a tuning result means: the verdict, the binding requirement, how far off, and what to try.

A result must always tell the engineer something useful. With a pass, that is the
tightest requirement and any gain that sits on its search bound. With a fail, it is
the requirement that decides, the figure the best gains reach, whether the search saw
any candidate that met every requirement, and a concrete next step.

Either way the hints also say how the scenarios were timed (the ``dt``/``horizon`` derived
from the plant, :mod:`gaintune.classical.timescale`), warn about a response that has not
settled by the end of its scenario (:mod:`gaintune.sim.settling`), and flag an integral time
``Ti = Kp/Ki`` longer than the horizon: a horizon too short to see integral action leaves
``Ki`` at whatever the search drew, often its lower bound.
"""

from __future__ import annotations

import math

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.plants.advice import plant_warnings
from gaintune.plants.plant import Plant
from gaintune.search.budget import min_budget_for_rl, rollout_sims
from gaintune.search.result import Diagnosis, TuneResult
from gaintune.spec import Gains, TuningSpec
from gaintune.verification.report import RequirementLine, VerificationReport

__all__ = ["diagnose", "budget_hints", "bound_hints", "direction_hints", "scenario_hints", "settling_hints",
           "integral_time_hints", "REQUIREMENT_TEXT"]

#: requirement field -> (figure label, comparison) used in messages.
REQUIREMENT_TEXT: dict[str, tuple[str, str]] = {
    "gm_min_db": ("GM (dB)", ">="),
    "pm_min_deg": ("PM (deg)", ">="),
    "dm_min": ("delay margin (s)", ">="),
    "ms_max": ("Ms", "<="),
    "mt_max": ("Mt", "<="),
    "mks_max": ("Mks", "<="),
    "wc_min": ("crossover (rad/s)", ">="),
    "wc_max": ("crossover (rad/s)", "<="),
}

#: A gain within this relative distance (in log scale) of a bound counts as on the bound.
ON_BOUND = 0.01


def bound_hints(layout: GainLayout, tuned: np.ndarray,
                skip: frozenset[tuple[int, str, str]] = frozenset()) -> list[str]:
    """One hint per tuned gain that lies on (within 1 % of) its search bound, except ``(loop index, gain, side)`` in
    ``skip``."""
    hints = []
    t = np.log(np.asarray(tuned, dtype=float))
    span = np.maximum(layout.log_hi - layout.log_lo, 1e-12)
    for slot, x, lo, hi, w in zip(layout.tuned_slots, t, layout.log_lo, layout.log_hi, span, strict=True):
        for side, b in (("lower", lo), ("upper", hi)):
            if abs(x - b) <= ON_BOUND * w and (slot.loop, slot.name, side) not in skip:
                hints.append(
                    f"{slot.loop_name}.{slot.name} = {math.exp(x):.4g} lies on its {side} search bound; "
                    f"widen {slot.spec_field}.bounds and tune again"
                )
    return hints


def budget_hints(result: TuneResult) -> list[str]:
    """What the budget did not buy: no RL search at all, or a set-up that alone exceeded it."""
    spec = TuningSpec.model_validate(result.spec)
    s = spec.search
    per = s.robust.samples * len(spec.scenarios)
    rollout = rollout_sims(s.n_envs, per, s.env)
    if result.rl_sims == 0 and result.stopped not in ("cancelled", "wall_time"):
        need = min_budget_for_rl(result.setup_sims, per, rollout, s.refine)
        policy = (f"saved policy of {result.warm_start} as it is (learning off)" if result.warm_start
                  else "untrained policy")
        return [f"no RL search ran: after the set-up's {result.setup_sims} simulations (search box, reward scale), "
                f"search.budget {s.budget} left too few for one rollout ({s.n_envs} gain sets x {per} simulation(s)) "
                f"beside the final checks and the refinement reserve; the answer is the search box's start or the "
                f"{policy}. "
                f"Raise search.budget to at least {need}, or lower search.n_envs"]
    if result.sims > s.budget:
        return [f"the tune ran {result.sims} simulations, more than search.budget {s.budget}: the set-up (search box, "
                "reward scale) and the final checks are always run in full"]
    return []


def _relative_margin(q: RequirementLine) -> float:
    return q.margin / max(abs(q.limit), 1e-12)


def _failing_lines(ver: VerificationReport) -> list[RequirementLine]:
    return sorted((q for q in ver.requirements if not q.passed), key=_relative_margin)


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


def scenario_hints(result: TuneResult) -> list[str]:
    """One line per scenario whose dt or horizon was derived from the plant: the values and why."""
    out = []
    for d in result.scenario_defaults:
        which = " and ".join(k for k, src in (("dt", d.dt_from), ("horizon", d.horizon_from)) if src == "plant")
        out.append(f"scenario {d.scenario!r}: dt {d.dt:.4g} s, horizon {d.horizon:.4g} s ({which} derived from the "
                   f"plant: {d.reason}); set them in the spec to choose others")
    return out


def settling_hints(spec: TuningSpec, plant: Plant, layout: GainLayout, full: np.ndarray) -> list[str]:
    """A warning per scenario whose response to the gains ``full`` has not settled by its end."""
    from gaintune.sim import Simulator
    from gaintune.sim.settling import settling_messages

    return settling_messages(Simulator(spec, plant, layout), full)


def slow_integral_loops(spec: TuningSpec, gains: Gains) -> list[tuple[int, float]]:
    """``(loop index, Ti)`` of every loop whose integral time Ti = Kp/Ki is longer than the longest scenario horizon."""
    from gaintune.controllers.pid import pid_params

    horizon = max(sc.resolved_horizon for sc in spec.scenarios)
    out = []
    for i, loop in enumerate(spec.loops):
        if loop.is_lq or "i" not in loop.type[1:] or loop.name not in gains:
            continue
        p = pid_params(loop, gains[loop.name])
        kp, ki = float(p.Kp), float(p.Ki)
        if ki != 0 and kp / ki > horizon:
            out.append((i, kp / ki))
    return out


def integral_time_hints(spec: TuningSpec, gains: Gains) -> list[str]:
    """A warning per loop whose integral time Ti = Kp/Ki is longer than the longest scenario horizon."""
    horizon = max(sc.resolved_horizon for sc in spec.scenarios)
    return [f"loops[{i}] ({spec.loops[i].name}): the integral time Ti = Kp/Ki = {ti:.4g} s is longer than the longest "
            f"scenario horizon ({horizon:.4g} s), so the scenarios cannot see the integral action work: lengthen the "
            "horizon (or leave dt/horizon out and let gaintune derive them from the plant) before widening the gain "
            "bounds"
            for i, ti in slow_integral_loops(spec, gains)]


def diagnose(result: TuneResult, layout: GainLayout, tuned: np.ndarray, plant: Plant | None = None) -> Diagnosis:
    """Build the :class:`Diagnosis` of a finished tune (its verification included, when run).

    With ``plant``, warnings about the plant itself (open-loop unstable, non-equilibrium
    operating point, :func:`gaintune.plants.advice.plant_warnings`) come first among the hints,
    and every scenario is simulated once more to warn about a response that has not settled.
    A lower-bound hint on a Ki whose integral time is longer than the horizon is left out: the
    horizon, not the bound, is what to change.
    """
    spec = TuningSpec.model_validate(result.spec)
    timing = scenario_hints(result)
    skip: frozenset[tuple[int, str, str]] = frozenset()
    if all(sc.resolved for sc in spec.scenarios):  # a tune stores the spec with its scenarios resolved
        timing += integral_time_hints(spec, result.gains)
        if plant is not None:
            timing += settling_hints(spec, plant, layout, layout.full(tuned))
        skip = frozenset((i, "Ki", "lower") for i, _ in slow_integral_loops(spec, result.gains))
    hints = (budget_hints(result) + (plant_warnings(plant) if plant is not None else []) + timing
             + bound_hints(layout, tuned, skip))
    ver = result.verification
    if ver is None:
        return Diagnosis(status="unverified", summary="the gains were not verified; they are not accepted", hints=hints)
    if ver.verdict == "pass":
        tight = min(ver.requirements, key=_relative_margin) if ver.requirements else None
        summary = "the gains pass verification"
        if tight is None:
            return Diagnosis(status="pass", summary=summary, hints=hints)
        label, op = REQUIREMENT_TEXT.get(tight.requirement, (tight.figure, "vs"))
        summary += f"; tightest requirement {label} {op} {_fmt(tight.limit)}: {_fmt(tight.value)}"
        return Diagnosis(status="pass", summary=summary, binding=tight.requirement, value=_finite(tight.value),
                         limit=tight.limit, hints=hints)
    stable = ver.stability.stable
    searched_feasible = result.violation <= 0
    failing = _failing_lines(ver)
    if not stable:
        summary = "no stabilising gains were found" if not searched_feasible else "the closed loop is unstable"
        generic = ("check the plant sign and model, or widen the gain bounds; the search never saw a stable loop"
                   if not searched_feasible
                   else "the exact verification found the loop unstable; raise verify.n_freq or report a bug")
        hints[:0] = direction_hints(TuningSpec.model_validate(result.spec), plant) + [generic]
        return Diagnosis(status="fail", summary=summary, hints=hints)
    if failing:
        q = failing[0]
        label, op = REQUIREMENT_TEXT.get(q.requirement, (q.figure, "vs"))
        summary = (f"{label} {op} {_fmt(q.limit)} is not met: the best gains found give {_fmt(q.value)} "
                   f"at {q.loop}/{q.break_point} ({q.case})")
        if not searched_feasible:
            kinds = {lp.type.upper() for lp in TuningSpec.model_validate(result.spec).loops}
            hints.insert(0, f"no candidate in {result.sims} simulations met every requirement, so the answer is the "
                            f"least-violating one: {label} {op} {_fmt(q.limit)} may not be reachable with "
                            f"{'/'.join(sorted(kinds))} on this plant within the gain bounds (best {_fmt(q.value)}). "
                            "Relax the requirement, add derivative action, or widen the bounds")
        else:
            hints.insert(0, "the search estimate and the exact verification disagree at these gains; "
                            "raise search.budget or report the spec")
        return Diagnosis(status="fail", summary=summary, binding=q.requirement, value=_finite(q.value), limit=q.limit,
                         hints=hints)
    return Diagnosis(status="fail", summary=ver.reasons[0] if ver.reasons else "verification failed", hints=hints)


def direction_hints(spec, plant: Plant | None) -> list[str]:
    """A hint per loop whose direction the spec forces against the sign its plant path has."""
    from gaintune.controllers.direction import resolve_directions
    from gaintune.errors import SpecError

    if plant is None:
        return []
    out = []
    for i, loop in enumerate(spec.loops):
        if loop.is_lq or loop.direction == "auto":
            continue
        free = spec.model_copy(deep=True)
        free.loops[i].direction = "auto"
        try:
            auto = resolve_directions(free, plant)[i]
        except SpecError:  # the sign cannot be read from the plant: nothing to contradict
            continue
        if (auto.sign > 0) != (loop.direction == "direct"):
            want = "direct" if auto.sign > 0 else "reverse"
            out.append(f"loops[{i}] ({loop.name}) is set to direction: {loop.direction}, but its path has "
                       f"{auto.reason}: no gains of that sign can stabilise it; set direction: {want} or auto")
    return out
