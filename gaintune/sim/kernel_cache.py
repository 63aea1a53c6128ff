"""numba's on-disk cache of a compiled kernel, loaded without numba's full target set-up.

Before it loads cached machine code, numba refreshes its whole target context:
it imports every typing and lowering registry (~0.16 s of a fresh process, a
quarter of a fresh ``gaintune tuner query``), which only a compile needs. The
load itself needs numba's runtime (NRT: the kernels allocate their arrays with
it), which that refresh also starts. :class:`KernelCache` starts the runtime and
loads the same cached machine code, so every result bit is unchanged. When the
cache has no entry, numba's compiler refreshes the context first thing, as always.
"""

from __future__ import annotations

from numba.core.caching import FunctionCache
from numba.core.runtime import rtsys

__all__ = ["KernelCache", "use_kernel_cache"]


class KernelCache(FunctionCache):
    """numba's function cache (same files), loading without the refresh of numba's target context.

    ``numba.core.caching.Cache.load_overload`` refreshes the context (every registry's import)
    and then loads; this one starts only what the loaded code calls, numba's runtime (NRT).
    """

    def load_overload(self, sig, target_context):
        rtsys.initialize(target_context)  # idempotent
        with self._guard_against_spurious_io_errors():  # numba's own guard (Windows file locks)
            return self._load_overload(sig, target_context)


def use_kernel_cache(dispatcher):
    """Give a ``cache=True`` numba dispatcher a :class:`KernelCache`; returns the dispatcher.

    A dispatcher without numba's function cache (caching off, or another numba's layout)
    is left as it is: it loads as numba always does.
    """
    if type(getattr(dispatcher, "_cache", None)) is FunctionCache:
        dispatcher._cache = KernelCache(dispatcher.py_func)
    return dispatcher
