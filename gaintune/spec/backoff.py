"""``requirements.backoff``: how far inside each requirement limit the search aims.

Requirements are hard constraints and the constrained optimum lies on an active one, so
without a back-off the answer sits exactly on its limit (Mks 0.6324 against 0.6325) and
anything the analysis did not model - a controller run at twice the design sample time,
a slightly different discretisation - takes it across. The back-off moves the **aim** of
the search inside every limit by a small amount; the **verdict** still judges the exact
limit, so an answer passes with the back-off as its margin.

:meth:`BackoffSpec.aim` is the one place the aimed limits are computed: the search's
requirement estimate (:mod:`gaintune.evaluation.evaluator`, hence :mod:`gaintune.evaluation.boundary_estimate` and the
search box) and the exact settle step (:mod:`gaintune.evaluation.boundary_exact`) all call it, through
:meth:`gaintune.spec.RequirementsSpec.aimed` or directly.
"""

from __future__ import annotations

from typing import Any

from pydantic import Field, GetJsonSchemaHandler, model_validator
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import core_schema as cs

from gaintune.spec.base import _Model

__all__ = ["BackoffSpec"]

#: Requirement fields that are upper limits on a peak: aimed at ``limit * (1 - peaks)``.
_PEAKS = ("ms_max", "mt_max", "mks_max")
#: Requirement fields the back-off leaves alone: the crossover band is a design target, not a
#: robustness limit (sampling moves the phase, hardly the crossover).
_UNCHANGED = ("wc_min", "wc_max")


class BackoffSpec(_Model):
    """How far inside each requirement limit the search aims; the verdict judges the exact limits, so an
    answer keeps the back-off as its margin. ``backoff: 0`` turns every part off (the answer lands on
    the limit itself). The crossover band (wc_min, wc_max) is not backed off.
    """

    peaks: float = Field(
        0.01, ge=0, lt=0.5,
        description="Relative back-off on the peak limits Ms, Mt and Mks: the search aims at limit x (1 - peaks) "
        "(Ms never below halfway between 1 and its limit).")
    pm_deg: float = Field(
        0.5, ge=0, le=10, description="Phase-margin back-off in degrees: the search aims at pm_min_deg + pm_deg.")
    gm_db: float = Field(
        0.1, ge=0, le=3,
        description="Gain-margin back-off in dB: the search aims at gm_min_db + gm_db (0.1 dB is ~1.2 % of loop gain, "
        "the scale of the peak back-off).")
    dm: float = Field(
        0.01, ge=0, lt=0.5, description="Relative delay-margin back-off: the search aims at dm_min x (1 + dm).")

    @model_validator(mode="before")
    @classmethod
    def _scalar_zero(cls, v: Any) -> Any:
        # `backoff: 0` is the one scalar form: every back-off off.
        if isinstance(v, (dict, BackoffSpec)):
            return v
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"give 0 (no back-off) or a mapping {{peaks, pm_deg, gm_db, dm}}, got {v!r}")
        if v != 0:
            raise ValueError(f"a number here can only be 0 (no back-off), got {v!r}; give a mapping "
                             "such as {peaks: 0.02, pm_deg: 1} to set the amounts")
        return {"peaks": 0.0, "pm_deg": 0.0, "gm_db": 0.0, "dm": 0.0}

    @classmethod
    def __get_pydantic_json_schema__(cls, schema: cs.CoreSchema, handler: GetJsonSchemaHandler) -> JsonSchemaValue:
        # Publish the scalar 0 too, so the JSON schema accepts what the model accepts.
        obj = handler.resolve_ref_schema(handler(schema))
        zero = {"const": 0, "description": "0: no back-off (the answer lands on each limit)."}
        return {"title": obj.pop("title", cls.__name__), "description": obj.pop("description", ""),
                "anyOf": [obj, zero]}

    @property
    def active(self) -> bool:
        """Whether any limit is moved."""
        return any((self.peaks, self.pm_deg, self.gm_db, self.dm))

    def aim(self, requirement: str, limit: float) -> float:
        """The limit the search aims at for ``requirement`` (a requirements field name) of verdict limit ``limit``.

        Minima move up, maxima down; with every back-off 0 the limit itself is returned.

        Parameters
        ----------
        requirement
            ``gm_min_db``, ``pm_min_deg``, ``dm_min``, ``ms_max``, ``mt_max``, ``mks_max`` (a resolved
            per-loop limit), ``wc_min`` or ``wc_max``.
        limit
            The exact limit the verdict judges.
        """
        if not self.active or requirement in _UNCHANGED:
            return limit
        if requirement == "ms_max":  # Ms >= 1 for any loop that rolls off: keep the aim above it
            return max(limit * (1.0 - self.peaks), 0.5 * (1.0 + limit))
        if requirement in _PEAKS:
            return limit * (1.0 - self.peaks)
        if requirement == "pm_min_deg":
            return limit + self.pm_deg
        if requirement == "gm_min_db":
            return limit + self.gm_db
        if requirement == "dm_min":
            return limit * (1.0 + self.dm)
        raise ValueError(f"no back-off is defined for requirement {requirement!r}")
