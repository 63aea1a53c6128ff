"""Classical rules loop by loop for decentralised loops on a plant with several inputs.

Each loop that drives a plant input directly is tuned by the single-input rules
(:func:`gaintune.classical.tuning.rule_candidates`) on its own path, from the input it drives to the
output it measures with every other loop open; the rules that apply to every loop are combined
into one gain set per rule. This ignores the interaction between the loops (Luyben's BLT detunes
for it): the search box is centred by scoring these sets, scaled, on the whole plant
(:mod:`gaintune.evaluation.search_box`). Chains (``drives: loop:<name>``), ties and a decoupler
have no such per-loop path: no candidates then.
"""

from __future__ import annotations

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


def loop_rule_candidates(spec: TuningSpec, plant) -> dict[str, Gains]:
    """``{method: {loop: {gain: value}}}`` of the rules that apply to every loop's own path, or ``{}``."""
    if spec.decoupler is not None or spec.ties or any(lp.is_lq for lp in spec.loops):
        return {}
    mp = as_mimo(plant)
    lti = mp.lti()
    per_loop: list[dict[str, Gains]] = []
    for lp in spec.loops:
        if lp.drives is None or lp.drives.startswith("loop:") or lp.drives not in mp.input_names:
            return {}
        o = mp.outputs.index(lp.measure or mp.outputs[0])
        path = _path_plant(lti, o, mp.input_names.index(lp.drives))
        if path is None:
            return {}
        loop = lp.model_dump(mode="json", exclude={"drives", "measure"})
        req = spec.requirements.model_dump(mode="json", exclude={"mimo_ms_max", "mimo_mt_max", "disk_margin_min",
                                                                  "disk_margin_at"})
        sc = spec.scenarios[0].model_dump(mode="json")
        sc["reference"].pop("loop", None)  # the one loop of the path's spec
        sc["disturbance"].pop("input", None)
        try:
            sub = TuningSpec.model_validate({"plant": path, "loops": [loop], "requirements": req, "scenarios": [sc]})
            rules = rule_candidates(sub, build_plant(sub.plant))
        except (SpecError, ValueError, np.linalg.LinAlgError):
            return {}
        per_loop.append(rules)
    common = set.intersection(*(set(r) for r in per_loop)) if per_loop else set()
    names = spec.loop_names
    return {m: {names[i]: per_loop[i][m][names[i]] for i in range(len(names))} for m in sorted(common)}
