"""Classical tuning: FOTD models of a loop's path, tuning rules, the MIGO optimum, default search boxes.

* :func:`fit_fotd` - FOTD model of a loop's plant path (half rule or step-response fit).
* :mod:`~gaintune.classical.rules` - the formulas (Ziegler-Nichols, SIMC, AMIGO, IMC).
* :func:`tune_classical` - a rule applied to every loop of a cascade, inner loop first.
* :func:`rule_candidates` - every rule that applies, as gain sets.
* :func:`auto_bounds` - log-scale search bounds a factor around a gain set.
* :mod:`~gaintune.classical.migo` - the constrained PI optimum under an Ms limit.
* :mod:`~gaintune.classical.blt` - Luyben's BLT for decentralised PI loops on a square MIMO plant.
* :mod:`~gaintune.classical.mimo_references` - published MIMO tunings (Wood-Berry, quadruple tank).

Below the simulator and the evaluation in the layering: this package imports only spec,
plants, controllers and numeric libraries. The rules run on :mod:`gaintune.lti.statespace`'s state
space, not python-control (whose import would cost ``gaintune tune`` about a second);
python-control objects are still accepted. See ``docs/baselines.md``.
"""

from gaintune.classical.fotd import Fotd, NoModelError, fit_fotd
from gaintune.classical.tuning import BOUNDS_FACTOR, CLASSICAL_METHODS, auto_bounds, rule_candidates, tune_classical

__all__ = [
    "Fotd",
    "NoModelError",
    "fit_fotd",
    "BOUNDS_FACTOR",
    "CLASSICAL_METHODS",
    "auto_bounds",
    "rule_candidates",
    "tune_classical",
]
