"""gaintune: reinforcement-learning gain tuning for cascaded PID and LQ loops, with verification.

The public API in one import::

    from gaintune import load_spec, tune, verify, TuneResult, VerificationReport

Names are imported on first use (PEP 562), so ``import gaintune`` stays fast and the heavy
search stack (torch, stable-baselines3) loads only when ``tune`` is touched.

Examples
--------
A spec (:class:`TuningSpec`, read by :func:`load_spec`), hand-picked gains checked by :func:`verify`
(a :class:`VerificationReport`), and the package versions a result records (:func:`versions`):

>>> from gaintune import TuningSpec, VerificationReport, load_spec, verify, versions
>>> spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
...                   "scenario": {"dt": 0.05, "horizon": 20.0}})
>>> isinstance(spec, TuningSpec), [lp.name for lp in spec.loops]
(True, ['loop0'])
>>> report = verify(spec, {"loop0": {"Kp": 1.14, "Ki": 0.454}})
>>> isinstance(report, VerificationReport), report.verdict
(True, 'pass')
>>> report.accepted_gains
{'loop0': {'Kp': 1.14, 'Ki': 0.454}}
>>> verify(spec, {"loop0": {"Kp": 20.0, "Ki": 20.0}}).accepted_gains is None  # unstable: not accepted
True
>>> "gaintune" in versions()
True

:func:`tune` searches the gains and returns a :class:`TuneResult` (see its own example).
"""

from __future__ import annotations

import importlib
import os
import sys
from typing import TYPE_CHECKING, Any


def _one_blas_thread() -> None:
    """Run BLAS on one thread (a user's own OPENBLAS/MKL_NUM_THREADS setting wins).

    gaintune's linear algebra is on tiny matrices (a 2x2 to 20x20 expm, eigenvalues of a loop), where
    OpenBLAS's worker threads only add wake-up and spin costs: on the 2-core CI machine under load a 2x2
    ``scipy.linalg.expm`` took 5.2 ms with the default threads and 0.010 ms with one. Set before numpy
    loads through the environment; when numpy is already loaded, through threadpoolctl for the BLAS
    libraries loaded so far, and the environment still for those loaded later (scipy bundles its own).
    """
    if "OPENBLAS_NUM_THREADS" in os.environ or "MKL_NUM_THREADS" in os.environ:
        return
    os.environ["OPENBLAS_NUM_THREADS"] = os.environ["MKL_NUM_THREADS"] = "1"
    if "numpy" not in sys.modules:
        return
    from threadpoolctl import threadpool_limits

    threadpool_limits(1, user_api="blas")


_one_blas_thread()

__version__ = "0.1.0"

#: public name -> module that defines it
_EXPORTS = {
    "load_spec": "gaintune.spec",
    "TuningSpec": "gaintune.spec",
    "tune": "gaintune.search.tuning",
    "TuneResult": "gaintune.search.result",
    "verify": "gaintune.verification",
    "VerificationReport": "gaintune.verification.report",
    "versions": "gaintune.provenance",
}

# spelled out, so linters and type checkers see the names (tests/test_public_api.py compares it with _EXPORTS)
__all__ = ["__version__", "load_spec", "TuningSpec", "tune", "TuneResult", "verify", "VerificationReport", "versions"]

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from gaintune.provenance import versions
    from gaintune.search.result import TuneResult
    from gaintune.search.tuning import tune
    from gaintune.spec import TuningSpec, load_spec
    from gaintune.verification import verify
    from gaintune.verification.report import VerificationReport


def __getattr__(name: str) -> Any:
    """Import a public name on first use (PEP 562)."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'gaintune' has no attribute {name!r}")
    mod = importlib.import_module(module)
    value = getattr(mod, name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    """The public names, for ``dir(gaintune)`` and completion."""
    return sorted(__all__)
