"""Steps 1 and 2 of ``gaintune tune --quick``: the loop's classical model and the ready-made tuner for it.

:func:`loop_model` fits the loop's path (actuator to measured output, at the operating point) with
:func:`gaintune.classical.fotd.fit_fotd`, half a sample of delay added as the classical rules add it
(a sampled controller with zero-order hold delays by about dt/2), and names the family it belongs to:

* an integrating path is ``ipd``: ``K e^{-Ls}/(s (T s + 1))`` from the fit's second-order form;
* a self-regulating path whose second-order fit has ``T2/T1 >= SOTD_MIN_RATIO`` is clearly second
  order: ``sotd`` ``K e^{-Ls}/((T1 s + 1)(T2 s + 1))``, when a SOTD tuner for the loop exists;
* otherwise ``fotd`` ``K e^{-Ls}/(T s + 1)``.

:func:`choose_tuner` picks the tuner of that family and controller type whose Ms limit is the
nearest at or below the spec's (the lowest one when none is, or when the spec has no Ms limit:
the move onto the true plant's boundary then sets the loop gain). :func:`tuner_params` maps the
model to the tuner's parameters, a shape outside the tuner's training range moved to its edge
(with a note): the answer is only the start of the settling on the true plant.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.classical.fotd import Fotd, NoModelError, fit_fotd, siso_minreal
from gaintune.classical.rules import IdealPid, to_loop_gains, with_direction
from gaintune.classical.tuning import sample_time
from gaintune.controllers.direction import loop_directions
from gaintune.errors import SpecError
from gaintune.lti.statespace import StateSpace
from gaintune.plants.plant import Plant
from gaintune.spec import Gains, TuningSpec
from gaintune.tuners import artefact
from gaintune.tuners.families import family
from gaintune.tuners.tuner import Tuner

__all__ = ["SOTD_MIN_RATIO", "LoopModel", "TunerInfo", "TunerStart", "loop_model", "available_tuners",
           "choose_tuner", "tuner_params", "tuner_start", "SEARCH_HINT"]

#: T2/T1 of the fitted second-order model from which a path counts as clearly second order.
SOTD_MIN_RATIO = 0.2
#: What to run instead when --quick does not apply.
SEARCH_HINT = "run the search instead: gaintune tune SPEC (without --quick)"


@dataclass(frozen=True)
class LoopModel:
    """The loop's fitted model: its family and the parameters a tuner of that family takes (``K > 0``)."""

    family: str
    params: dict[str, float]
    fotd: Fotd | None
    #: The fit's sign of the path gain (the loop's direction is resolved separately).
    sign: int = 1
    #: Why no model applies (family ``none``: unstable, oscillatory, ... paths).
    reason: str = ""

    def text(self) -> str:
        """The model as one line, e.g. ``FOTD K=2 T=60 L=10.25 (half_rule fit)``."""
        if self.fotd is None:
            return f"no FOTD/SOTD/integrating model ({self.reason})"
        vals = " ".join(f"{k}={v:.4g}" for k, v in self.params.items())
        return f"{self.family.upper()} {vals} ({self.fotd.method} fit)"

    def as_dict(self) -> dict[str, Any]:
        fit = self.fotd.to_dict() if self.fotd is not None else None
        return {"family": self.family, "params": self.params, "fit": fit, "text": self.text()}


@dataclass(frozen=True)
class TunerInfo:
    """A tuner folder and the problem it was trained on (from its ``tuner.json``)."""

    name: str
    folder: Path
    family: str
    ctype: str
    ms_max: float
    extra: dict[str, Any] = field(default_factory=dict, compare=False)


def _siso_path(spec: TuningSpec, plant: Plant) -> tuple[StateSpace, float]:
    lin = plant.linearize()
    loop = spec.loops[0]
    m = lin.output_index(loop.measure) if loop.measure else 0
    siso = siso_minreal(StateSpace(lin.A, lin.B, lin.C[m : m + 1, :], lin.D[m : m + 1, :]))
    return siso, float(lin.delay)


def loop_model(spec: TuningSpec, plant: Plant, sotd: bool = True) -> LoopModel:
    """The loop's model (see the module docstring); ``spec`` has resolved scenarios.

    Raises
    ------
    SpecError
        Naming ``plant`` when no FOTD model applies (unstable, oscillatory, double-integrating or
        zero-gain path), with the reason and the search to run instead.
    """
    siso, delay = _siso_path(spec, plant)
    try:
        m = fit_fotd(siso, delay).with_extra_delay(0.5 * sample_time(spec))
    except NoModelError as exc:
        raise SpecError("plant", f"--quick answers from a FOTD/SOTD/integrating model of the loop, and none "
                        f"applies here: {exc.message.split(';')[0]}; {SEARCH_HINT}") from None
    sign = 1 if m.K > 0 else -1
    K = abs(m.K)
    if m.integrating:
        return LoopModel("ipd", {"K": K, "T": m.T2, "L": m.L2}, m, sign)
    if sotd and m.T1 > 0 and m.T2 >= SOTD_MIN_RATIO * m.T1:
        return LoopModel("sotd", {"K": K, "T1": m.T1, "T2": m.T2, "L": m.L2}, m, sign)
    return LoopModel("fotd", {"K": K, "T": m.T, "L": m.L}, m, sign)


def available_tuners(tuners_dir: str | Path | None = None) -> list[TunerInfo]:
    """The tuners in ``tuners_dir`` (each a sub-folder with ``tuner.json``), default the shipped ones.

    Only family tuners are listed (a tuner trained on a spec's family answers that family alone);
    a folder whose ``tuner.json`` cannot be read is skipped.
    """
    root = Path(tuners_dir) if tuners_dir is not None else artefact.SHIPPED_DIR
    if not root.is_dir():
        return []
    out = []
    for folder in sorted(p for p in root.iterdir() if (p / "tuner.json").is_file()):
        try:
            prob = json.loads((folder / "tuner.json").read_text()).get("problem") or {}
            if prob.get("kind") == "family":
                out.append(TunerInfo(folder.name, folder, str(prob["family"]), str(prob["ctype"]),
                                     float(prob["ms_max"])))
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            continue  # a damaged folder: Tuner.load would name what is wrong if it were chosen
    return out


def choose_tuner(tuners: list[TunerInfo], fam: str, ctype: str, ms_limit: float | None) -> TunerInfo | None:
    """The tuner of ``fam`` and ``ctype`` whose Ms limit is the nearest at or below ``ms_limit``.

    The lowest limit when none is at or below it, or when ``ms_limit`` is None; None when no
    tuner of that family and controller type exists.
    """
    cands = sorted((t for t in tuners if t.family == fam and t.ctype == ctype), key=lambda t: t.ms_max)
    if not cands:
        return None
    if ms_limit is None:
        return cands[0]
    below = [t for t in cands if t.ms_max <= ms_limit + 1e-9]
    return below[-1] if below else cands[0]


def tuner_params(model: LoopModel, problem: Any) -> tuple[dict[str, float], str | None]:
    """The model's parameters for a family tuner's ``problem``, its shape moved inside the training ranges.

    Returns the parameters and a note when the shape was moved (None otherwise).
    """
    fam = family(model.family)
    params = dict(model.params)
    shape = fam.shape_of(params)
    inside = {v.name: float(np.clip(shape[v.name], v.lo, v.hi)) for v in problem.variables}
    if all(math.isclose(inside[k], shape[k], rel_tol=1e-12) for k in inside):
        return params, None
    tc = fam.time_scale(params)
    unit = fam.unit_params(inside)
    moved = {k: (params["K"] if k == "K" else v * tc) for k, v in unit.items()}
    what = ", ".join(f"{k} {shape[k]:.4g} -> {inside[k]:.4g}" for k in inside if not math.isclose(inside[k], shape[k]))
    note = (f"the model's shape lies outside the tuner's training range ({what}; tau is the normalised dead "
            "time): the tuner answered for the nearest shape it knows, and the settling on the true plant set the "
            "loop gain")
    return moved, note


@dataclass
class TunerStart:
    """The loop's model, the tuner chosen for it and its gains for the true loop (None without a tuner)."""

    model: LoopModel
    tuner: TunerInfo | None
    gains: Gains | None
    notes: list[str] = field(default_factory=list)


#: How a note names each requirement.
_REQ_TEXT = {"ms_max": "Ms <= {:g}", "gm_min_db": "GM >= {:g} dB", "pm_min_deg": "PM >= {:g} deg",
             "mt_max": "Mt <= {:g}", "dm_min": "DM >= {:g} s", "wc_min": "wc >= {:g} rad/s",
             "wc_max": "wc <= {:g} rad/s"}


def _notes(spec: TuningSpec, info: TunerInfo) -> list[str]:
    """Notes when the spec asks for more or other than the tuner's Ms limit, or randomises the plant."""
    req = spec.requirements
    asked: dict[str, float] = {k: v for k in _REQ_TEXT if isinstance(v := getattr(req, k, None), (int, float))}
    out = []
    if set(asked) != {"ms_max"} or abs(asked["ms_max"] - info.ms_max) > 1e-9:
        text = ", ".join(_REQ_TEXT[k].format(v) for k, v in asked.items()) or "no requirement"
        out.append(f"tuner {info.name} was trained for Ms <= {info.ms_max:g} alone and the spec asks for {text}: its "
                   "answer is the start that the settling on the true plant moves onto the spec's boundary")
    if spec.randomize.active:
        out.append("the spec randomises the plant: the model and the tuner's answer are for the nominal plant; the "
                   "settling and the verdict cover the randomisation set")
    return out


def _loop_gains(spec: TuningSpec, parallel: dict[str, float], direction: int) -> Gains:
    """Parallel-form magnitudes as the spec's loop writes them (form, sign), fixed gains at their value."""
    loop = spec.loops[0]
    kp, ki, kd = (abs(parallel.get(k, 0.0)) for k in ("Kp", "Ki", "Kd"))
    pid = with_direction(IdealPid(kp, kp / ki if ki > 0 else math.inf, kd / kp if kd > 0 else 0.0), direction)
    gains = to_loop_gains(pid, loop)
    for name, g in loop.gains.items():
        if not g.tune and g.value is not None and name in gains:
            gains[name] = float(g.value)
    return {loop.name or "loop0": gains}


def tuner_start(spec: TuningSpec, plant: Plant, tuners_dir: str | Path | None = None) -> TunerStart:
    """Steps 1 and 2: the model, the tuner of its family, controller type and Ms limit, and its gains.

    ``spec`` has one PI/PID loop and resolved scenarios. Without a tuner for the model's family and
    controller type, ``tuner`` and ``gains`` are None and a note says so.
    """
    ctype = spec.loops[0].type
    tuners = available_tuners(tuners_dir)
    try:
        model = loop_model(spec, plant, sotd=any(t.family == "sotd" and t.ctype == ctype for t in tuners))
    except SpecError as exc:  # unstable, oscillatory, ...: no tuner's family; the search box's start serves
        reason = exc.message.split(": ", 1)[-1].split(";")[0]
        return TunerStart(LoopModel("none", {}, None, 1, reason), None, None,
                          [f"no FOTD/SOTD/integrating model applies ({reason}): the answer starts from the search "
                           "box's start (the best classical rule by the requirements, detuned until feasible, where "
                           "one applies) and the refinement"])
    info = choose_tuner(tuners, model.family, ctype, spec.requirements.ms_max)
    if info is None:
        where = f"in {tuners_dir}" if tuners_dir is not None else "shipped with gaintune"
        have = ", ".join(t.name for t in tuners) or "none"
        return TunerStart(model, None, None, [f"no ready-made tuner for a {model.family.upper()} {ctype.upper()} "
                                              f"loop (tuners {where}: {have}): the answer starts from the rules"])
    tuner = Tuner.load(info.folder)
    try:
        params, note = tuner_params(model, tuner.problem)
        raw, _, _ = tuner.policy_gains(params)
    except SpecError as exc:  # the model's gain or time scale lies outside what the family tuners answer for
        return TunerStart(model, None, None, [f"the tuner {info.name} does not answer for this model "
                                              f"({exc.message.split(';')[0]}): the answer starts from the rules"])
    gains = _loop_gains(spec, next(iter(raw.values())), loop_directions(spec, plant)[0])
    notes = _notes(spec, info) + ([note] if note else [])
    return TunerStart(model, info, gains, notes)
