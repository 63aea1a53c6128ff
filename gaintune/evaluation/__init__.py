"""The evaluation core: a gain set in, its scores out, and the moves onto the requirement boundary.

* :mod:`~gaintune.evaluation.evaluator` - :class:`Evaluator`: cost, requirement violation and the
  feasibility-first merit every search ranks by (:class:`Scores`);
* :mod:`~gaintune.evaluation.search_box` - the default search box and start gains of a spec;
* :mod:`~gaintune.evaluation.boundary` - the loop-gain move onto the requirement boundary, made at
  two fidelities: :mod:`~gaintune.evaluation.boundary_estimate` (``onto_boundary_estimate``, on the
  search estimate, batched) and :mod:`~gaintune.evaluation.boundary_exact` (``onto_boundary_exact``,
  on the exact verification, the last step of every search).

See ``docs/architecture.md``. Import from the modules: this package imports nothing, so the
simulator loads only with the evaluator.
"""
