"""Baselines the RL search is judged against: classical rules, black-box optimisers, a reference optimum.

>>> from gaintune.baselines import METHODS
>>> METHODS[:5]
('zn_step', 'zn_ultimate', 'simc', 'amigo', 'imc')

* :func:`run_baseline` - one entry point, returns a :class:`BaselineResult`.
* :mod:`~gaintune.baselines.optimizers` - random search, CMA-ES, DE, Nelder-Mead on the shared cost.
* :mod:`~gaintune.baselines.reference` - the multistart reference optimum.
* The rules themselves live below, in :mod:`gaintune.classical`.

See ``docs/baselines.md``.
"""

from gaintune.baselines.optimizers import OptResult, optimize
from gaintune.baselines.run import METHODS, BaselineResult, make_evaluator, run_baseline

__all__ = ["METHODS", "BaselineResult", "run_baseline", "make_evaluator", "OptResult", "optimize"]
