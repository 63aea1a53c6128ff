"""The CMA-ES optimiser of the ``cmaes`` package, imported without loading ``scipy.stats``.

``import cmaes`` runs the package's ``__init__``, which imports every variant it ships. One
of them (``CMAwM``) imports ``scipy.stats`` for two distribution functions, and falls back
to ``cmaes``'s own implementations when ``scipy.stats`` cannot be imported. That import
cost ~0.3 s of every ``gaintune tune`` (``python -X importtime``). gaintune uses only
:class:`cmaes.CMA`, which needs neither, so the first import of ``cmaes`` hides
``scipy.stats`` for its duration. It does so only while the process runs a single Python
thread, so that no other thread can be importing ``scipy.stats`` in that moment; otherwise
``cmaes`` is imported as usual, as it is again should the hidden import fail (a release that
needs ``scipy.stats``). Later imports of ``scipy.stats`` work as usual.
"""

from __future__ import annotations

import sys
import threading
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover
    from cmaes import CMA

__all__ = ["load_cma"]


def load_cma() -> type[CMA]:
    """:class:`cmaes.CMA`; the first import skips ``scipy.stats`` when it is safe (see the module docstring)."""
    if "cmaes" not in sys.modules and "scipy.stats" not in sys.modules and threading.active_count() == 1:
        sys.modules["scipy.stats"] = None  # type: ignore[assignment]  # `from scipy import stats` raises ImportError
        try:
            import cmaes  # noqa: F401  # imported for its side effect: loaded while scipy.stats is blocked
        except ImportError:  # a cmaes that needs scipy.stats after all: imported as usual below
            pass
        finally:
            if "scipy.stats" in sys.modules and sys.modules["scipy.stats"] is None:
                del sys.modules["scipy.stats"]
    from cmaes import CMA

    return CMA
