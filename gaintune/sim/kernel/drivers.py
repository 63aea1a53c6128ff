"""The compiled, batched closed-loop rollout: the time loop, its compiled variants, and the dispatch.

One call simulates B candidates (gain sets, each with its own plant sample and
scenario draw). Arrays carry the batch on their LAST axis; the batch is cut
into chunks of ``CHUNK`` candidates, and the compiled function runs a given
range of chunks. All state of a chunk lives in one flat array of rows of
``CHUNK`` lanes (see :mod:`.layout`), so memory is O(B) unless traces are requested.

Two variants are compiled from the one source: ``CHUNK`` lanes, and a single
lane for a batch of one (below). A batch of more than one chunk runs on
threads, each a contiguous range of chunks through the same compiled variant
with the GIL released (:func:`simulate_kernel_parallel`). numba's ``prange``
would do the same, but its parfor variant was a third compile, the costliest
(64 s of CPU against ~20 s for each of the others): threads over the serial
variant ran as fast, and compiled nothing more.

Each stage of a time step (signals, measurement, monitor, controllers,
actuator, metrics, plant update) is one short loop over the lanes of a chunk,
written in its own module (:mod:`.signals`, :mod:`.plant`, :mod:`.monitor`,
:mod:`.law`, :mod:`.metrics`) and inlined here at numba IR level
(``inline="always"``): the kernel compiles as one function, as if the stages
were written in the loop below, to the same machine code as the kernel did as
one source file. (The variants need :mod:`.pipeline` for that: without
its copy propagation every array handed to a stage cost a reference-count pair
per step, 3x on a single simulation.) LLVM vectorises the stage loops (AVX2: 4
candidates per instruction). What it took, each measured on the reference case
(see docs/simulation.md):

* one flat state array with a compile-time row stride, indexed with unsigned
  integers (signed indices carry numba's wrap-around select, which hides the
  address from LLVM's dependence analysis);
* ``_min``/``_max`` as plain selects (numba's builtins block vectorisation);
* no conditional stores: "store the new value or the old one" turns into a
  masked store, which is microcoded on AMD cores;
* the stride, and the measured-output row, bound inside the chunk loop:
  as a ``prange`` body, outlined by numba, the loop received them as runtime
  arguments (the parfor variant ran 1.45x slower per thread for it);
* every row a stage loop touches at a compile-time distance from one base:
  the controller loop first copies its setpoint into its own rows, and the
  applied input is kept in the chunk state (``F_U``) beside the delay line.
  Runtime-offset rows left LLVM with memory checks that cost the controller
  loop its speed (1.4x per core on the reference case).

Per-step work is trimmed where results are unchanged bit for bit: a plant
identical across a chunk (many gain sets on the nominal plant) is read as
scalars and its zero entries skipped; the measured output is the true output
when there is no noise; disturbance, fractional-delay and feedthrough terms are
only computed when present; a signal shared by the chunk is evaluated again only
when one of its pieces starts or ends, or while a ramp is active. A batch of one
runs on a single-lane variant of the same source (``CHUNK = 1``, a compile-time
lane count), where every stage loop collapses to straight-line code.

numba's on-disk cache checks only the source file of the function it compiles
(this one), not the modules inlined into it: the variants' names carry a hash
of every kernel source file, so an edit anywhere in the kernel compiles afresh
instead of loading a stale cache.
"""

from __future__ import annotations

import os
import queue
import threading
import types
from concurrent.futures import Future

import numba as nb
import numpy as np

from gaintune.sim.kernel_aot import source_tag as _source_tag
from gaintune.sim.kernel_args import KernelArgs
from gaintune.sim.kernel_cache import use_kernel_cache
from gaintune.sim.threads import sim_threads

from .law import actuator, controllers, init_loops
from .layout import (
    _U,
    CHUNK,
    F_ALIVE,
    F_KLD,
    F_KST,
    F_LAST,
    F_T10,
    F_T90,
    F_UHI,
    F_ULO,
    F_UOP,
    F_UPREV,
    LP0,
    METRICS,
    N_P,
    P_YM,
    P_YT,
)
from .metrics import accumulate_metrics, finish_metrics, record_traces, start_metrics
from .monitor import check_divergence, safety_monitor
from .pipeline import SerialKernelCompiler
from .plant import (
    add_noise,
    delay_shared,
    freeze_dead,
    input_seen_by_outputs,
    outputs_lti,
    outputs_tape,
    plant_input,
    plant_shared,
    update_rk4,
    update_zoh,
    update_zoh_shared,
)
from .signals import fill_signals, hold_shared_signals, signals_shared

__all__ = [
    "simulate_kernel", "run_jit", "simulate_kernel_parallel", "simulate_kernel_serial", "simulate_kernel_single",
    "VARIANTS", "COMPILED",
]


def _kernel(
    n_steps, dt, nonlinear,
    Ad, G0, G1, Cm, Dm,
    f_op, f_a, f_b, f_o, f_c, f_nw, h_op, h_a, h_b, h_o, h_c, h_nw, h_nout, P, meas_idx,
    x_op, u_op, y_op,
    dsteps,
    kp, ki, kd, tf, bw, cw, kb, lo, hi, aw,
    sf, K, kint, nr,
    u_lo, u_hi, rate,
    sk0, sk1, soff, sslope, dist_out_loops,
    noise_std, noise_seed,
    max_err, max_out, xbound, div_bound, safe_mode, u_safe, fb_kp, fb_ki, fb_kd, fb_tf, fb_kb,
    target, k_step, k_load,
    want_traces, tr_y, tr_sp, tr_u,
    chunk0, chunk1,
):
    C = _U(CHUNK)
    n = x_op.shape[0]
    L = kp.shape[0]
    un = _U(n)
    uL = _U(L)
    B = u_op.shape[0]
    out = np.zeros((len(METRICS), B))
    dmax = 0
    any_noise = False
    for b in range(B):
        dmax = max(dmax, dsteps[b])
        any_noise = any_noise or noise_std[b] > 0
    M = dmax + 2  # delay ring-buffer length
    has_G1 = False
    if not nonlinear:
        for i in range(G1.shape[0]):
            for b in range(G1.shape[1]):
                has_G1 = has_G1 or G1[i, b] != 0.0
    has_D = False
    for l in range(Dm.shape[0]):
        for b in range(Dm.shape[1]):
            has_D = has_D or Dm[l, b] != 0.0
    has_sig = np.zeros(3, dtype=np.bool_)
    for sg in range(3):
        for p in range(sk0.shape[1]):
            for b in range(B):
                if sk0[sg, p, b] <= n_steps:
                    has_sig[sg] = True
    monitor = max_err < np.inf or max_out < np.inf
    for i in range(un):
        monitor = monitor or xbound[i] < np.inf
    has_rate = rate < np.inf
    n_in = n + 1 + P.shape[0]
    X0 = LP0 + uL * N_P  # plant state rows X0 + i, next state rows X0 + n + i
    n_rows = X0 + _U(2) * un
    for c in range(chunk0, chunk1):
        # Bound inside the chunk loop's body. Were the loop a prange, numba would pass outer
        # variables into the outlined body as runtime arguments: the row stride would no longer be
        # a compile-time constant, and the measured-output row offset made the controller loop's
        # memory checks opaque (that parfor variant ran ~1.45x slower per thread than the serial one).
        C = _U(CHUNK)
        # measured = true output unless there is noise
        ymf = P_YM if any_noise else P_YT
        b0 = _U(c) * C
        mt = min(C, _U(B) - b0)  # lanes in use, as a runtime count (the tape interpreter's)
        # one lane: a compile-time trip count, so every stage loop unrolls to straight-line code
        # (the tape interpreter keeps the runtime count: unrolled there it measured slower)
        m = C if CHUNK == 1 else mt
        # Signals identical across the chunk (no randomised references) are evaluated once per step.
        shared = signals_shared(sk0, sk1, soff, sslope, b0, m)
        # A plant identical across the chunk (e.g. B gain sets on the nominal plant) is read as scalars.
        shared_plant = not nonlinear
        if shared_plant:
            shared_plant = plant_shared(Ad, G0, G1, Cm, b0, m, un, uL)
        # A delay common to the chunk reads the ring buffer at one row for all lanes (vectorisable).
        shared_delay = delay_shared(dsteps, b0, m)
        S = np.zeros(n_rows * C)
        xa = X0  # rows of the current state; the next state goes to rows xb (swapped every step)
        xb = X0 + un
        all_alive = True
        buf = np.zeros(M * C)
        inp = np.zeros((n_in, C))
        wf = np.zeros((max(f_nw, 1), C))
        wh = np.zeros((max(h_nw, 1), C))
        k1 = np.zeros((n, C))
        k2 = np.zeros((n, C))
        k3 = np.zeros((n, C))
        k4 = np.zeros((n, C))
        hout = np.zeros((max(h_nout, 1), C))
        for j in range(m):
            b = b0 + j
            for i in range(un):
                S[(xa + i) * C + j] = x_op[i, b]
            for q in range(np.uint64(M)):
                buf[q * C + j] = u_op[b]
            S[F_UPREV * C + j] = u_op[b]
            S[F_ALIVE * C + j] = 1.0
            S[F_T10 * C + j] = -1.0
            S[F_T90 * C + j] = -1.0
            S[F_LAST * C + j] = -1.0
            S[F_ULO * C + j] = u_lo[b]
            S[F_UHI * C + j] = u_hi[b]
            S[F_UOP * C + j] = u_op[b]
            S[F_KST * C + j] = k_step[b]
            S[F_KLD * C + j] = k_load[b]
            init_loops(S, C, j, b, uL, kp, ki, kd, tf, kb, bw, cw, lo, hi, u_lo, u_hi, y_op, u_op, dt)
            if nonlinear:
                for q in range(P.shape[0]):
                    inp[n + 1 + q, j] = P[q, b]

        pos = M - 1
        rs = dins = douts = 0.0  # shared signal values, held until the step in *_until
        r_until = din_until = dout_until = 0
        for k in range(n_steps):
            t = k * dt
            pos = pos + 1 if pos + 1 < M else 0  # k % M, without a division per step
            upos = _U(pos)
            check_div = (k & 7) == 0 or k == n_steps - 1
            if shared:
                rs, dins, douts, r_until, din_until, dout_until = hold_shared_signals(
                    k, b0, has_sig, sk0, sk1, soff, sslope, dt, rs, dins, douts, r_until, din_until, dout_until)
            if nonlinear:
                input_seen_by_outputs(S, C, m, b0, pos, M, dsteps, buf)
            fill_signals(S, C, m, k, b0, shared, has_sig, rs, dins, douts, y_op, sk0, sk1, soff, sslope, dt)
            # ---- measured outputs
            if nonlinear:
                outputs_tape(S, C, m, mt, n, un, uL, xa, inp, h_op, h_a, h_b, h_o, h_c, wh, hout, meas_idx,
                             dist_out_loops)
            else:
                outputs_lti(S, C, m, b0, un, uL, xa, shared_plant, has_sig, has_D, Cm, Dm, dist_out_loops, buf, pos,
                            M, dsteps)
            if any_noise:
                add_noise(S, C, m, b0, uL, k, noise_std, noise_seed)
            # ---- divergence every 8 steps, safety monitor
            if check_div:
                all_alive = check_divergence(S, C, m, un, uL, xa, div_bound, all_alive)
            if monitor:
                safety_monitor(S, C, m, b0, un, uL, xa, t, dt, max_err, max_out, xbound, safe_mode,
                               fb_kp, fb_ki, fb_kd, fb_tf, fb_kb)
            # ---- controllers (outer first) and actuator
            controllers(S, C, m, b0, k, uL, un, xa, ymf, sf, aw, dt, nr, y_op, K, x_op, kint)
            actuator(S, C, m, uL, L, aw, has_rate, rate, dt, monitor, safe_mode, u_safe, buf, upos)
            # ---- metrics (streaming: no trace kept)
            if k == 0:
                start_metrics(S, C, m, b0, target)
            accumulate_metrics(S, C, m, k, t, dt)
            # ---- plant input held over the sample, plant update into the next-state rows
            plant_input(S, C, m, b0, pos, M, dsteps, buf, shared_delay, has_G1)
            if nonlinear:
                update_rk4(S, C, m, mt, n, un, xa, xb, dt, f_op, f_a, f_b, f_o, f_c, inp, wf, k1, k2, k3, k4)
            elif shared_plant:
                update_zoh_shared(S, C, m, b0, un, xa, xb, Ad, G0, G1, has_G1)
            else:
                update_zoh(S, C, m, b0, un, xa, xb, Ad, G0, G1, has_G1)
            if not all_alive:
                freeze_dead(S, C, m, un, xb)
            xa, xb = xb, xa
            if want_traces:
                record_traces(S, C, m, b0, k, uL, tr_y, tr_sp, tr_u)

        finish_metrics(out, S, C, m, b0, n_steps, dt, target, k_step)
    return out


# The record and the kernel must agree field for field: a mismatch would splat arrays into the
# wrong parameters, so it fails here, at import, rather than as a typing error or wrong numbers.
_PARAMS = _kernel.__code__.co_varnames[: _kernel.__code__.co_argcount]
if _PARAMS != KernelArgs._fields + ("chunk0", "chunk1"):
    raise ImportError(f"KernelArgs fields do not match the kernel's parameters: {KernelArgs._fields} != {_PARAMS}")


_TAG = _source_tag()


def _compile(lanes: int, name: str):
    """Compile a variant of :func:`_kernel` with ``lanes`` candidates per chunk.

    A distinct function object and qualname per variant keeps numba's on-disk
    caches apart; ``CHUNK`` is frozen into the variant as a compile-time constant.
    The qualname carries :data:`_TAG`, since numba's cache sees only this file.
    ``nogil``: :func:`simulate_kernel_parallel` runs chunk ranges of one batch on threads.
    The cache is a :class:`gaintune.sim.kernel_cache.KernelCache`: a cached variant loads without numba's full set-up.
    """
    glb = dict(_kernel.__globals__, CHUNK=lanes)
    fn = types.FunctionType(_kernel.__code__, glb, "_kernel")
    fn.__qualname__ = f"{name}_{_TAG}"
    return use_kernel_cache(nb.njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract"},
                                    pipeline_class=SerialKernelCompiler)(fn))


#: The compiled variants, each called with a record's fields and then the range of chunks to run:
#: ``"serial"`` with ``CHUNK`` lanes per chunk, and ``"single"`` with one lane, a compile-time
#: count, so every per-lane loop collapses to straight-line code (same source: the same law).
COMPILED = {"serial": _compile(CHUNK, "simulate_kernel_serial"), "single": _compile(1, "simulate_kernel_single")}
_serial, _single = COMPILED["serial"], COMPILED["single"]

_BATCH = KernelArgs._fields.index("u_op")  # the argument that sets the batch size


class _Workers:
    """Daemon threads that run kernel calls (daemon: a finished command exits without joining them)."""

    def __init__(self, n: int) -> None:
        self.pid, self.n = os.getpid(), n
        self._tasks: queue.SimpleQueue = queue.SimpleQueue()
        for i in range(n):
            threading.Thread(target=self._work, name=f"gaintune-kernel-{i}", daemon=True).start()

    def submit(self, fn, *args) -> Future:
        f: Future = Future()
        self._tasks.put((f, fn, args))
        return f

    def _work(self) -> None:
        while True:
            f, fn, args = self._tasks.get()
            if f.set_running_or_notify_cancel():
                try:
                    f.set_result(fn(*args))
                except BaseException as exc:  # noqa: BLE001 - handed to the caller
                    f.set_exception(exc)


_WORKERS: _Workers | None = None
_WORKERS_LOCK = threading.Lock()


def _workers(n: int) -> _Workers:
    """At least ``n`` worker threads of this process (threads do not survive a fork: new ones then)."""
    global _WORKERS
    with _WORKERS_LOCK:
        if _WORKERS is None or _WORKERS.pid != os.getpid() or _WORKERS.n < n:
            _WORKERS = _Workers(n)
        return _WORKERS


def simulate_kernel_single(*args) -> np.ndarray:
    """The single-lane variant on positional arguments (a :class:`KernelArgs` splatted): one chunk per candidate."""
    return _single(*args, 0, args[_BATCH].shape[0])


def simulate_kernel_serial(*args) -> np.ndarray:
    """The ``CHUNK``-lane variant, every chunk in turn on the calling thread."""
    return _serial(*args, 0, -(-args[_BATCH].shape[0] // CHUNK))


def simulate_kernel_parallel(*args) -> np.ndarray:
    """The ``CHUNK``-lane variant on ``sim_threads()`` threads, each a contiguous range of chunks.

    The compiled variant releases the GIL; the calling thread runs the first range. Each call
    sees the whole batch (its batch-wide flags, such as noise anywhere, are those of one serial
    pass) and fills its chunks' columns, so the numbers are the serial variant's, bit for bit.
    """
    B = args[_BATCH].shape[0]
    nchunks = -(-B // CHUNK)
    n = min(sim_threads(), nchunks)
    if n == 1:
        return _serial(*args, 0, nchunks)
    edges = [nchunks * i // n for i in range(n + 1)]
    pool = _workers(n - 1)
    futures = [pool.submit(_serial, *args, lo, hi) for lo, hi in zip(edges[1:-1], edges[2:], strict=True)]
    out = _serial(*args, edges[0], edges[1])
    for lo, hi, f in zip(edges[1:-1], edges[2:], futures, strict=True):
        a, b = lo * CHUNK, min(hi * CHUNK, B)
        out[:, a:b] = f.result()[:, a:b]
    return out


#: The variants by name, for :func:`run_jit`; each takes a :class:`KernelArgs` splatted.
VARIANTS = {"parallel": simulate_kernel_parallel, "serial": simulate_kernel_serial, "single": simulate_kernel_single}


def simulate_kernel(*args) -> np.ndarray:
    """Run the kernel on positional arguments (a :class:`KernelArgs` splatted), choosing the variant.

    The single-lane variant for one candidate, serially for one chunk, else on threads.
    Returns the (16, B) metric rows, in the order of :data:`METRICS`.
    """
    B = args[_BATCH].shape[0]
    if B == 1:
        return _single(*args, 0, 1)
    if B <= CHUNK:
        return _serial(*args, 0, 1)
    return simulate_kernel_parallel(*args)


def run_jit(args: KernelArgs, variant: str = "auto") -> np.ndarray:
    """:func:`gaintune.sim.kernel.run_kernel` on the JIT variants alone (its parameters and return)."""
    if variant == "auto":
        return simulate_kernel(*args)
    try:
        fn = VARIANTS[variant]
    except KeyError:
        raise ValueError(f"unknown kernel variant {variant!r}; expected 'auto' or one of {sorted(VARIANTS)}") from None
    return fn(*args)
