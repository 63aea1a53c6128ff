"""The plant families of the ready-made tuners, and their dimensionless form.

A ready-made tuner answers any plant of a classical model family: FOTD ``K e^{-Ls}/(Ts+1)``,
SOTD ``K e^{-Ls}/((T1 s+1)(T2 s+1))`` and integrating-plus-delay ``K e^{-Ls}/(s (T s+1))``. Each
family is self-similar: with time measured in units of the plant's time scale ``tc`` and gain in
units of ``K``, the constrained optimum (load-step IAE under an Ms limit) depends only on the
dimensionless shape, e.g. ``tau = L/(L+T)`` for FOTD (Åström & Hägglund's normalised dead time).
So a tuner is trained on the unit plants of the family (``K = 1``, ``tc = 1``) over the shape
parameters, and :meth:`Family.scale_gains` maps its dimensionless gains to a real plant:
``Kp = kp/K``, ``Ki = ki/(K tc)``, ``Kd = kd tc/K`` (for the integrating family ``K`` is the
velocity gain and the factors carry one more ``tc``). The answer is then verified on the real plant
(its own sample time and horizon), never only on the unit plant.

:func:`problem_spec` is the one definition of the tuning problem every tuner, the reference optimum
and ``gaintune bench tuners`` share: a unit load step at the plant input, cost = its IAE (no effort
term), the Ms limit as the only requirement, at the exact limit (``backoff: 0``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from gaintune.errors import SpecError
from gaintune.spec import TuningSpec, load_spec

__all__ = ["Family", "FAMILIES", "problem_spec", "problem_data", "family", "GAIN_RANGE", "TIME_RANGE"]

#: The plant gains K (the integrating family's: its velocity gain) and the time scales (s) a family tuner
#: answers for. Inside them the unit plant's answer, scaled, is verified on the plant itself
#: (``tests/tuners/test_self_similarity.py`` probes their corners); far outside, the scaled costs, gains and
#: divergence bound leave floating-point range (T = 1e200 s overflowed; K = 1e30 reported the diverged cost).
GAIN_RANGE = (1e-10, 1e10)
TIME_RANGE = (1e-9, 1e8)


@dataclass(frozen=True)
class Family:
    """A self-similar plant family: its model, parameters, shape variables and their ranges.

    Attributes
    ----------
    name
        ``fotd``, ``sotd`` or ``ipd``.
    title
        The model as a formula.
    params
        The physical parameters a query gives (``K``, ``T``, ``L``, ...).
    shape
        The dimensionless shape variables and their training ranges (log-uniform).
    integrating
        The plant has an integrator (K is a velocity gain: gains carry one more time factor).
    """

    name: str
    title: str
    params: tuple[str, ...]
    shape: dict[str, tuple[float, float]]
    integrating: bool = False

    def plant(self, values: Mapping[str, float]) -> dict[str, Any]:
        """The spec's ``plant`` block for physical parameters ``values``."""
        v = {k: float(values[k]) for k in self.params}
        if self.name == "fotd":
            tf = {"num": ["K"], "den": "T*s + 1"}
        elif self.name == "sotd":
            tf = {"num": ["K"], "den": "(T1*s + 1)*(T2*s + 1)"}
        else:
            tf = {"num": ["K"], "den": "s*(T*s + 1)"}
        return {"tf": tf, "delay": "L", "params": v}

    def time_scale(self, v: Mapping[str, float]) -> float:
        """The time unit ``tc`` of the dimensionless form (seconds)."""
        if self.name == "fotd":
            return v["L"] + v["T"]
        if self.name == "sotd":
            return v["L"] + v["T1"] + v["T2"]
        return v["L"] + v["T"]

    def shape_of(self, values: Mapping[str, float]) -> dict[str, float]:
        """The dimensionless shape of a plant (checked: every parameter given, finite, K > 0, lags >= 0)."""
        v = self.checked(values)
        tc = self.time_scale(v)
        if self.name == "fotd":
            return {"tau": v["L"] / tc}
        if self.name == "sotd":
            return {"tau": v["L"] / tc, "r": min(v["T1"], v["T2"]) / max(v["T1"], v["T2"], 1e-300)}
        return {"tau": v["L"] / tc}

    def unit_params(self, shape: Mapping[str, float]) -> dict[str, float]:
        """Physical parameters of the unit plant (K = 1, tc = 1) with this shape."""
        tau = float(shape["tau"])
        if self.name == "sotd":
            r = float(shape["r"])
            lag = 1.0 - tau  # T1 + T2 = 1 - tau, T2 = r T1
            return {"K": 1.0, "T1": lag / (1.0 + r), "T2": lag * r / (1.0 + r), "L": tau}
        return {"K": 1.0, "T": 1.0 - tau, "L": tau}

    def checked(self, values: Mapping[str, float]) -> dict[str, float]:
        """``values`` as floats, every parameter present and in its physical domain (SpecError otherwise)."""
        missing = [p for p in self.params if p not in values]
        if missing:
            raise SpecError(f"params.{missing[0]}", f"the {self.name} family needs {', '.join(self.params)}; "
                            f"give {missing[0]} (-p {missing[0]}=VALUE)")
        extra = sorted(set(values) - set(self.params))
        if extra:
            raise SpecError(f"params.{extra[0]}", f"not a parameter of the {self.name} family {self.title}; "
                            f"its parameters are {', '.join(self.params)}")
        out: dict[str, float] = {}
        for p in self.params:
            x = values[p]
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                raise SpecError(f"params.{p}", f"must be a finite number, got {x!r}")
            out[p] = float(x)
        if out["K"] <= 0:
            raise SpecError("params.K", f"must be > 0 (got {out['K']:g}); for a reverse-acting plant give |K| "
                            "and set the loop's direction to -1")
        for p in self.params[1:]:
            if out[p] < 0:
                raise SpecError(f"params.{p}", f"must be >= 0, got {out[p]:g}")
        if self.time_scale(out) <= 0:
            raise SpecError("params", "the plant has no time scale (all lags and the delay are 0)")
        self._check_scales(out)
        return out

    def _check_scales(self, v: Mapping[str, float]) -> None:
        """SpecError unless the plant's gain K and time scale lie in :data:`GAIN_RANGE` and :data:`TIME_RANGE`."""
        tc = self.time_scale(v)
        lags = " + ".join(["L"] + [p for p in self.params[1:] if p != "L"])
        if not TIME_RANGE[0] <= tc <= TIME_RANGE[1]:
            raise SpecError("params", f"the plant's time scale {lags} = {tc:g} s is outside the {TIME_RANGE[0]:g} to "
                            f"{TIME_RANGE[1]:g} s a ready-made tuner answers for; give the times in other units "
                            "(and scale the answer's Ki and Kd back), or use 'gaintune tune'")
        if not GAIN_RANGE[0] <= v["K"] <= GAIN_RANGE[1]:
            raise SpecError("params.K", f"the plant's gain K = {v['K']:g} is outside the {GAIN_RANGE[0]:g} to "
                            f"{GAIN_RANGE[1]:g} a ready-made tuner answers for; express the output or the input "
                            "in other units (kPa instead of Pa, say), or use 'gaintune tune'")

    def scale_gains(self, unit_gains: Mapping[str, float], values: Mapping[str, float]) -> dict[str, float]:
        """The unit plant's gains scaled to the plant with physical parameters ``values``."""
        v = self.checked(values)
        K, tc = v["K"], self.time_scale(v)
        if self.integrating:
            K = K * tc  # a velocity gain: K e^{-Ls}/s has the static gain K tc at the time unit tc
        factor = {"Kp": 1.0 / K, "Ki": 1.0 / (K * tc), "Kd": tc / K}
        return {g: float(x) * factor[g] for g, x in unit_gains.items()}


FAMILIES: dict[str, Family] = {
    "fotd": Family("fotd", "K e^{-Ls}/(T s + 1)", ("K", "T", "L"), {"tau": (0.05 / 1.05, 10.0 / 11.0)}),
    "sotd": Family("sotd", "K e^{-Ls}/((T1 s + 1)(T2 s + 1))", ("K", "T1", "T2", "L"),
                   {"tau": (0.05 / 1.05, 10.0 / 11.0), "r": (0.05, 1.0)}),
    "ipd": Family("ipd", "K e^{-Ls}/(s (T s + 1))", ("K", "T", "L"), {"tau": (0.05, 0.95)}, integrating=True),
}


def family(name: str) -> Family:
    """The family called ``name`` (SpecError naming ``family`` otherwise)."""
    try:
        return FAMILIES[name]
    except KeyError:
        raise SpecError("family", f"unknown family {name!r}; known: {', '.join(FAMILIES)}") from None


def problem_data(fam: Family, values: Mapping[str, float], ctype: str = "pi", ms_max: float = 1.4,
                 name: str | None = None) -> dict[str, Any]:
    """The spec data of :func:`problem_spec` (a dict :func:`gaintune.spec.load_spec` takes)."""
    v = fam.checked(values)
    return {
        "name": name or f"{fam.name}_{ctype}_ms{ms_max:g}",
        "plant": fam.plant(v),
        "loops": [{"name": "main", "type": ctype}],
        "scenarios": [{"name": "load", "reference": {"kind": "none"},
                       "disturbance": {"kind": "step", "entry": "input", "amplitude": 1.0, "time": 0.0}}],
        "objective": {"measure": "iae", "effort_weight": 0.0},
        "requirements": {"gm_min_db": None, "pm_min_deg": None, "ms_max": ms_max, "backoff": 0},
        **_safety(fam, v),
    }


def _safety(fam: Family, v: Mapping[str, float]) -> dict[str, Any]:
    """The ``safety`` block of a plant whose signals outgrow the unit plant's: its divergence bound scaled.

    The simulator calls a run diverged when a signal passes ``safety.divergence_bound`` (1e6 by default). A
    plant's output scales with its static gain, the controller's integral with the time scale too, and the
    states of a second-order realisation with the time scale squared (the integrating plant's position state
    is the integral of a lag's state): with the default, K = 1e8, T = L = 1e7 s, or an integrating plant with
    T = L = 1e6 s "diverged" on every run although the answer is the unit plant's, scaled
    (``test_plants_far_from_the_unit_plant_get_the_unit_answer_scaled_and_verified``). The bound keeps the unit
    plant's headroom: the default times max(1, static gain) times max(1, time scale) squared. Plants within the
    unit plant's scales keep the default, and their spec is unchanged.
    """
    from gaintune.spec import SafetySpec

    tc = fam.time_scale(v)
    scale = max(1.0, v["K"] * tc if fam.integrating else v["K"]) * max(1.0, tc) ** 2
    if scale == 1.0:
        return {}
    return {"safety": {"divergence_bound": float(SafetySpec.model_fields["divergence_bound"].default) * scale}}


def problem_spec(fam: Family, values: Mapping[str, float], ctype: str = "pi", ms_max: float = 1.4,
                 name: str | None = None) -> TuningSpec:
    """The tuning problem of one plant of ``fam``: unit load step at the input, load IAE, Ms <= ``ms_max``.

    Sample time and horizon are derived from the plant (:mod:`gaintune.classical.timescale`), so a
    plant with T = 60 s is simulated and verified at its own time scale.
    """
    return load_spec(problem_data(fam, values, ctype, ms_max, name))
