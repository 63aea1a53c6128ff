"""The whole MIMO architecture as the export formats carry it: loops, graph wiring, actuators, decoupler.

A spec with several plant inputs or a loop graph (:func:`gaintune.sim.simulator.needs_mimo`) runs on
:class:`gaintune.sim.mimo.MimoSimulator`; :func:`mimo_architecture` resolves it the same way
(:func:`gaintune.sim.mimo.architecture`): every loop's parallel-form law, in *evaluation order*
(a loop whose output is another loop's setpoint comes before it), what it measures and drives,
the chains (one reference each, by outer loop), the actuators, the matrix ``W`` that maps the
loops' outputs onto the plant inputs (identity, or the decoupler, tuned entries at the exported
gains) and the reference feedforward ``FF`` (plant inputs x chains: ``u = W v + FF r``). The C header
(:mod:`gaintune.export.mimo_c`), the MATLAB file (:mod:`gaintune.export.mimo_matlab`) and the
JSON/YAML/Python payload (:func:`mimo_payload`) are rendered from it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gaintune.export.common import Gains, _version, is_mimo
from gaintune.export.verdict import _Stamp, stamp_fields
from gaintune.spec import TuningSpec

__all__ = ["is_mimo", "mimo_architecture", "mimo_payload"]


def _actuator(spec: TuningSpec, name: str, n_inputs: int) -> dict[str, Any]:
    """The actuator in front of plant input ``name`` (as the MIMO simulator resolves it)."""
    acts = spec.actuators or {}
    a: Any = acts.get(name)
    if a is None and n_inputs == 1 and spec.actuators is None:
        a = spec.actuator  # a single-input plant keeps the spec's one actuator
    if a is None:
        return {"limits": None, "rate_limit": None, "delay": 0.0, "safe_value": 0.0}
    return {"limits": list(a.limits) if a.limits is not None else None, "rate_limit": a.rate_limit,
            "delay": float(getattr(a, "delay", 0.0) or 0.0), "safe_value": float(a.safe_value)}


def _pid_law(lp: Any, g: dict[str, float]) -> dict[str, Any]:
    """One PID loop's parallel-form law (the fields the SISO exports give a loop)."""
    from gaintune.controllers.pid import pid_params

    p = pid_params(lp, g)
    return {"Kp": p.Kp, "Ki": p.Ki, "Kd": p.Kd, "Tf": p.Tf, "b": p.b, "c": p.c, "aw": lp.anti_windup,
            "Tt": p.Tt if math.isfinite(p.Tt) else None, "kb": 1.0 / p.Tt if math.isfinite(p.Tt) else 0.0,
            "Ti": p.Kp / p.Ki if p.Ki * p.Kp > 0 else math.inf, "Td": p.Kd / p.Kp if p.Kp != 0 else 0.0,
            "N": (p.Kd / p.Kp / p.Tf) if p.Tf > 0 and p.Kp != 0 else math.inf}


def mimo_architecture(spec: TuningSpec, gains: Gains) -> dict[str, Any]:
    """The resolved MIMO architecture of ``spec`` with ``gains`` (see the module docstring).

    Returns
    -------
    dict
        ``loops`` (evaluation order; each with its law, ``measure``, ``drives``, ``parent`` and
        ``chain`` positions, limits ``lo``/``hi``, ``direct`` input index or -1), ``order`` (spec
        loop indices in evaluation order), ``chains`` (outer loop names; reference ``r[c]`` feeds
        chain c), ``inputs`` and ``outputs`` (names, units; inputs with their actuator and the loop
        driving them), ``W`` (inputs x loops), ``decoupler`` (its inputs and matrix as numbers, or
        None), ``FF`` (inputs x chains, or None without feedforward), ``feedforward`` (per item its
        loop, chain index, input, input index and gain) and ``blocks`` (the tuned block entries,
        ``{decoupler: {...}, feedforward: {...}}`` as in a gain set).
    """
    from gaintune.controllers.layout import GainLayout
    from gaintune.plants import build_plant
    from gaintune.plants.mimo import as_mimo
    from gaintune.sim.mimo import architecture
    from gaintune.sim.mimo_blocks import BlockMatrices

    plant = build_plant(spec.plant)
    mimo = as_mimo(plant)
    arch = architecture(spec, mimo)
    layout = GainLayout(spec, plant.states, plant=plant)
    full = layout.from_dict(gains)
    named = layout.to_dict(full)
    in_names, outs = mimo.input_names, mimo.outputs
    m = len(in_names)
    acts = [_actuator(spec, n, m) for n in in_names]
    chains = [spec.loop_names[arch.order[int(p)]] for p in arch.roots]
    loops = []
    for pos, i in enumerate(arch.order):
        lp, name = spec.loops[i], spec.loop_names[i]
        j, parent = int(arch.drives[pos]), int(arch.parent[pos])
        direct = j if j >= 0 and spec.decoupler is None else -1
        lo, hi = -math.inf, math.inf
        if lp.output_limits is not None:
            lo, hi = lp.output_limits
        elif direct >= 0 and acts[direct]["limits"] is not None:
            lo, hi = acts[direct]["limits"]
        d: dict[str, Any] = {
            "name": name, "type": lp.type, "form": lp.form, "gains": dict(named[name]),
            "measure": outs[int(arch.meas[pos])], "meas_index": int(arch.meas[pos]),
            "drives": lp.drives or (in_names[j] if j >= 0 else f"loop:{spec.loop_names[arch.order[pos + 1]]}"),
            "drive_index": j, "parent": parent, "chain": chains.index(name) if parent < 0 else -1,
            "direct": direct, "lo": float(lo), "hi": float(hi), "i0": 0.0,
        }
        d.update(_pid_law(lp, d["gains"]))
        loops.append(d)
    Wm, Fm = BlockMatrices(spec, layout, arch.W, arch.drives, arch.order, in_names).one(full)
    W = [[float(x) for x in row] for row in Wm]
    drivers = {ld["drive_index"]: ld["name"] for ld in loops if ld["drive_index"] >= 0}
    inputs = [{"name": s.name, "unit": s.unit, **acts[j], "driven_by": drivers.get(j)}
              for j, s in enumerate(mimo.inputs)]
    outputs = [{"name": s.name, "unit": s.unit} for s in mimo.output_signals]
    blocks = {k: v for k, v in named.items() if k not in spec.loop_names}
    return {"loops": loops, "order": list(arch.order), "chains": chains, "inputs": inputs, "outputs": outputs,
            "W": W, **_static_blocks(spec, arch, Wm, Fm, chains, in_names), "blocks": blocks}


def _static_blocks(spec: TuningSpec, arch: Any, Wm: np.ndarray, Fm: np.ndarray, chains: list[str],
                   in_names: list[str]) -> dict[str, Any]:
    """``decoupler`` (its inputs and matrix as applied: tuned entries at the exported gains, or None),
    ``feedforward`` (per item) and ``FF`` (inputs x chains, None without feedforward)."""
    dec = None
    if spec.decoupler is not None:
        rows = [in_names.index(n) for n in spec.decoupler.inputs]
        cols = [int(np.flatnonzero(arch.drives == j)[0]) if np.any(arch.drives == j) else -1 for j in rows]
        dec = {"inputs": list(spec.decoupler.inputs),
               "matrix": [[float(Wm[ja, c]) if c >= 0 else float(e) for c, e in zip(cols, row, strict=True)]
                          for ja, row in zip(rows, spec.decoupler.values(), strict=True)]}
    roots = [int(p) for p in arch.roots]
    ff = [{"loop": f.loop, "input": f.input, "input_index": in_names.index(f.input),
           "chain": chains.index(f.loop), "gain": float(Fm[in_names.index(f.input), roots[chains.index(f.loop)]])}
          for f in spec.feedforward or []]
    FF = [[float(Fm[j, p]) for p in roots] for j in range(len(in_names))] if ff else None
    return {"decoupler": dec, "FF": FF, "feedforward": ff}


def _clean(x: Any) -> Any:
    """JSON/YAML-safe: infinities as the strings "inf"/"-inf"."""
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_clean(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return "inf" if x > 0 else ("-inf" if x < 0 else "nan")
    return x


def mimo_payload(spec: TuningSpec, gains: Gains, st: _Stamp) -> dict[str, Any]:
    """The JSON/YAML/Python document of a MIMO export: the verdict stamp and the whole architecture."""
    a = mimo_architecture(spec, gains)
    return {
        **stamp_fields(spec, gains, st),
        "architecture": "mimo",
        "evaluation_order": [lp["name"] for lp in a["loops"]],
        "chains": a["chains"],
        "loops": _clean(a["loops"]),
        "inputs": _clean(a["inputs"]),
        "outputs": a["outputs"],
        "W": a["W"],
        "decoupler": a["decoupler"],
        **({"FF": a["FF"], "feedforward": a["feedforward"]} if a["FF"] is not None else {}),
        **({"blocks": a["blocks"]} if a["blocks"] else {}),
        "generator": f"gaintune {_version()}",
    }
