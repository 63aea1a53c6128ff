"""``gaintune bench kernel``: the simulator kernel timed side by side with an earlier revision of it.

Run from a git checkout of gaintune (it reads the old kernel with ``git show`` in the
checkout this package is imported from)::

    gaintune bench kernel --rev REV [--batch 512] [--min-time 0.4]

``--rev`` has no default: which earlier revision is worth comparing depends on the
checkout (a shallow or rewritten history lacks any fixed hash). Without it, the error
names the last commit that changed the kernel as an example.

The kernel source of ``--rev`` is taken from git into a temporary module (or package,
for revisions where the kernel is the package ``gaintune/sim/kernel/``), so both
kernels run in one process on the same prebuilt arguments (the
:class:`~gaintune.sim.kernel_args.KernelArgs` of ``Simulator.kernel_args``). For
each case of ``gaintune bench sim`` it prints:

* serial kernel, CPU seconds of this thread per simulation (one core; robust to
  other load on the machine), best of interleaved repetitions, at batch 1 (the
  single-lane variant, where ``--rev`` has one) and ``--batch``;
* the speed-up ratio, and whether the two kernels return identical metrics;
* with ``--parallel-batch N`` (default 4,096), the parallel kernels on all cores at
  batch N, wall-clock time (the issue's throughput figure, side by side).

The old kernel at ``e0e478f3`` takes a leading ``chunk`` argument; it is passed 64.
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import inspect
import re
import subprocess
import sys
import tempfile
import time
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.bench import sim as bench_sim
from gaintune.bench.arguments import MAX_BATCH, BenchParser, fail, int_range, positive_float, positive_int
from gaintune.sim import kernel as new_kernel

#: The checkout this package is imported from: its history holds the earlier kernels.
REPO = Path(__file__).resolve().parents[2]
#: Where the kernel lives (a package now; one module in early revisions).
KERNEL_PATHS = ("gaintune/sim/kernel/", "gaintune/sim/kernel.py")
#: A compiled kernel variant: called with a :class:`~gaintune.sim.kernel_args.KernelArgs`'s fields.
Kernel = Callable[..., np.ndarray]


def _git(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True, check=check)


def _git_show(rev: str, path: str) -> str:
    return _git("show", f"{rev}:{path}").stdout


def check_rev(rev: str | None) -> str:
    """``rev`` if it is a commit of this checkout that has a kernel; else exit 2 naming ``--rev`` and an example."""
    try:
        last = _git("log", "-1", "--format=%h", "--", *KERNEL_PATHS, check=False)
    except OSError:  # no git executable
        fail("--rev", "needs git to read the earlier kernel; install git")
    if last.returncode != 0:
        fail("--rev", f"needs a git checkout of gaintune to read the earlier kernel ({REPO} is not one)")
    hint = (f"e.g. --rev {last.stdout.strip()} (the last commit that changed the kernel; "
            f"`git log --oneline -- gaintune/sim/kernel` lists the others)")
    if rev is None:
        fail("--rev", f"give the git revision to compare the working-tree kernel with, {hint}")
    if _git("rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}", check=False).returncode != 0:
        fail("--rev", f"{rev!r} is not a commit of this checkout; {hint}")
    if not _git("ls-tree", "--name-only", rev, "--", *KERNEL_PATHS).stdout.strip():
        fail("--rev", f"{rev} has no simulator kernel ({' or '.join(KERNEL_PATHS)}); {hint}")
    return rev


@functools.cache
def _load_module(rev: str) -> types.ModuleType:
    """The kernel module as of git revision ``rev``, loaded under a private name beside the working tree's.

    A kernel package is copied whole: its modules import each other relatively,
    so the copy runs its own stages, not the working tree's.
    """
    name = "kernel_" + re.sub(r"\W", "_", rev)
    tmp = Path(tempfile.mkdtemp())
    listing = _git("ls-tree", "--name-only", rev, "gaintune/sim/kernel/").stdout.split()
    if listing:
        pkg = tmp / name
        pkg.mkdir()
        for in_repo in listing:
            if in_repo.endswith(".py"):
                (pkg / Path(in_repo).name).write_text(_git_show(rev, in_repo))
        spec = importlib.util.spec_from_file_location(name, pkg / "__init__.py",
                                                      submodule_search_locations=[str(pkg)])
    else:  # the kernel as one module
        path = tmp / f"{name}.py"
        path.write_text(_git_show(rev, "gaintune/sim/kernel.py"))
        spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:  # pragma: no cover - a .py path always gets a source loader
        raise ImportError(f"cannot load the kernel of {rev} from {tmp}")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # the package's relative imports resolve through it
    spec.loader.exec_module(mod)
    return mod


def _load_old(rev: str, variant: str = "simulate_kernel_serial") -> Kernel:
    """The compiled kernel ``variant`` as of git revision ``rev`` (called with the working tree's arguments)."""
    mod = _load_module(rev)
    fn = getattr(mod, variant)
    inner = mod._kernel if hasattr(mod, "_kernel") else mod.drivers._kernel
    takes_chunk = "CHUNK" in inspect.signature(inner).parameters
    return (lambda *a: fn(64, *a)) if takes_chunk else fn


def _parser() -> BenchParser:
    """The options of ``gaintune bench kernel``."""
    ap = BenchParser(prog="gaintune bench kernel", description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--rev", help="git revision of the earlier kernel (required; the error without it suggests one)")
    ap.add_argument("--batch", type=int_range(1, MAX_BATCH), default=512)
    ap.add_argument("--repeat", type=positive_int, default=3)
    ap.add_argument("--min-time", type=positive_float, default=0.4, help="seconds of back-to-back calls per timing")
    ap.add_argument("--parallel-batch", type=int_range(0, MAX_BATCH), default=4096, help="0 skips the parallel rows")
    return ap


def _old_kernels(rev: str, parallel: bool) -> tuple[Kernel, Kernel, Kernel | None]:
    """The serial, batch-1 and (when ``parallel``) parallel kernels of ``rev``; exit 2 naming ``--rev`` if they fail."""
    try:  # a revision's kernel may not fit this tree's arguments or imports: say so, not a traceback
        old = _load_old(rev)
        # batch 1 runs on the single-lane variant; revisions before it existed run it serially
        old1 = _load_old(rev, "simulate_kernel_single") if hasattr(_load_module(rev), "simulate_kernel_single") else old
        old_par = _load_old(rev, "simulate_kernel_parallel") if parallel else None
    except Exception as exc:
        fail("--rev", f"the kernel of {rev} does not load beside this tree ({type(exc).__name__}: {exc}); "
                      "pick a later revision")
    return old, old1, old_par


def _side_by_side(
    old: Kernel, new: Kernel, args: Any, repeat: int, min_time: float,
    clock: Callable[[], float] = time.perf_counter,
) -> tuple[bool, float, float]:
    """(identical metrics, best old and new seconds per call of ``clock``), the two kernels timed interleaved."""
    o_old, o_new = old(*args), new(*args)
    same = np.array_equal(np.nan_to_num(o_old, nan=-7.0), np.nan_to_num(o_new, nan=-7.0))
    t_old, t_new = [], []
    for _ in range(repeat):  # interleaved
        t_old.append(bench_sim._per_call(lambda: old(*args), min_time, clock=clock))
        t_new.append(bench_sim._per_call(lambda: new(*args), min_time, clock=clock))
    return bool(same), min(t_old), min(t_new)


def _serial_table(a: argparse.Namespace, old: Kernel, old1: Kernel) -> None:
    """Serial kernels on one core (thread CPU time) at batch 1 and ``--batch``, one row per case and batch."""
    print(f"serial kernel, one core (thread CPU time), old = {a.rev}, new = working tree")
    print("| case | batch | old sims/s | new sims/s | new ms/sim | speed-up | identical |")
    print("|---|---:|---:|---:|---:|---:|---|")
    for name in bench_sim.CASES:
        for B in (1, a.batch):
            case = bench_sim.make_case(name, B)
            args = case.sim.kernel_args(case.full)
            new = new_kernel.VARIANTS["single" if B == 1 else "serial"]
            same, to, tn = _side_by_side(old1 if B == 1 else old, new, args, a.repeat, a.min_time, time.thread_time)
            print(f"| {name} | {B} | {B / to:,.0f} | {B / tn:,.0f} | {1e3 * tn / B:.4f} | {to / tn:.2f}x | {same} |",
                  flush=True)


def _parallel_table(a: argparse.Namespace, old_par: Kernel) -> None:
    """Parallel kernels on all cores (wall clock) at ``--parallel-batch``, one row per case."""
    B = a.parallel_batch
    print(f"\nparallel kernel, all cores (wall clock), batch {B}")
    print("| case | old sims/s | new sims/s | speed-up | identical |")
    print("|---|---:|---:|---:|---|")
    for name in bench_sim.CASES:
        case = bench_sim.make_case(name, B)
        args = case.sim.kernel_args(case.full)
        same, to, tn = _side_by_side(old_par, new_kernel.VARIANTS["parallel"], args, a.repeat, a.min_time)
        print(f"| {name} | {B / to:,.0f} | {B / tn:,.0f} | {to / tn:.2f}x | {same} |", flush=True)


def main(argv: list[str] | None = None) -> int:
    """``gaintune bench kernel``: the working-tree kernel beside the one of ``--rev``; prints Markdown tables."""
    a = _parser().parse_args(argv)
    check_rev(a.rev)
    old, old1, old_par = _old_kernels(a.rev, bool(a.parallel_batch))
    _serial_table(a, old, old1)
    if old_par is not None:
        _parallel_table(a, old_par)
    return 0


if __name__ == "__main__":
    sys.exit(main())
