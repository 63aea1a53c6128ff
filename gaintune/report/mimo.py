"""The report of a MIMO result: loop map, every loop, per-chain time responses and the MIMO margin tables.

A spec with several plant inputs or a loop graph (:func:`gaintune.export.mimo.is_mimo`) is
reported by :func:`build_mimo_context` with the template ``report_mimo.html.j2``; every other
spec keeps the single-input report (:mod:`gaintune.report.context`).

MIMO margins
------------
The margin section is filled from the verification the result carries: ``verification.mimo``
(an attribute, or a key of its JSON form) with the fields of
:class:`gaintune.verification.mimo.MimoMargins` (``loops``, ``inputs``, ``outputs``,
``stability``, ``input_breaks``/``output_breaks`` with the SISO break figures, ``ms_input``,
``mt_input``, ``ms_output``, ``mt_output`` as peaks ``{value, freq}``, ``disk_input``/
``disk_output`` with ``alpha``, ``gm_db``, ``pm_deg``, ``freq``), or the ``margins`` argument.
Without them the section says the MIMO margins were not computed.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gaintune.fmt import fmt as _fmt
from gaintune.report import plots
from gaintune.report.loopmap import chains_of, loop_map_svg
from gaintune.spec import TfEntrySpec, TuningSpec

__all__ = ["build_mimo_context", "mimo_margin_tables", "verified_margins", "MIMO_METRIC_KEYS"]

#: The nominal metrics tabulated per scenario (besides the IAE of every chain).
MIMO_METRIC_KEYS = ("iae", "effort", "overshoot", "settling_time", "peak_u", "sat_frac")


def _get(obj: Any, name: str, default: Any = None) -> Any:
    """Field ``name`` of a dataclass/model or of its JSON form (a dict)."""
    if isinstance(obj, dict):
        return obj.get(name, default)
    return getattr(obj, name, default)


#: Worst-case figure -> its column's label.
_LABELS = {"gm_db": "GM", "pm_deg": "PM", "delay_margin": "DM", "ms": "Ms", "mt": "Mt", "disk_alpha": "alpha"}


def _draws(where: Any) -> str:
    """Which draw attains each worst-case figure, grouped by draw (``GM, Ms at K=1.2; PM at K=3``)."""
    groups: dict[str, list[str]] = {}
    for fig, label in _LABELS.items():
        d = _get(where or {}, fig)
        if d:
            groups.setdefault(", ".join(f"{k}={_fmt(v, 4)}" for k, v in d.items()), []).append(label)
    return "; ".join(f"{', '.join(labels)} at {draw}" for draw, labels in groups.items())


def _interleave(rows: list[dict[str, Any]], worst: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each nominal row followed by its worst-case row (the rows of either without a partner last)."""
    n = min(len(rows), len(worst))
    return [r for pair in zip(rows[:n], worst[:n], strict=True) for r in pair] + rows[n:] + worst[n:]


def _robust_rows(robust: Any, breaks: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], list[dict[str, Any]], str]:
    """The worst-case rows of the robust set (a :class:`~gaintune.verification.report.RobustReport` or its
    dict): per side and per break point (labelled as the nominal ``breaks`` rows), and a summary line."""
    sides = [{"side": f"plant {_get(w, 'side')}s (worst case)", "ms": _fmt(_get(w, "ms"), 3), "ms_freq": "",
              "mt": _fmt(_get(w, "mt"), 3), "alpha": _fmt(_get(w, "disk_alpha"), 3), "disk_gm": "", "disk_pm": "",
              "disk_freq": "", "draw": _draws(_get(w, "where"))} for w in _get(robust, "sides", []) or []]
    rows = []
    for k, w in enumerate(_get(robust, "worst", []) or []):
        label = breaks[k]["break"] if k < len(breaks) else str(_get(w, "break_point"))
        rows.append({"loop": _get(w, "loop"), "break": f"{label} (worst case)", "gm": _fmt(_get(w, "gm_db"), 3),
                     "pm": _fmt(_get(w, "pm_deg"), 3), "dm": _fmt(_get(w, "delay_margin"), 3),
                     "ms": _fmt(_get(w, "ms"), 3), "mt": _fmt(_get(w, "mt"), 3),
                     "disk": _fmt(_get(w, "disk_alpha"), 3), "draw": _draws(_get(w, "where"))})
    n, nu = _get(robust, "n_samples", 0), _get(robust, "n_unstable", 0)
    summary = (f"robust set: {n} drawn plants ({_get(robust, 'n_corners', 0)} box corners + "
               f"{_get(robust, 'n_monte_carlo', 0)} Monte-Carlo draws, seed {_get(robust, 'seed', 0)}), "
               f"{nu} with an unstable closed loop; worst case over the stable ones")
    return sides, rows, summary


def mimo_margin_tables(margins: Any, robust: Any = None) -> dict[str, Any] | None:
    """The MIMO margin tables from a :class:`~gaintune.verification.mimo.MimoMargins` (or its dict); None if absent.

    Returns ``{"stability": ..., "sides": rows, "breaks": rows, "notes": [...], "robust": text}``: per
    side (plant inputs, plant outputs) the peak sigma_max of S and T and the multiloop disk margin;
    per loop the loop-at-a-time figures at its plant input and its plant output, all other loops
    closed. ``robust`` (the verification's ``robust`` section) adds a worst-case row, with the draw
    attaining it, after each nominal row; ``robust`` in the result is then the set's summary, else None.
    """
    if margins is None:
        return None
    stab = _get(margins, "stability")
    sides = []
    for side in ("input", "output"):
        ms, mt, disk = (_get(margins, f"{k}_{side}") for k in ("ms", "mt", "disk"))
        sides.append({"side": f"plant {side}s", "ms": _fmt(_get(ms, "value"), 3), "ms_freq": _fmt(_get(ms, "freq"), 3),
                      "mt": _fmt(_get(mt, "value"), 3), "alpha": _fmt(_get(disk, "alpha"), 3),
                      "disk_gm": _fmt(_get(disk, "gm_db"), 3), "disk_pm": _fmt(_get(disk, "pm_deg"), 3),
                      "disk_freq": _fmt(_get(disk, "freq"), 3)})
    breaks = []
    names = list(_get(margins, "loops", []) or [])
    for side, chans in (("input", _get(margins, "inputs", [])), ("output", _get(margins, "outputs", []))):
        for k, f in enumerate(_get(margins, f"{side}_breaks", []) or []):
            breaks.append({"loop": names[k] if k < len(names) else _get(f, "loop"),
                           "break": f"plant {side} {chans[k] if k < len(chans) else ''}".strip(),
                           "gm": _fmt(_get(f, "gm_db"), 3), "pm": _fmt(_get(f, "pm_deg"), 3),
                           "dm": _fmt(_get(f, "delay_margin"), 3), "ms": _fmt(_get(f, "ms"), 3),
                           "mt": _fmt(_get(f, "mt"), 3), "disk": _fmt(_get(f, "disk_alpha"), 3)})
    summary = None
    if robust is not None:
        worst_sides, worst_breaks, summary = _robust_rows(robust, breaks)
        sides, breaks = _interleave(sides, worst_sides), _interleave(breaks, worst_breaks)
    stable = _get(stab, "stable")
    return {"stable": stable, "stability": ("stable" if stable else "UNSTABLE") + f" ({_get(stab, 'method', '?')}, "
            f"max Re pole {_fmt(_get(stab, 'max_real_pole'))})", "sides": sides, "breaks": breaks,
            "notes": list(_get(margins, "notes", []) or []), "robust": summary}


def verified_margins(rep: Any) -> Any:
    """The :func:`mimo_margin_tables` input of a verification report (or its dict): its ``mimo`` figures
    with the closed-loop stability and the loop-at-a-time figures the report keeps beside them
    (``stability``, ``loops``); None when it has no MIMO figures."""
    m = _get(rep, "mimo")
    if m is None or _get(m, "stability") is not None:  # absent, or already in MimoMargins form
        return m
    loops = list(_get(rep, "loops", []) or [])
    return {"loops": _get(m, "loops"), "inputs": _get(m, "inputs"), "outputs": _get(m, "outputs"),
            "stability": _get(rep, "stability"),
            "input_breaks": [f for f in loops if _get(f, "break_point") == "plant_input"],
            "output_breaks": [f for f in loops if _get(f, "break_point") == "plant_output"],
            **{f"{k}_{side}": {"value": _get(m, f"{k}_{side}")} for k in ("ms", "mt") for side in ("input", "output")},
            "disk_input": _get(m, "disk_input"), "disk_output": _get(m, "disk_output"), "notes": []}


def _plant_table(spec: TuningSpec, plant: Any) -> dict[str, Any]:
    """Title, description and (for a transfer-function matrix) every entry as text."""
    from gaintune.report.plant_summary import _poly, _wrap

    p, title, desc = spec.plant, "Plant with several inputs", ""
    tfm = p.tf_matrix
    if p.model is not None:
        from gaintune.plants.library import load_model

        m = load_model(p.model if isinstance(p.model, str) else p.model.name)
        title, desc, tfm = f"{m.title} (built-in model '{m.name}')", m.description, m.plant.tf_matrix
    mimo = plant if hasattr(plant, "inputs") and hasattr(plant, "output_signals") else None
    inputs = [(s.name, s.unit) for s in mimo.inputs] if mimo is not None else [("u", "")]
    outputs = [(s.name, s.unit) for s in mimo.output_signals] if mimo is not None else [(o, "") for o in plant.outputs]
    rows = []
    if tfm is not None:
        for o, row in zip(tfm.outputs, tfm.entries, strict=True):
            cells = []
            for e in row:
                if not isinstance(e, TfEntrySpec):
                    cells.append("0")
                    continue
                if isinstance(e.delay, str):
                    d = f" e^(-({e.delay}) s)"
                else:
                    d = f" e^(-{_fmt(e.delay)} s)" if e.delay else ""
                cells.append(f"{_wrap(_poly(e.num))} / {_wrap(_poly(e.den))}{d}")
            rows.append({"output": o.name, "cells": cells})
    return {"title": title, "description": desc, "inputs": inputs, "outputs": outputs, "entries": rows,
            "states": len(plant.states)}


def _loop_rows(arch: dict[str, Any]) -> list[dict[str, Any]]:
    chains = chains_of(arch["loops"])
    chain_of = {pos: arch["loops"][c[0]]["name"] for c in chains for pos in c}
    rows = []
    for pos, lp in enumerate(arch["loops"]):
        drives = lp["drives"]
        lim = (lp["lo"], lp["hi"])
        rows.append({"name": lp["name"], "type": lp["type"].upper(), "form": lp["form"], "measure": lp["measure"],
                     "drives": f"setpoint of {drives[5:]}" if drives.startswith("loop:") else f"input {drives}",
                     "chain": chain_of.get(pos, "-"), "order": pos + 1,
                     "limits": "-" if not any(map(math.isfinite, lim)) else f"[{_fmt(lim[0])}, {_fmt(lim[1])}]",
                     "anti_windup": lp["aw"] if "i" in lp["type"][1:] else "-",
                     "weights": f"b={_fmt(lp['b'])}, c={_fmt(lp['c'])}"})
    return rows


def _gain_rows(spec: TuningSpec, arch: dict[str, Any], plant: Any) -> list[dict[str, Any]]:
    from gaintune.spec.mimo import gain_unit

    ins, outs = getattr(plant, "inputs", None), getattr(plant, "output_signals", None)
    tied = {ref: t for t, tie in enumerate(spec.ties or []) for ref in tie}
    rows = []
    for lp in arch["loops"]:
        i = spec.loop_names.index(lp["name"])
        for k, v in lp["gains"].items():
            t = tied.get(f"{lp['name']}.{k}")
            rows.append({"loop": lp["name"], "gain": k, "value": _fmt(v, 6),
                         "unit": (gain_unit(spec, i, k, ins, outs) or "") if ins is not None else "",
                         "tie": "-" if t is None else ", ".join((spec.ties or [])[t])})
    return rows


def _time_figure(res: Any, arch: dict[str, Any], title: str) -> str:
    """One subplot per chain (its reference and its outer loop's output), one per driven plant input."""
    plt = plots._plt()
    chains = chains_of(arch["loops"])
    units = {o["name"]: o["unit"] for o in arch["outputs"]}
    acts = [i for i in arch["inputs"] if i["driven_by"] or arch.get("decoupler")]
    n = len(chains) + len(acts)
    fig, axes = plt.subplots(n, 1, figsize=(8, 1.6 * n + 0.5), sharex=True, squeeze=False)
    for ax, chain in zip(axes[: len(chains), 0], chains, strict=True):
        lp = arch["loops"][chain[0]]
        ax.plot(res.t, plots._plottable(res.traces[f"sp.{lp['name']}"][0]), color="0.4", ls="--", lw=1.0,
                label=f"reference {lp['name']}")
        ax.plot(res.t, plots._plottable(res.traces[f"y.{lp['name']}"][0]), color=plots.COLORS[0], lw=1.4,
                label=f"{lp['name']} ({lp['measure']})")
        unit = units.get(lp["measure"], "")
        ax.set_ylabel(lp["measure"] + (f" [{unit}]" if unit else ""))
        ax.legend(loc="lower right", fontsize=8, framealpha=0.8)
    for k, (ax, inp) in enumerate(zip(axes[len(chains):, 0], acts, strict=True)):
        ax.plot(res.t, plots._plottable(res.traces[f"u.{inp['name']}"][0]), color=plots.COLORS[1 + k % 7], lw=1.2,
                label=f"input {inp['name']}")
        for v in inp["limits"] or ():
            ax.axhline(v, color="k", ls=":", lw=1.0)
        ax.set_ylabel(inp["name"] + (f" [{inp['unit']}]" if inp["unit"] else ""))
        ax.legend(loc="lower right", fontsize=8, framealpha=0.8)
    axes[-1, 0].set_xlabel("time")
    axes[0, 0].set_title(title)
    plots._layout(fig)
    return plots.to_svg(fig)


def _time_section(spec: TuningSpec, sim: Any, full: np.ndarray, arch: dict[str, Any]) -> tuple[list, list]:
    chains = [arch["loops"][c[0]]["name"] for c in chains_of(arch["loops"])]
    figs, rows = [], []
    for i, sc in enumerate(spec.scenarios):
        res = sim.run(full[None], scenario=i, traces=True)
        what = [f"reference {sc.reference.kind} on {sc.reference.loop or chains[0]}"] if sc.reference.kind != "none" \
            else []
        if sc.disturbance.kind != "none":
            what.append(f"{sc.disturbance.kind} disturbance at input {sc.disturbance.input or '-'}")
        title = f"Scenario '{sc.name}': " + (", ".join(what) or "no reference change")
        figs.append({"title": title, "svg": _time_figure(res, arch, title)})
        m = res.metrics
        rows.append({"scenario": sc.name, "diverged": bool(m["diverged"][0]),
                     "chains": [_fmt(float(m[f"iae.{c}"][0])) for c in chains],
                     **{k: _fmt(float(m[k][0])) for k in MIMO_METRIC_KEYS}})
    return figs, rows


def build_mimo_context(result: Any, *, command: str | None = None, margins: Any = None) -> dict[str, Any]:
    """All data of the MIMO report of ``result`` (a :class:`~gaintune.search.result.TuneResult`).

    ``margins`` (a :class:`~gaintune.verification.mimo.MimoMargins` or its dict) fills the MIMO
    margin section; by default it is read from ``result.verification`` (see the module docstring).
    """
    from gaintune.export.mimo import mimo_architecture
    from gaintune.plants import build_plant
    from gaintune.report.context import _repro, _requirements, _search_section
    from gaintune.sim import Simulator

    spec = TuningSpec.model_validate(result.spec)
    plant = build_plant(spec.plant)
    sim = Simulator(spec, plant)
    full = sim.layout.from_dict(result.gains)
    arch = mimo_architecture(spec, result.gains)
    rep = result.verification
    if margins is None and rep is not None:
        margins = verified_margins(rep)
    figs, metric_rows = _time_section(sim.spec, sim, full, arch)
    verdict = _get(rep, "verdict") if rep is not None else None
    return {
        "title": f"gaintune report: {spec.name}",
        "spec_name": spec.name,
        "description": spec.description,
        "verdict": verdict,
        "passed": verdict == "pass",
        "reasons": list(_get(rep, "reasons", []) or []) if rep is not None else [],
        "set_aside": result.verification_set_aside,
        "diagnosis": result.diagnosis.model_dump() if result.diagnosis is not None else None,
        "plant": _plant_table(spec, plant),
        "loop_map": loop_map_svg(arch),
        "loops": _loop_rows(arch),
        "inputs": arch["inputs"],
        "decoupler": arch["decoupler"],
        "gains": _gain_rows(spec, arch, plant),
        "gains_source": result.gains_source,
        "chains": [arch["loops"][c[0]]["name"] for c in chains_of(arch["loops"])],
        "metric_keys": MIMO_METRIC_KEYS,
        "metrics": metric_rows,
        "time": figs,
        "margins": mimo_margin_tables(margins, _get(rep, "robust") if rep is not None else None),
        "requirements": _requirements(rep) if rep is not None and not isinstance(rep, dict) else [],
        "search": _search_section(result, spec),
        "repro": _repro(result, command),
        "fmt": _fmt,
    }
