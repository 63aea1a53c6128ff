"""Baselines the RL search is judged against: classical rules, black-box optimisers, a reference optimum.

>>> from gaintune.baselines import METHODS
>>> METHODS[:5]
('zn_step', 'zn_ultimate', 'simc', 'amigo', 'imc')

* :func:`run_baseline` - one entry point, returns a :class:`BaselineResult`.
* :func:`auto_bounds` - default log-scale search bounds around the SIMC (else AMIGO) gains.
* :func:`fit_fotd` - FOTD model of a loop's plant path (half rule or step-response fit).
* :mod:`~gaintune.baselines.rules` - the formulas; :mod:`~gaintune.baselines.optimizers`;
  :mod:`~gaintune.baselines.reference`.

See ``docs/baselines.md``.
"""

from gaintune.baselines.classical import BOUNDS_FACTOR, auto_bounds, tune_classical
from gaintune.baselines.fotd import Fotd, NoModelError, fit_fotd
from gaintune.baselines.optimizers import OptResult, optimize
from gaintune.baselines.run import METHODS, BaselineResult, make_evaluator, run_baseline

__all__ = [
    "METHODS",
    "BaselineResult",
    "run_baseline",
    "make_evaluator",
    "auto_bounds",
    "BOUNDS_FACTOR",
    "tune_classical",
    "Fotd",
    "NoModelError",
    "fit_fotd",
    "OptResult",
    "optimize",
]
