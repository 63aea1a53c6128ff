"""Everything the HTML report shows, computed from a TuneResult (simulations, frequency responses, tables)."""

from __future__ import annotations

import math
from dataclasses import fields
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from gaintune.fmt import fmt
from gaintune.provenance import versions as all_versions
from gaintune.report import plots
from gaintune.report.plant_summary import plant_summary as _plant_summary
from gaintune.spec import DisturbanceSpec, Gains, ProfileSpec, ScenarioSpec, TuningSpec

if TYPE_CHECKING:  # the result model, for annotations only (the report reads any TuneResult)
    from gaintune.search.result import TuneResult

__all__ = ["build_context"]

#: Monte-Carlo draws (besides the box corners) for the robustness envelope.
ENVELOPE_DRAWS = 32
#: Classical baselines computed by the report when the result carries none.
QUICK_BASELINES = ("simc", "amigo")



_fmt = fmt  # one formatter for every table (gaintune.fmt)


# ------------------------------------------------------------------ summary


def _loop_rows(spec: TuningSpec, plant) -> list[dict[str, Any]]:
    rows = []
    for i, lp in enumerate(spec.loops):
        inner = i == len(spec.loops) - 1
        lim = spec.actuator.limits if inner else lp.output_limits
        rows.append({
            "name": lp.name,
            "type": lp.type.upper(),
            "form": lp.form if not lp.is_lq else lp.lq_mode,
            "measure": lp.measure or plant.outputs[0],
            "drives": "actuator u" if inner else f"setpoint of {spec.loops[i + 1].name}",
            "limits": "-" if lim is None else f"[{_fmt(lim[0])}, {_fmt(lim[1])}]",
            "anti_windup": "-" if lp.is_lq or "i" not in lp.type[1:] else lp.anti_windup,
            "weights": "-" if lp.is_lq else f"b={_fmt(lp.b)}, c={_fmt(lp.c)}",
        })
    return rows


def _gain_rows(spec: TuningSpec, plant, gains: Gains, ps: dict[str, Any]) -> list[dict[str, Any]]:
    """One row per gain: value, unit (where the model gives units) and the other PID form's equivalent."""
    from gaintune.controllers.forms import equivalent, gain_unit

    units, rows = ps["units"], []
    loops = {lp.name: (i, lp) for i, lp in enumerate(spec.loops)}
    for loop, g in gains.items():
        i, lp = loops.get(loop, (-1, None))
        pid = lp is not None and not lp.is_lq
        other: dict[str, float] = equivalent(lp.form, g) if lp is not None and not lp.is_lq else {}
        y_unit = units.get((lp.measure or plant.outputs[0]) if lp is not None else "", "")
        if lp is None:
            u_unit = ""
        elif i == len(spec.loops) - 1:
            u_unit = ps.get("input_unit", "")
        else:
            nxt = spec.loops[i + 1]
            u_unit = units.get(nxt.measure or plant.outputs[0], "")
        alt = [f"{k} {_fmt(v, 4)}" + (f" {gain_unit(k, u_unit, y_unit)}" if gain_unit(k, u_unit, y_unit) else "")
               for k, v in other.items() if k not in g]
        for k, v in g.items():
            rows.append({"loop": loop, "gain": k, "value": _fmt(v, 6),
                         "unit": gain_unit(k, u_unit, y_unit) if pid else "",
                         "other": ", ".join(alt) if k == next(iter(g)) else ""})
    return rows


def _draw_text(q) -> str:
    """`` (draw K=1.2)``: the robust-set draw a MIMO worst-case line was read on."""
    draw = getattr(q, "draw", None)
    return " (draw " + ", ".join(f"{k}={_fmt(v, 4)}" for k, v in draw.items()) + ")" if draw else ""


def _requirements(rep) -> list[dict[str, Any]]:
    names = {"gm_min_db": "gain margin >= (dB)", "pm_min_deg": "phase margin >= (deg)", "dm_min": "delay margin >= (s)",
             "ms_max": "Ms <=", "mt_max": "Mt <=", "mks_max": "Mks <=",
             "wc_min": "crossover >= (rad/s)", "wc_max": "crossover <= (rad/s)"}
    return [{
        "name": names.get(q.requirement, q.requirement), "value": _fmt(q.value), "limit": _fmt(q.limit),
        "margin": _fmt(q.margin), "passed": q.passed, "status": q.status,
        "where": " / ".join(x for x in (q.loop, q.break_point, q.case) if x) + _draw_text(q),
    } for q in rep.requirements]


def _margin_rows(rep) -> list[dict[str, Any]]:
    return [{
        "loop": f.loop, "break": "controller output" if f.break_point == "controller_output" else "plant input",
        "gm": _fmt(f.gm_db, 3), "pm": _fmt(f.pm_deg, 3), "wc": _fmt(f.pm_freq, 3), "dm": _fmt(f.delay_margin, 3),
        "ms": _fmt(f.ms, 3), "mt": _fmt(f.mt, 3), "disk": _fmt(f.disk_alpha, 3),
    } for f in rep.loops]


# ------------------------------------------------------------ simulations


def _loop_traces(res, spec: TuningSpec, plant, units: dict[str, str], b: int = 0) -> list[dict[str, Any]]:
    out = []
    for lp in spec.loops:
        meas = lp.measure or plant.outputs[0]
        out.append({"name": lp.name, "measure": meas, "unit": units.get(meas, ""),
                    "y": res.traces[f"y.{lp.name}"][b], "sp": res.traces[f"sp.{lp.name}"][b]})
    return out


def _load_scenario(spec: TuningSpec, u_final: float, u0: float) -> ScenarioSpec | None:
    """A load-disturbance experiment derived from the first scenario (when no scenario has one)."""
    if any(sc.disturbance.kind != "none" for sc in spec.scenarios):
        return None
    sc = spec.scenarios[0]
    lim = spec.actuator.limits
    amp = 0.1 * (lim[1] - lim[0]) if lim else abs(u_final - u0)
    if not math.isfinite(amp) or amp < 1e-9:
        amp = 1.0
    t_d = round(0.1 * sc.resolved_horizon / sc.resolved_dt) * sc.resolved_dt
    return sc.model_copy(update={
        "name": "load_disturbance",
        "reference": ProfileSpec(kind="none"),
        "disturbance": DisturbanceSpec(kind="step", amplitude=float(amp), time=t_d, entry="input"),
        "noise_std": 0.0,
    })


def _setpoint_scenario(spec: TuningSpec) -> ScenarioSpec | None:
    """A unit setpoint step derived from the first scenario, when no scenario changes the reference."""
    if any(sc.reference.kind != "none" for sc in spec.scenarios):
        return None
    return spec.scenarios[0].model_copy(update={
        "name": "setpoint_step", "reference": ProfileSpec(kind="step", amplitude=1.0, time=0.0),
        "disturbance": DisturbanceSpec(kind="none"), "noise_std": 0.0,
    })


def _time_section(spec, plant, sim, full, ps) -> tuple[list[dict], dict]:
    units, u_unit = ps["units"], ps.get("input_unit", "")
    lim = spec.actuator.limits

    def figure(res, title: str) -> str:
        return plots.time_figure(res.t, _loop_traces(res, spec, plant, units), res.traces["u"][0], lim, title,
                                 u_unit=u_unit)

    figs = []
    nominal_runs = {}
    for i, sc in enumerate(spec.scenarios):
        res = sim.run(full[None], scenario=i, traces=True)
        nominal_runs[i] = res
        kind = sc.reference.kind if sc.reference.kind != "none" else "no reference change"
        dist = ("" if sc.disturbance.kind == "none"
                else f", {sc.disturbance.kind} load disturbance at the {sc.disturbance.entry}")
        title = f"Scenario '{sc.name}': reference {kind}{dist}"
        figs.append({"title": title, "svg": figure(res, title)})
    lin = plant.linearize()
    u_final = float(nominal_runs[0].traces["u"][0][-1])
    load = _load_scenario(spec, u_final, float(lin.u0))
    if load is not None:
        res = sim.run(full[None], scenario=load, traces=True)
        title = (f"Load disturbance: input step of {load.disturbance.amplitude:.3g} at t = {load.disturbance.time:g} s "
                 "(derived from the first scenario, reference held)")
        figs.append({"title": title, "svg": figure(res, title),
                     "note": f"load IAE {_fmt(float(res.metrics['load_iae'][0]))}"})
    step = _setpoint_scenario(spec)
    if step is not None:
        res = sim.run(full[None], scenario=step, traces=True)
        title = "Setpoint step of 1, for information (the spec tunes for its load scenarios only)"
        m = res.metrics
        figs.append({"title": title, "svg": figure(res, title),
                     "note": f"overshoot {_fmt(float(m['overshoot'][0]))}, "
                             f"settling time {_fmt(float(m['settling_time'][0]))} s"})
    return figs, nominal_runs


def _freq_section(spec, plant, layout, full, rep) -> dict[str, Any]:
    from gaintune.verification.analysis import sampling_delay
    from gaintune.verification.cascade import build_cascade
    from gaintune.verification.core import analysis_dt, loop_frequency_responses

    lin = plant.linearize()
    delay_T = lin.delay + (0.0 if spec.verify.sampled else sampling_delay(spec))
    cas = build_cascade(spec, layout, full[None, :], lin)
    cross = []
    for f in rep.loops:
        cross += [x for x in (f.pm_freq, f.gm_freq, f.ms_freq, f.mt_freq) if x]
        cross += f.gain_crossovers + f.phase_crossovers[:2]
    cross = [x for x in cross if math.isfinite(x) and x > 1e-9]
    poles = [abs(e) for e in np.linalg.eigvals(lin.A)] if lin.A.size else []
    poles = [x for x in poles if math.isfinite(x) and x > 1e-9]
    if not cross:
        cross = poles or [1.0]
    lo = min(cross + poles) / 30.0 if poles else min(cross) / 100.0
    lo = max(lo, min(cross) / 1e3)
    hi = max(cross) * 100.0
    if delay_T > 0:  # beyond a few rad of delay phase the plot only shows the delay spinning
        hi = min(hi, max(max(cross) * 5.0, 3.0 / delay_T))
    if spec.verify.sampled:  # the sampled loop repeats beyond the Nyquist frequency
        hi = min(hi, math.pi / analysis_dt(spec))
        lo = min(lo, hi / 1e3)
    w = np.logspace(math.log10(lo), math.log10(hi), 800)
    # the loop verification analysed (sampled by default), so the plots match the report's figures
    L = loop_frequency_responses(spec, plant, layout, full, w, lin)
    figs_by_break = {(f.loop, f.break_point): f for f in rep.loops}
    bodes, curves = [], []
    breaks = list(zip(cas.break_names, L, strict=True))
    if len(spec.loops) == 1:  # the controller output is the plant input: one curve is enough
        breaks = breaks[:1]
    for (loop, brk), Lr in breaks:
        f = figs_by_break.get((loop, brk))
        label = (f"{loop} (broken at its controller output)" if brk == "controller_output"
                 else "plant input (all loops closed)")
        gm = {"db": f.gm_db, "freq": f.gm_freq} if f else None
        pm = {"deg": f.pm_deg, "freq": f.pm_freq} if f else None
        bodes.append({"title": f"Bode: loop transfer at {label}",
                      "svg": plots.bode_figure(w, Lr, f"L at {label}", gm, pm)})
        curves.append((loop if brk == "controller_output" else "plant input", Lr))
    req = spec.requirements
    ms_vals = [f.ms for f in rep.loops]
    return {
        "noise": _noise_plot(spec, plant, layout, full, w, lin, rep),
        "bodes": bodes,
        "nyquist": plots.nyquist_figure(curves, req.ms_max, [max(ms_vals)] if ms_vals else []),
        "sensitivity": plots.sensitivity_figure(w, curves, req.ms_max, req.mt_max),
        "delay_note": (
            f"Sampled loop at dt = {analysis_dt(spec):.4g} s: zero-order-hold plant with its delay {lin.delay:.4g} s "
            f"(exact), the controllers' discrete laws"
            + (f", {spec.verify.compute_delay} sample(s) of computation delay" if spec.verify.compute_delay else "")
            + "."
            if spec.verify.sampled else
            f"Continuous loop: delay {delay_T:.4g} s = plant delay {lin.delay:.4g} s + sampling delay dt/2 = "
            f"{sampling_delay(spec):.4g} s, " + ("exact e^(-jwT)." if spec.verify.pade_order is None
                                                 else f"Padé order {spec.verify.pade_order}.")),
    }


def _noise_plot(spec, plant, layout, full, w, lin, rep) -> str | None:
    """The |C S| plot with the Mks limits, when Mks is a requirement of some loop (else None)."""
    from gaintune.verification.core import loop_frequency_responses

    limits = {f.loop: f.mks_max for f in rep.loops if f.break_point == "controller_output" and f.mks_max}
    if not limits:
        return None
    N = loop_frequency_responses(spec, plant, layout, full, w, lin, noise=True)
    names = [lp.name for lp in spec.loops]
    curves = [(n, N[i], limits.get(n)) for i, n in enumerate(names) if not spec.loops[i].is_lq]
    return plots.noise_figure(w, curves) if curves else None


def _concat_draws(a, b):
    from gaintune.sim.draws import Draws

    return Draws(**{f.name: np.concatenate([getattr(a, f.name), getattr(b, f.name)]) for f in fields(Draws)})


def _robust_section(spec, plant, sim, full, rep, nominal_res, units) -> dict[str, Any]:
    from gaintune.sim import draws as dm

    out: dict[str, Any] = {"active": spec.randomize.active, "worst": [], "svg": None}
    if rep.robust is not None:
        r = rep.robust
        out["summary"] = (f"{r.n_samples} sampled plants ({r.n_corners} box corners + {r.n_monte_carlo} random draws, "
                          f"seed {r.seed}); {r.n_unstable} unstable")
        out["n_unstable"] = r.n_unstable
        for wc in r.worst:
            out["worst"].append({
                "loop": wc.loop,
                "break": "controller output" if wc.break_point == "controller_output" else "plant input",
                "gm": _fmt(wc.gm_db, 3), "pm": _fmt(wc.pm_deg, 3), "dm": _fmt(wc.delay_margin, 3), "ms": _fmt(wc.ms, 3),
                "mt": _fmt(wc.mt, 3), "disk": _fmt(wc.disk_alpha, 3),
                "where": ", ".join(f"{k}={_fmt(v, 3)}" for k, v in wc.where.get("pm_deg", {}).items()),
            })
    if not spec.randomize.active:
        return out
    rng = np.random.default_rng(spec.search.seed)
    d = _concat_draws(dm.corners(spec, plant, 64), dm.sample(spec, plant, rng, ENVELOPE_DRAWS))
    n = len(d)
    res = sim.run(np.tile(full, (n, 1)), draws=d, scenario=0, traces=True)
    lp0 = spec.loops[0]
    meas = lp0.measure or plant.outputs[0]
    ys = res.traces[f"y.{lp0.name}"]
    nom = nominal_res[0]
    ok = np.all(np.isfinite(ys), axis=1) & ~res.metrics["diverged"]
    out["n_draws"] = n
    out["n_diverged"] = int((~ok).sum())
    if ok.any():
        out["svg"] = plots.envelope_figure(res.t, ys[ok], nom.traces[f"y.{lp0.name}"][0],
                                           nom.traces[f"sp.{lp0.name}"][0], res.traces["u"][ok], nom.traces["u"][0],
                                           meas)
        iae = res.metrics["iae"][ok]
        out["iae"] = {"min": _fmt(float(iae.min())), "mean": _fmt(float(iae.mean())), "max": _fmt(float(iae.max()))}
    return out


def _search_section(result, spec: TuningSpec) -> dict[str, Any]:
    series = []
    if result.curve:
        series.append((f"{result.algo} (gaintune)", [c.sims for c in result.curve],
                       [c.best_cost for c in result.curve]))
    for b in result.baselines or []:
        h = b.get("history") or []
        if h:
            series.append((b.get("method", "?"), [int(x[0]) for x in h], [float(x[1]) for x in h]))
    facts = [
        ("algorithm", result.algo), ("environment", spec.search.env), ("budget (simulations)", spec.search.budget),
        ("simulations used", result.sims), ("RL simulations", result.rl_sims), ("parallel envs", spec.search.n_envs),
        ("robust samples / aggregate", f"{spec.search.robust.samples} / {spec.search.robust.aggregate}"),
        ("wall time", f"{result.wall_time:.1f} s"), ("stopped by", result.stopped),
        ("gains source", result.gains_source), ("final cost", _fmt(result.cost)),
        ("RL-only cost", _fmt(result.rl_cost)), ("policy cost", _fmt(result.policy_cost)),
        ("seed", spec.search.seed), ("agent", result.agent_path or "-"),
    ]
    return {"facts": [(k, _fmt(v) if not isinstance(v, str) else v) for k, v in facts],
            "svg": plots.curve_figure(series) if series else None}


def _gains_text(gains: Gains | None) -> str:
    """Gains as one short line per table cell, e.g. ``loop0: Kp 1.14, Ki 0.454``."""
    if not gains:
        return "-"
    return "; ".join(f"{lp}: " + ", ".join(f"{k} {_fmt(v, 4)}" for k, v in g.items()) for lp, g in gains.items())


def _baselines_section(result, rep0, spec, plant, sim, full, nominal_res, units) -> dict[str, Any]:
    from gaintune.verification import verify

    computed = False
    entries = [dict(b) for b in (result.baselines or [])]
    if not entries:
        from gaintune.baselines import run_baseline

        computed = True
        for m in QUICK_BASELINES:
            try:
                entries.append(run_baseline(spec, m).model_dump())
            except Exception as exc:  # a baseline that cannot run is reported, never fatal
                entries.append({"method": m, "gains": None, "reason": str(exc)})
    rows = [{"method": f"gaintune ({result.algo})", "gains": _gains_text(result.gains), "cost": _fmt(result.cost),
             "sims": _fmt(result.sims), "verdict": rep0.verdict, "gm": "", "pm": "", "ms": "", "note": "this result",
             "self": True}]
    if rep0.loops:
        rows[0].update(gm=_fmt(min(f.gm_db for f in rep0.loops), 3), pm=_fmt(min(f.pm_deg for f in rep0.loops), 3),
                       ms=_fmt(max(f.ms for f in rep0.loops), 3))
    lp0 = spec.loops[0]
    nom = nominal_res[0]
    runs = [(f"gaintune ({result.algo})", nom.traces[f"y.{lp0.name}"][0], nom.traces["u"][0])]
    for b in entries:
        g = b.get("gains")
        row = {"method": b.get("method", "?"), "gains": _gains_text(g), "cost": _fmt(b.get("cost")),
               "sims": _fmt(b.get("n_sims")), "verdict": "-", "gm": "-", "pm": "-", "ms": "-",
               "note": b.get("reason") or "", "self": False}
        if g:
            try:
                vec = sim.layout.from_dict(g)
                vr = verify(spec, g, robust=False, nonlinear=False, plant=sim.plant, layout=sim.layout)
                row.update(verdict=vr.verdict + " (nominal)", gm=_fmt(min(f.gm_db for f in vr.loops), 3),
                           pm=_fmt(min(f.pm_deg for f in vr.loops), 3), ms=_fmt(max(f.ms for f in vr.loops), 3))
                res = sim.run(vec[None], scenario=0, traces=True)
                if not res.metrics["diverged"][0]:
                    runs.append((b.get("method", "?"), res.traces[f"y.{lp0.name}"][0], res.traces["u"][0]))
                else:
                    row["note"] = (row["note"] + "; " if row["note"] else "") + "diverges"
            except Exception as exc:
                row["note"] = f"could not evaluate: {exc}"
        rows.append(row)
    meas = lp0.measure or plant.outputs[0]
    svg = plots.overlay_figure(nom.t, nom.traces[f"sp.{lp0.name}"][0], runs, spec.actuator.limits, meas,
                               f"Scenario '{spec.scenarios[0].name}': gaintune vs baselines") if len(runs) > 1 else None
    return {"rows": rows, "svg": svg, "computed": computed}


# -------------------------------------------------------------------- main

#: The nominal metrics the report tabulates per scenario.
METRIC_KEYS = ("iae", "ise", "effort", "overshoot", "rise_time", "settling_time", "sse", "peak_u", "sat_frac")


def _metric_rows(spec: TuningSpec, nominal_res: dict[int, Any]) -> list[dict[str, Any]]:
    """One row of :data:`METRIC_KEYS` per scenario, from the nominal runs."""
    rows = []
    for i, sc in enumerate(spec.scenarios):
        m = nominal_res[i].metrics
        rows.append({"scenario": sc.name, **{k: _fmt(float(m[k][0])) for k in METRIC_KEYS},
                     "diverged": bool(m["diverged"][0])})
    return rows


def _repro(result: TuneResult, command: str | None) -> dict[str, Any]:
    """What reproduces the result: the spec as YAML, seed, spec hash, package versions and the command."""
    prov = result.provenance
    versions = dict(prov.versions) if prov.versions else {}
    if not versions:
        versions = all_versions()
    return {
        "spec_yaml": yaml.safe_dump(result.spec, sort_keys=False),
        "seed": prov.seed,
        "spec_hash": prov.spec_hash,
        "versions": versions,
        "command": command or prov.command or f"gaintune tune spec.yaml --seed {prov.seed}",
    }



def build_context(result: TuneResult, *, command: str | None = None) -> dict[str, Any]:
    """All data of the report for one TuneResult (re-simulates with traces, computes frequency responses).

    Parameters
    ----------
    result
        The result to report; it is verified here when it carries no verification.
    command
        The command shown as the way to reproduce it (default: the one in its provenance).

    Returns
    -------
    dict
        The template's context: sections of tables, SVG figures and facts.
    """
    from gaintune.plants.plant import build_plant
    from gaintune.sim import Simulator
    from gaintune.verification import verify

    spec = TuningSpec.model_validate(result.spec)
    plant = build_plant(spec.plant)
    sim = Simulator(spec, plant)
    full = sim.layout.from_dict(result.gains)
    rep = result.verification
    verified_now = rep is None
    if rep is None:
        rep = verify(spec, result.gains, plant=plant, layout=sim.layout)
    ps = _plant_summary(spec, plant)
    units = ps["units"]
    time_figs, nominal_res = _time_section(spec, plant, sim, full, ps)
    return {
        "title": f"gaintune report: {spec.name}",
        "spec": spec,
        "spec_name": spec.name,
        "description": spec.description,
        "passed": rep.verdict == "pass",
        "diagnosis": result.diagnosis.model_dump() if result.diagnosis is not None else None,
        "verdict": rep.verdict,
        "verified_now": verified_now,
        "set_aside": result.verification_set_aside,
        "reasons": rep.reasons,
        "notes": rep.notes,
        "plant": ps,
        "loops": _loop_rows(spec, plant),
        "actuator": {"limits": spec.actuator.limits, "rate_limit": spec.actuator.rate_limit},
        "gains": _gain_rows(spec, plant, result.gains, ps),
        "gains_source": result.gains_source,
        "requirements": _requirements(rep),
        "margins": _margin_rows(rep),
        "stability": rep.stability,
        "metric_keys": METRIC_KEYS,
        "metrics": _metric_rows(spec, nominal_res),
        "time": time_figs,
        "freq": _freq_section(spec, plant, sim.layout, full, rep),
        "robust": _robust_section(spec, plant, sim, full, rep, nominal_res, units),
        "search": _search_section(result, spec),
        "baselines": _baselines_section(result, rep, spec, plant, sim, full, nominal_res, units),
        "repro": _repro(result, command),
        "fmt": _fmt,
    }
