"""``verify(spec, gains) -> VerificationReport``: stability, margins, robustness, nonlinear check, verdict.

The steps are in :mod:`gaintune.verification.steps`; :func:`verify` runs them in order.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.plants.plant import LinearModel, Plant
from gaintune.spec import TuningSpec, load_spec
from gaintune.verification.analysis import analysis_dt, sampling_delay
from gaintune.verification.cascade import build_cascade
from gaintune.verification.context import SpecContext
from gaintune.verification.freqresp import DelayModel
from gaintune.verification.gains import coerce_gains, fixed_gain_overrides
from gaintune.verification.report import VerificationReport
from gaintune.verification.requirements import REQUIREMENTS
from gaintune.verification.sampled import SampledPlant, sample_plant
from gaintune.verification.steps import (
    Findings,
    assemble_report,
    closing_notes,
    noise_figures,
    nominal_analysis,
    nonlinear_step,
    prepare,
    requirement_step,
    robust_step,
    stability_findings,
)

__all__ = ["verify", "coerce_gains", "REQUIREMENTS", "loop_frequency_responses", "analysis_dt"]


def loop_frequency_responses(spec: TuningSpec, plant: Plant, layout: GainLayout, full: np.ndarray, w: np.ndarray,
                             lin: LinearModel | None = None, *, noise: bool = False) -> np.ndarray:
    """L (n_loops + 1, W) at the frequencies ``w`` (rad/s) of every break point of the loop
    :func:`verify` analyses (rows as ``report.loops``): the sampled loop at z = e^{jw dt} (then
    w <= pi/dt is meaningful, higher w are aliases), or the continuous loop with dt/2 and the
    computation delay. For plots of the verified loop (Bode, Nyquist, sensitivity).

    ``noise``: return instead each loop's noise response N_i (n_loops, W), whose peak is Mks
    (:mod:`gaintune.verification.noise`; -C S for one loop)."""
    lin = lin if lin is not None else plant.linearize()
    full = np.asarray(full, dtype=float).reshape(1, -1)
    cas = build_cascade(spec, layout, full, lin)
    s = 1j * np.asarray(w, dtype=float)
    vs, dt = spec.verify, analysis_dt(spec)
    sp: SampledPlant | None = None
    fac: np.ndarray | complex = 1.0
    with np.errstate(all="ignore"):
        if vs.sampled:
            sp = sample_plant(lin, dt, vs.compute_delay, plant.kind == "nonlinear")
        else:
            T = lin.delay + sampling_delay(spec) + vs.compute_delay * dt
            fac = DelayModel(T, vs.pade_order).factor(s)
        if noise:
            return cas.noise_responses(s, lin, fac, sampled=sp)[1][:, 0, :]
        return cas.loop_responses(s, lin, fac, sampled=sp)[:, 0, :]


def _is_mimo(spec: TuningSpec, plant: Plant | None) -> bool:
    """Whether ``spec`` needs the MIMO verdict (:func:`gaintune.sim.simulator.needs_mimo`); the plant is built
    only for a model reference (a plain single-input spec is recognised from the spec)."""
    from gaintune.plants.plant import build_plant, is_mimo_plant_spec
    from gaintune.sim.simulator import needs_mimo

    if plant is None and getattr(spec.plant, "model", None) is None:
        return is_mimo_plant_spec(spec.plant) or needs_mimo(spec, None)
    return needs_mimo(spec, plant if plant is not None else build_plant(spec.plant))


def verify(
    spec: TuningSpec | dict[str, Any] | str | Path,
    gains: Any,
    *,
    robust: bool | None = None,
    nonlinear: bool = True,
    plant: Plant | None = None,
    layout: GainLayout | None = None,
    cache: bool = True,
    spec_hash: str | None = None,
    context: SpecContext | None = None,
) -> VerificationReport:
    """Verify frozen gains against the spec's requirements.

    The loop analysed is, by default (``verify.sampled``), the sampled loop the simulator runs:
    the plant discretised by ZOH with its delay at the largest scenario dt, the controllers'
    discrete laws, margins on z = e^{jw dt} up to pi/dt and stability from the discrete
    closed-loop poles (:mod:`gaintune.verification.sampled`); ``verify.sampled: false`` analyses the
    continuous loop with dt/2 of delay instead. ``verify.compute_delay`` samples of computation
    delay are included either way.

    Parameters
    ----------
    spec
        The tuning problem: a :class:`TuningSpec`, or anything :func:`gaintune.spec.load_spec` takes
        (a dict, a YAML/JSON file path or text).
    gains
        ``{loop: {gain: value}}``, or a vector of all gains (layout order) or of the tuned gains only.
    robust
        Evaluate the randomisation set (box corners + ``verify.robust_samples`` draws); default:
        when the spec randomises plant parameters or the delay. A MIMO spec judges every drawn
        plant's MIMO report (:mod:`gaintune.verification.mimo_robust`).
    nonlinear
        Run the nonlinear simulation check (skipped with a note if :mod:`gaintune.sim` is missing).
    plant, layout
        Pre-built objects to reuse (built from ``spec`` when omitted).
    cache
        Reuse the per-spec plant, layout, linearisation and simulator of earlier calls on the same spec
        (:mod:`gaintune.verification.context`); a cached entry takes precedence over ``plant``/``layout``.
    spec_hash
        ``spec.content_hash()`` when the caller has computed it already (saves hashing the spec again).
    context
        The caller's :class:`gaintune.verification.context.SpecContext` of ``spec`` (its plant, layout,
        linearisation and simulator, e.g. those an evaluator of the same spec built), used instead of the
        cache when every scenario of ``spec`` has its dt and horizon: the same analysis on objects already built.

    Raises
    ------
    GainError
        For NaN, non-positive, missing/unknown gains or a wrong count.
    SpecError, pydantic.ValidationError
        For a spec that is not a valid :class:`TuningSpec` (the message names the field).
    """
    t0 = time.perf_counter()
    tspec = spec if isinstance(spec, TuningSpec) else load_spec(spec)
    if _is_mimo(tspec, plant):  # several plant inputs or a loop graph: the MIMO verdict
        from gaintune.verification.mimo_verdict import verify_mimo

        return verify_mimo(tspec, gains, plant=plant, layout=layout, spec_hash=spec_hash, nonlinear=nonlinear,
                           elapsed_from=t0, robust=robust)
    setup = prepare(tspec, gains, plant, layout, cache, spec_hash, context)
    found = Findings(notes=fixed_gain_overrides(setup.spec, setup.layout, setup.full))
    nom = nominal_analysis(setup, found)
    loops, mks = noise_figures(setup, nom, found)
    stab = stability_findings(nom, found)
    rob, worst = robust_step(setup, nom, mks, robust, found)
    nl = nonlinear_step(setup, stab, nonlinear, found)
    req = requirement_step(setup, loops, worst, stab, rob, found)
    closing_notes(setup, stab, found)
    return assemble_report(setup, nom, found, loops=loops, stab=stab, rob=rob, nl=nl, req=req,
                           elapsed_s=time.perf_counter() - t0)
