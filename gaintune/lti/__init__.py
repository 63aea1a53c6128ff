"""Linear time-invariant (LTI) maths every layer may use: nothing here knows about specs, loops or plants.

* :mod:`gaintune.lti.pade` - Padé approximants of a delay, the controller canonical form;
* :mod:`gaintune.lti.modes` - eigenvalues, state responses through the complex Schur form,
  observable modes (remembered per model object);
* :mod:`gaintune.lti.statespace` - the python-control stand-in the classical rules run on (state
  space, conversions, series, step response), bit for bit python-control 0.10's operations.

Each imports numpy and, lazily, scipy.linalg only: python-control costs ~1 s to import.
"""
