"""How many threads one batched simulation may use.

The kernels split a batch over threads of their own (they release the GIL). By default they use
numba's ``NUMBA_NUM_THREADS`` (the machine's cores). A process that was given fewer CPUs, such as a
sweep worker beside other workers, lowers it with :func:`set_sim_threads` so that the workers do
not contend for the same cores.
"""

from __future__ import annotations

_LIMIT: list[int] = []


def set_sim_threads(n: int | None) -> None:
    """Use at most ``n`` threads per simulation in this process (``None``: numba's default)."""
    _LIMIT[:] = [] if n is None else [max(1, int(n))]


def sim_threads() -> int:
    """The number of threads a simulation may use in this process."""
    if _LIMIT:
        return _LIMIT[0]
    import numba as nb

    return max(1, int(nb.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]  # set at import; not in numba's stubs
