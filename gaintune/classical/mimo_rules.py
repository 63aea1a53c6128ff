"""Classical rules loop by loop for decentralised loops on a plant with several inputs.

Each loop that drives a plant input directly is tuned by the single-input rules
(:func:`gaintune.classical.tuning.rule_candidates`) on its own path, from the input it drives to the
output it measures with every other loop open; the rules that apply to every loop are combined
into one gain set per rule. A chain of loops (``drives: loop:<name>``) down to the input its
innermost loop drives is tuned the same way as a single-input cascade (inner loop first) on the
path from that input to the outputs its loops measure. This ignores the interaction between the
loops and chains (Luyben's BLT detunes for it): the search box is centred by scoring these sets,
scaled, on the whole plant (:mod:`gaintune.evaluation.search_box`). Ties and a decoupler have no
such per-loop path, nor has a transfer-matrix plant under a chain: no candidates then.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from gaintune.classical.tuning import rule_candidates
from gaintune.errors import SpecError
from gaintune.lti.mimo import TfMatrix
from gaintune.plants import build_plant
from gaintune.plants.mimo import as_mimo
from gaintune.spec import Gains, TuningSpec

__all__ = ["loop_rule_candidates"]


def _path_plant(lti, o: int, j: int) -> dict[str, Any] | None:
    """The plant spec of the single path from input j to output o (None for no path)."""
    if isinstance(lti, TfMatrix):
        e = lti.entries[o][j]
        if e.is_zero:
            return None
        return {"tf": {"num": [float(x) for x in e.num], "den": [float(x) for x in e.den]}, "delay": float(e.delay)}
    return {"ss": {"A": lti.A.tolist(), "B": lti.B[:, j:j + 1].tolist(), "C": lti.C[o:o + 1, :].tolist(),
                   "outputs": ["y"]}, "delay": float(lti.input_delays[j])}


def _chains(spec: TuningSpec, inputs: list[str]) -> list[list[int]] | None:
    """Each chain of the loop graph, outer loop first, ending in the loop that drives a plant input;
    None when a loop drives nothing the plant has."""
    names = spec.loop_names
    child = {}
    for i, lp in enumerate(spec.loops):
        if lp.drives is None or (not lp.drives.startswith("loop:") and lp.drives not in inputs):
            return None
        if lp.drives.startswith("loop:"):
            target = lp.drives[len("loop:"):]
            if target not in names:
                return None
            child[i] = names.index(target)
    driven = set(child.values())
    chains = []
    for i in range(len(names)):
        if i in driven:
            continue
        chain = [i]
        while chain[-1] in child:
            chain.append(child[chain[-1]])
        chains.append(chain)
    return chains


def _chain_plant(lti, outs: list[int], j: int) -> dict[str, Any] | None:
    """The single-input plant spec from input j to the outputs ``outs`` (state space only)."""
    if len(outs) == 1:
        return _path_plant(lti, outs[0], j)
    if isinstance(lti, TfMatrix):
        return _tf_chain_plant(lti, outs, j)
    return {"ss": {"A": lti.A.tolist(), "B": lti.B[:, j:j + 1].tolist(), "C": lti.C[outs, :].tolist(),
                   "outputs": [f"y{k}" for k in range(len(outs))]}, "delay": float(lti.input_delays[j])}


def _tf_chain_plant(lti: TfMatrix, outs: list[int], j: int) -> dict[str, Any] | None:
    """The single-input plant spec from input j to the outputs ``outs`` of a transfer-function matrix:
    the column's entries realised one by one, the delay they share at the input and the rest of each
    entry's delay as a second-order Pade approximant. Only a start for the rules: the search box scores
    every rule candidate on the true plant."""
    col = [lti.entries[o][j] for o in outs]
    if any(e.is_zero for e in col):
        return None
    shared = min(e.delay for e in col)
    sub = TfMatrix(tuple((replace(e, delay=e.delay - shared),) for e in col), (lti.inputs[j],),
                   tuple(f"y{k}" for k in range(len(outs))))
    ss = sub.pade_ss(order=2)
    if np.any(ss.D):
        return None
    return {"ss": {"A": ss.A.tolist(), "B": ss.B.tolist(), "C": ss.C.tolist(), "outputs": list(ss.outputs)},
            "delay": float(shared)}


def _chain_rules(spec: TuningSpec, mp, lti, chain: list[int]) -> dict[str, Gains]:
    """``{method: {loop: gains}}`` of the single-input rules on one chain's own path ({} when none apply)."""
    loops = [spec.loops[i] for i in chain]
    outs = [mp.outputs.index(lp.measure or mp.outputs[0]) for lp in loops]
    path = _chain_plant(lti, outs, mp.input_names.index(loops[-1].drives))
    if path is None:
        return {}
    sub_loops = []
    for k, lp in enumerate(loops):
        d = lp.model_dump(mode="json", exclude={"drives", "measure"})
        if len(loops) > 1:
            d["measure"] = f"y{k}"
        sub_loops.append(d)
    req = spec.requirements.model_dump(mode="json", exclude={"mimo_ms_max", "mimo_mt_max", "disk_margin_min",
                                                              "disk_margin_at"})
    sc = spec.scenarios[0].model_dump(mode="json")
    sc["reference"].pop("loop", None)  # the one chain of the path's spec
    sc["disturbance"].pop("input", None)
    sc["disturbance"].pop("state", None)
    try:
        sub = TuningSpec.model_validate({"plant": path, "loops": sub_loops, "requirements": req, "scenarios": [sc]})
        return rule_candidates(sub, build_plant(sub.plant))
    except (SpecError, ValueError, np.linalg.LinAlgError):
        return {}


def loop_rule_candidates(spec: TuningSpec, plant) -> dict[str, Gains]:
    """``{method: {loop: {gain: value}}}`` of the rules that apply to every loop's own path, or ``{}``."""
    if spec.decoupler is not None or spec.ties or any(lp.is_lq for lp in spec.loops):
        return {}
    mp = as_mimo(plant)
    lti = mp.lti()
    chains = _chains(spec, mp.input_names)
    if not chains:
        return {}
    per_chain = [_chain_rules(spec, mp, lti, chain) for chain in chains]
    common = set.intersection(*(set(r) for r in per_chain))
    names = spec.loop_names
    out: dict[str, Gains] = {}
    for m in sorted(common):
        gains: Gains = {}
        for chain, rules in zip(chains, per_chain, strict=True):
            gains.update({names[i]: rules[m][names[i]] for i in chain})
        out[m] = gains
    return out
