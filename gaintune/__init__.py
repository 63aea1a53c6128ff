"""gaintune: reinforcement-learning gain tuning for cascaded PID and LQ loops, with verification.

The public API in one import::

    from gaintune import load_spec, tune, verify, TuneResult, VerificationReport

Names are imported on first use (PEP 562), so ``import gaintune`` stays fast and the heavy
search stack (torch, stable-baselines3) loads only when ``tune`` is touched.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

#: public name -> module that defines it
_EXPORTS = {
    "load_spec": "gaintune.spec",
    "TuningSpec": "gaintune.spec",
    # the module that defines the function: once anything imported gaintune.search.tune, the package
    # attribute gaintune.search.tune is that module, so the package cannot be asked
    "tune": "gaintune.search.tune",
    "TuneResult": "gaintune.search.result",
    "verify": "gaintune.verification",
    "VerificationReport": "gaintune.verification.report",
    "versions": "gaintune.provenance",
}

__all__ = ["__version__", *_EXPORTS]

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from gaintune.search.result import TuneResult
    from gaintune.search.tune import tune
    from gaintune.spec import TuningSpec, load_spec
    from gaintune.verification import verify
    from gaintune.verification.report import VerificationReport
    from gaintune.provenance import versions


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'gaintune' has no attribute {name!r}")
    mod = importlib.import_module(module)
    value = getattr(mod, name)
    globals()[name] = value  # later lookups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
