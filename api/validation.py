"""Semantic validation of a spec before it is accepted: service limits, plant build, name checks, gain layout.

Everything that would otherwise fail later in a worker (``build_plant``,
``validate_against_plant``, ``GainLayout``, the simulator set-up) runs here,
synchronously, and becomes a 422 problem naming the field.
"""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass
from typing import Any, Literal

from fastapi import Request
from pydantic import ValidationError

from gaintune.cache import LRU
from gaintune.errors import GaintuneError, problem_details
from gaintune.spec import TuningSpec
from gaintune_api.deps import run_compute
from gaintune_api.problem_details import ApiError
from gaintune_api.settings import Settings

__all__ = ["Checked", "check_spec", "cached_check", "check_and_remember", "checked_spec", "nonfinite_paths", "invalid"]

log = logging.getLogger("gaintune.api")

Purpose = Literal["tune", "verify", "simulate"]
#: CPU seconds a request's thread may spend building its plant and checking it at the randomised
#: parameters' ends before the spec is refused (422 naming the expression's field). A cooperative
#: limit (:func:`gaintune.plants.expr.cpu_budget`), checked at every expression node evaluated: a
#: thread cannot be stopped from outside, and the work between two checks is bounded (degree <=
#: MAX_ORDER, expressions <= 2000 characters). Thread CPU time, so load from other requests does not
#: count. The simulator set-up (SimSetup.build) runs outside it: a cold server compiles kernels there.
SPEC_CPU_SECONDS = 5.0
_CHECK_LOCK = threading.Lock()


@dataclass
class Checked:
    """A spec that passed :func:`check_spec`, with its built plant and gain layout."""

    spec: TuningSpec
    plant: Any
    layout: Any


def invalid(errors: list[dict[str, Any]], detail: str = "The spec is invalid.") -> ApiError:
    """A 422 problem listing ``errors`` (each ``{"loc", "msg"}``)."""
    return ApiError(422, detail, errors=errors)


def nonfinite_paths(obj: Any, prefix: str = "") -> list[str]:
    """Paths of NaN/inf floats anywhere in a dumped model."""
    out: list[str] = []
    stack: list[tuple[Any, str]] = [(obj, prefix)]
    while stack:
        node, path = stack.pop()
        if isinstance(node, float) and not math.isfinite(node):
            out.append(path)
        elif isinstance(node, dict):
            stack.extend((v, f"{path}.{k}" if path else str(k)) for k, v in node.items())
        elif isinstance(node, (list, tuple)):
            stack.extend((v, f"{path}.{i}" if path else str(i)) for i, v in enumerate(node))
    return sorted(out)


def _limits(spec: TuningSpec, s: Settings, purpose: Purpose, prefix: str) -> list[dict[str, str]]:
    errs: list[dict[str, str]] = []
    p = f"{prefix}." if prefix else ""
    for path in nonfinite_paths(spec.model_dump(mode="python"), prefix):
        errs.append({"loc": path, "msg": "must be a finite number (NaN and infinity are not accepted)"})
    if purpose == "tune" and spec.search.budget > s.max_budget:
        errs.append({"loc": f"{p}search.budget",
                     "msg": f"{spec.search.budget} exceeds this server's limit of {s.max_budget} simulations"})
    if len(spec.scenarios) > s.max_scenarios:
        errs.append({"loc": f"{p}scenarios",
                     "msg": f"{len(spec.scenarios)} scenarios exceed this server's limit of {s.max_scenarios}"})
    for i, sc in enumerate(spec.scenarios):
        if sc.resolved and sc.n_steps > s.max_steps:  # derived dt/horizon are checked once chosen (check_spec)
            errs.append({"loc": f"{p}scenarios.{i}.horizon",
                         "msg": f"horizon/dt = {sc.n_steps} steps exceeds this server's limit of {s.max_steps}; "
                                "raise dt or shorten the horizon"})
    if purpose == "verify":
        if spec.verify.n_freq > s.sync_max_n_freq:
            errs.append({"loc": f"{p}verify.n_freq",
                         "msg": f"{spec.verify.n_freq} exceeds the limit of {s.sync_max_n_freq} "
                                "for synchronous verification"})
        if spec.verify.robust_samples > s.sync_max_robust_samples:
            errs.append({"loc": f"{p}verify.robust_samples",
                         "msg": f"{spec.verify.robust_samples} exceeds the limit of {s.sync_max_robust_samples} "
                                "for synchronous verification"})
    return errs


def _prefixed(errs: list[dict[str, Any]], prefix: str) -> list[dict[str, Any]]:
    if not prefix:
        return errs
    return [{**e, "loc": f"{prefix}.{e['loc']}" if e.get("loc") else prefix} for e in errs]


def check_spec(spec: TuningSpec, settings: Settings, purpose: Purpose, *, prefix: str = "") -> Checked:
    """Enforce service limits and build plant + layout. Raises ApiError(422) with [{loc, msg}]."""
    errs = _limits(spec, settings, purpose, prefix)
    if errs:
        raise invalid(errs)
    from gaintune.controllers.layout import GainLayout
    from gaintune.plants import build_plant
    from gaintune.plants.checks import validate_against_plant
    from gaintune.plants.expr import cpu_budget

    try:
        with cpu_budget(SPEC_CPU_SECONDS):  # bounds the plant's expressions; see SPEC_CPU_SECONDS
            plant = build_plant(spec.plant)
            if plant.order > settings.max_order:
                raise invalid([{"loc": f"{prefix + '.' if prefix else ''}plant",
                                "msg": f"plant order {plant.order} exceeds this server's limit "
                                       f"of {settings.max_order}"}])
            validate_against_plant(spec, plant)
        from gaintune.classical.timescale import resolve_scenarios

        spec = resolve_scenarios(spec, plant)  # scenarios without dt/horizon: derived from the plant
        errs = _limits(spec, settings, purpose, prefix)
        if errs:
            raise invalid(errs)
        layout = GainLayout(spec, plant.states)
        if purpose == "tune":
            layout.require_tuned()
        if purpose in ("tune", "simulate"):
            from gaintune.sim.mimo import MimoSimulator
            from gaintune.sim.simulator import needs_mimo

            if needs_mimo(spec, plant):  # several inputs or a loop graph: its loops resolved against the plant
                MimoSimulator(spec, plant, layout)
            else:
                from gaintune.sim.build import SimSetup

                SimSetup.build(spec, plant, layout)
    except ApiError:
        raise
    except (GaintuneError, ValidationError) as exc:
        raise invalid(_prefixed(problem_details(exc), prefix)) from None
    except Exception as exc:  # noqa: BLE001 - user input must never produce a 500
        log.warning("spec rejected by an unexpected %s while building the plant", type(exc).__name__, exc_info=True)
        raise invalid([{"loc": prefix + (".plant" if prefix else "plant"),
                        "msg": f"the plant could not be built ({type(exc).__name__}: {str(exc)[:300]})"}]) from None
    return Checked(spec, plant, layout)


#: Validated specs kept per app (purpose, prefix, spec hash) -> Checked.
CHECK_CACHE_SIZE = 64


def _check_cache(request) -> LRU[tuple, Checked]:
    """The app's LRU of checked specs, created on first use."""
    st = request.app.state
    c = getattr(st, "check_cache", None)
    if c is None:
        with _CHECK_LOCK:  # two first requests must not each install their own cache
            c = getattr(st, "check_cache", None)
            if c is None:
                c = st.check_cache = LRU(CHECK_CACHE_SIZE)
    return c


def cached_check(request: Request, spec: TuningSpec, purpose: Purpose, prefix: str = "",
                 spec_hash: str | None = None) -> Checked | None:
    """The result of an earlier successful :func:`check_spec` of the same spec content, or None.

    Only successes are kept (the limits are the app's settings, fixed for its lifetime).
    ``spec_hash``: ``spec.content_hash()`` when the caller has it already."""
    hit = _check_cache(request).get((purpose, prefix, spec_hash or spec.content_hash()))
    if hit is None:
        return None
    return Checked(spec, hit.plant, hit.layout)


def check_and_remember(request: Request, spec: TuningSpec, purpose: Purpose, prefix: str = "",
                       spec_hash: str | None = None) -> Checked:
    """:func:`check_spec` with the app's settings, remembering a success for :func:`cached_check`."""
    checked = check_spec(spec, request.app.state.settings, purpose, prefix=prefix)
    _check_cache(request).put((purpose, prefix, spec_hash or spec.content_hash()), checked)
    return checked


async def checked_spec(request: Request, spec: TuningSpec, purpose: Purpose, prefix: str = "spec",
                       spec_hash: str | None = None) -> Checked:
    """The spec's semantic check: from the per-spec cache, else computed off the event loop and remembered."""
    checked = cached_check(request, spec, purpose, prefix, spec_hash)
    if checked is None:
        checked = await run_compute(request, check_and_remember, request, spec, purpose, prefix, spec_hash)
    return checked
