"""The compiled, batched closed-loop rollout.

One call simulates B candidates (gain sets, each with its own plant sample and
scenario draw). Arrays carry the batch on their LAST axis; the batch is cut
into chunks of ``CHUNK`` candidates that run in parallel (``prange``). All
state of a chunk lives in one flat array of rows of ``CHUNK`` lanes, so memory
is O(B) unless traces are requested.

Each stage of a time step (signals, measurement, monitor, controllers,
actuator, metrics, plant update) is one short loop over the lanes of a chunk,
and LLVM vectorises these loops (AVX2: 4 candidates per instruction). What it
took, each measured on the reference case (see docs/simulation.md):

* one flat state array with a compile-time row stride, indexed with unsigned
  integers (signed indices carry numba's wrap-around select, which hides the
  address from LLVM's dependence analysis);
* ``_min``/``_max`` as plain selects (numba's builtins block vectorisation);
* no conditional stores: "store the new value or the old one" turns into a
  masked store, which is microcoded on AMD cores;
* the stride, and the measured-output row, re-bound inside the ``prange``
  body, whose outlined function would otherwise receive them as runtime
  arguments;
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

The discrete-time controller law is documented in :mod:`gaintune.controllers.pid`;
the plant update is exact ZOH with a fractional input delay for LTI plants,
and RK4 over a casadi instruction tape for nonlinear ones.
"""

from __future__ import annotations

import math
import types

import numba as nb
import numpy as np

from gaintune.sim import tape as T

__all__ = ["simulate_kernel", "METRICS", "CHUNK"]

CHUNK = 64

#: Metric rows of the kernel's output, in order.
METRICS = (
    "iae", "ise", "itae", "effort", "tv", "overshoot", "rise_time", "settling_time",
    "sse", "sat_frac", "peak_u", "load_iae", "diverged", "tripped", "trip_time", "y_final",
)
(M_IAE, M_ISE, M_ITAE, M_EFFORT, M_TV, M_OVERSHOOT, M_RISE, M_SETTLE, M_SSE, M_SAT,
 M_PEAKU, M_LOAD, M_DIV, M_TRIP, M_TRIPT, M_YFIN) = map(np.uint64, range(len(METRICS)))

AW_NONE, AW_CLAMP, AW_BACKCALC = 0, 1, 2

# Indices into the chunk state are unsigned: with signed ones numba emits a
# negative-index wrap-around select, which hides the affine address from LLVM
# and stops it from vectorising the per-lane loops.
_U = np.uint64


@nb.njit(cache=True, inline="always")
def _max(a, b):
    """``max(a, b)`` exactly as numba's builtin, but as a plain select that LLVM can vectorise."""
    return b if b > a else a


@nb.njit(cache=True, inline="always")
def _min(a, b):
    """``min(a, b)`` exactly as numba's builtin, but as a plain select that LLVM can vectorise."""
    return b if b < a else a


@nb.njit(cache=True)
def _normal(seed: np.int64, k: np.int64, lane: np.int64) -> float:
    """Counter-based standard normal (splitmix64 hash + Box-Muller): reproducible per candidate."""
    z = np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(k) * np.uint64(0xBF58476D1CE4E5B9)
    z = z + np.uint64(lane) * np.uint64(0x94D049BB133111EB) + np.uint64(0x632BE59BD9B4E019)
    z1 = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z1 = (z1 ^ (z1 >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z1 = z1 ^ (z1 >> np.uint64(31))
    z2 = (z1 + np.uint64(0x9E3779B97F4A7C15)) * np.uint64(0xBF58476D1CE4E5B9)
    z2 = z2 ^ (z2 >> np.uint64(31))
    u1 = (float(z1 >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)
    u2 = float(z2 >> np.uint64(11)) * (1.0 / 9007199254740992.0)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@nb.njit(cache=True)
def _run_tape(op, ta, tb, to, tc, inp, w, out, m):
    """Execute a tape on chunk columns 0..m-1: inputs ``inp`` (rows), work ``w``, outputs ``out``."""
    for q in range(op.shape[0]):
        code = op[q]
        a = ta[q]
        b = tb[q]
        o = to[q]
        if code == T.LOAD:
            for j in range(m):
                w[o, j] = inp[a, j]
        elif code == T.STORE:
            for j in range(m):
                out[o, j] = w[a, j]
        elif code == T.CONST:
            for j in range(m):
                w[o, j] = tc[q]
        elif code == T.ADD:
            for j in range(m):
                w[o, j] = w[a, j] + w[b, j]
        elif code == T.SUB:
            for j in range(m):
                w[o, j] = w[a, j] - w[b, j]
        elif code == T.MUL:
            for j in range(m):
                w[o, j] = w[a, j] * w[b, j]
        elif code == T.DIV:
            for j in range(m):
                w[o, j] = w[a, j] / w[b, j]
        elif code == T.NEG:
            for j in range(m):
                w[o, j] = -w[a, j]
        elif code == T.EXP:
            for j in range(m):
                w[o, j] = math.exp(_min(w[a, j], 700.0))
        elif code == T.LOG:
            for j in range(m):
                w[o, j] = math.log(w[a, j]) if w[a, j] > 0 else np.nan
        elif code == T.POW:
            for j in range(m):
                w[o, j] = w[a, j] ** w[b, j]
        elif code == T.SQRT:
            for j in range(m):
                w[o, j] = math.sqrt(w[a, j]) if w[a, j] >= 0 else np.nan
        elif code == T.SQ:
            for j in range(m):
                w[o, j] = w[a, j] * w[a, j]
        elif code == T.TWICE:
            for j in range(m):
                w[o, j] = 2.0 * w[a, j]
        elif code == T.SIN:
            for j in range(m):
                w[o, j] = math.sin(w[a, j])
        elif code == T.COS:
            for j in range(m):
                w[o, j] = math.cos(w[a, j])
        elif code == T.TAN:
            for j in range(m):
                w[o, j] = math.tan(w[a, j])
        elif code == T.ASIN:
            for j in range(m):
                w[o, j] = math.asin(w[a, j]) if abs(w[a, j]) <= 1 else np.nan
        elif code == T.ACOS:
            for j in range(m):
                w[o, j] = math.acos(w[a, j]) if abs(w[a, j]) <= 1 else np.nan
        elif code == T.ATAN:
            for j in range(m):
                w[o, j] = math.atan(w[a, j])
        elif code == T.ATAN2:
            for j in range(m):
                w[o, j] = math.atan2(w[a, j], w[b, j])
        elif code == T.SINH:
            for j in range(m):
                w[o, j] = math.sinh(_min(_max(w[a, j], -700.0), 700.0))
        elif code == T.COSH:
            for j in range(m):
                w[o, j] = math.cosh(_min(_max(w[a, j], -700.0), 700.0))
        elif code == T.TANH:
            for j in range(m):
                w[o, j] = math.tanh(w[a, j])
        elif code == T.FABS:
            for j in range(m):
                w[o, j] = abs(w[a, j])
        elif code == T.SIGN:
            for j in range(m):
                x = w[a, j]
                w[o, j] = 1.0 if x > 0 else (-1.0 if x < 0 else 0.0)
        elif code == T.FMIN:
            for j in range(m):
                w[o, j] = _min(w[a, j], w[b, j])
        elif code == T.FMAX:
            for j in range(m):
                w[o, j] = _max(w[a, j], w[b, j])
        elif code == T.INV:
            for j in range(m):
                w[o, j] = 1.0 / w[a, j]
        elif code == T.LT:
            for j in range(m):
                w[o, j] = 1.0 if w[a, j] < w[b, j] else 0.0
        elif code == T.LE:
            for j in range(m):
                w[o, j] = 1.0 if w[a, j] <= w[b, j] else 0.0
        elif code == T.EQ:
            for j in range(m):
                w[o, j] = 1.0 if w[a, j] == w[b, j] else 0.0
        elif code == T.NE:
            for j in range(m):
                w[o, j] = 1.0 if w[a, j] != w[b, j] else 0.0
        elif code == T.NOT:
            for j in range(m):
                w[o, j] = 1.0 if w[a, j] == 0 else 0.0
        elif code == T.AND:
            for j in range(m):
                w[o, j] = 1.0 if ((w[a, j] != 0) & (w[b, j] != 0)) else 0.0
        elif code == T.OR:
            for j in range(m):
                w[o, j] = 1.0 if ((w[a, j] != 0) | (w[b, j] != 0)) else 0.0
        elif code == T.IF_ELSE_ZERO:
            for j in range(m):
                v = w[b, j]  # loaded unconditionally: no masked load in the vector loop
                w[o, j] = v if w[a, j] != 0 else 0.0
        elif code == T.ASSIGN:
            for j in range(m):
                w[o, j] = w[a, j]



# ---------------------------------------------------------------- chunk state layout
# All mutable state of a chunk lives in ONE flat float array ``S`` of rows of
# ``CHUNK`` lanes: value ``(row, lane j)`` is ``S[row * CHUNK + j]``. Because
# ``CHUNK`` is a compile-time constant, two rows of the same loop body are a
# known constant distance apart, which lets LLVM prove the per-lane loops free
# of overlap and vectorise them (AVX2: 4 candidates per instruction). With 2-D
# chunk arrays (runtime strides, separate allocations) it could not, and this
# layout measured about 3x faster per core on the reference case.

# Per-candidate scalar fields: rows 0 .. N_F-1.
(F_UPREV, F_ALIVE, F_TRIP, F_Z, F_Y0, F_INVSPAN, F_PEAK, F_T10, F_T90, F_LAST, F_ULO, F_UHI,
 F_UOP, F_KST, F_KLD, F_R, F_DIN, F_DOUT, F_UA, F_UB, F_U) = map(_U, range(21))
N_F = _U(21)
#: Metric accumulators: rows A0 + metric index.
A0 = N_F
#: Per-loop fields: rows LP0 + loop * N_P + field.
LP0 = A0 + _U(len(METRICS))
(P_YM, P_YT, P_I, P_D, P_EDP, P_AWE, P_VOUT, P_SP, P_KP, P_KI, P_KB, P_AL, P_BE, P_BW, P_CW,
 P_LO, P_HI) = map(_U, range(17))
N_P = _U(17)
_1 = _U(1)


@nb.njit(cache=True)
def _signal(s, k, b, sk0, sk1, soff, sslope, dt):
    """Sum of the additive pieces of signal ``s`` active at step k for candidate b."""
    v = 0.0
    for p in range(sk0.shape[1]):
        k0 = sk0[s, p, b]
        if k >= k0 and k < sk1[s, p, b]:
            v += soff[s, p, b] + sslope[s, p, b] * ((k - k0) * dt)
    return v


@nb.njit(cache=True)
def _signal_until(s, k, b, sk0, sk1, sslope):
    """First step after k at which signal ``s`` of candidate b can change.

    Between piece starts and ends a signal whose active pieces are all flat
    (steps, sequences) keeps the value :func:`_signal` gave at k, exactly; a
    sloped active piece (ramp) changes it every step.
    """
    until = np.iinfo(np.int64).max
    for p in range(sk0.shape[1]):
        k0 = sk0[s, p, b]
        k1 = sk1[s, p, b]
        if k0 > k:
            until = min(until, k0)
        elif k1 > k:
            until = min(until, k1)
            if sslope[s, p, b] != 0.0:
                return k + 1
    return until


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
):
    C = _U(CHUNK)
    n = x_op.shape[0]
    L = kp.shape[0]
    un = _U(n)
    uL = _U(L)
    B = u_op.shape[0]
    nchunks = (B + C - 1) // C
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
    for c in nb.prange(nchunks):
        # re-bound inside the parallel body: numba passes outer variables into the outlined
        # body as arguments, which would hide the compile-time row stride from LLVM
        C = _U(CHUNK)
        # measured = true output unless there is noise. Bound here for the same reason: as an
        # argument of the outlined body, this row offset made the controller loop's memory checks
        # opaque, and the parallel kernel ran ~1.45x slower per thread than the serial one.
        ymf = P_YM if any_noise else P_YT
        b0 = _U(c) * C
        mt = min(C, _U(B) - b0)  # lanes in use, as a runtime count (the tape interpreter's)
        # one lane: a compile-time trip count, so every stage loop unrolls to straight-line code
        # (the tape interpreter keeps the runtime count: unrolled there it measured slower)
        m = C if CHUNK == 1 else mt
        # Signals identical across the chunk (no randomised references) are evaluated once per step.
        shared = True
        for sg in range(3):
            for p in range(sk0.shape[1]):
                for j in range(m):
                    b = b0 + j
                    if (sk0[sg, p, b] != sk0[sg, p, b0] or sk1[sg, p, b] != sk1[sg, p, b0]
                            or soff[sg, p, b] != soff[sg, p, b0] or sslope[sg, p, b] != sslope[sg, p, b0]):
                        shared = False
        # A plant identical across the chunk (e.g. B gain sets on the nominal plant) is read as scalars.
        shared_plant = not nonlinear
        if shared_plant:
            for j in range(_1, m):
                b = b0 + j
                for i in range(un):
                    shared_plant = shared_plant and G0[i, b] == G0[i, b0] and G1[i, b] == G1[i, b0]
                    for q in range(un):
                        shared_plant = shared_plant and Ad[i, q, b] == Ad[i, q, b0]
                    for l in range(uL):
                        shared_plant = shared_plant and Cm[l, i, b] == Cm[l, i, b0]
        # A delay common to the chunk reads the ring buffer at one row for all lanes (vectorisable).
        shared_delay = True
        for j in range(m):
            shared_delay = shared_delay and dsteps[b0 + j] == dsteps[b0]
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
            for l in range(uL):
                p = (LP0 + l * N_P) * C + j
                S[p + P_KP * C] = kp[l, b]
                S[p + P_KI * C] = ki[l, b] * dt  # stored times dt: one multiply less per step
                S[p + P_KB * C] = kb[l, b] * dt
                S[p + P_AL * C] = tf[l, b] / (tf[l, b] + dt)
                S[p + P_BE * C] = kd[l, b] / (tf[l, b] + dt)
                S[p + P_BW * C] = bw[l, b]
                S[p + P_CW * C] = cw[l, b]
                S[p + P_LO * C] = u_lo[b] if l == uL - _1 else lo[l, b]
                S[p + P_HI * C] = u_hi[b] if l == uL - _1 else hi[l, b]
                # bumpless start at the operating point: integrators hold the next setpoint / u0
                S[p + P_I * C] = y_op[l + _1, b] if l + _1 < uL else u_op[b]
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
                # evaluated again only when a piece starts or ends, or while a ramp is active
                # (the signal scan measured ~30 % of a single simulation when done every step)
                if k >= r_until:
                    rs = _signal(0, k, b0, sk0, sk1, soff, sslope, dt)
                    r_until = _signal_until(0, k, b0, sk0, sk1, sslope)
                if has_sig[1] and k >= din_until:
                    dins = _signal(1, k, b0, sk0, sk1, soff, sslope, dt)
                    din_until = _signal_until(1, k, b0, sk0, sk1, sslope)
                if has_sig[2] and k >= dout_until:
                    douts = _signal(2, k, b0, sk0, sk1, soff, sslope, dt)
                    dout_until = _signal_until(2, k, b0, sk0, sk1, sslope)
            # ---- plant input seen by the outputs (only the delayed u[k-1-d] is known before u[k])
            if nonlinear:
                for j in range(m):
                    idd = pos - 1 - dsteps[b0 + j]
                    S[F_UB * C + j] = buf[_U(idd + M if idd < 0 else idd) * C + j]
            # ---- signals
            if shared:
                for j in range(m):
                    S[F_R * C + j] = rs + y_op[0, b0 + j]
                if has_sig[1]:
                    for j in range(m):
                        S[F_DIN * C + j] = dins
                if has_sig[2]:
                    for j in range(m):
                        S[F_DOUT * C + j] = douts
            else:
                for j in range(m):
                    b = b0 + j
                    S[F_R * C + j] = _signal(0, k, b, sk0, sk1, soff, sslope, dt) + y_op[0, b]
                    S[F_DIN * C + j] = _signal(1, k, b, sk0, sk1, soff, sslope, dt) if has_sig[1] else 0.0
                    S[F_DOUT * C + j] = _signal(2, k, b, sk0, sk1, soff, sslope, dt) if has_sig[2] else 0.0
            # ---- true outputs
            if nonlinear:
                for j in range(m):
                    for i in range(un):
                        inp[i, j] = S[(xa + i) * C + j]
                    inp[n, j] = S[F_UB * C + j] + S[F_DIN * C + j]
                _run_tape(h_op, h_a, h_b, h_o, h_c, inp, wh, hout, mt)
                for l in range(uL):
                    mi = meas_idx[l]
                    dl = dist_out_loops[l]
                    yt = (LP0 + l * N_P + P_YT) * C
                    for j in range(m):
                        S[yt + j] = hout[mi, j] + dl * S[F_DOUT * C + j]
            else:
                for l in range(uL):
                    dl = dist_out_loops[l]
                    yt = (LP0 + l * N_P + P_YT) * C
                    if has_sig[2]:
                        for j in range(m):
                            S[yt + j] = dl * S[F_DOUT * C + j]
                    else:
                        for j in range(m):
                            S[yt + j] = 0.0
                    for i in range(un):
                        xi = (xa + i) * C
                        if shared_plant:
                            cli = Cm[l, i, b0]
                            if cli != 0.0:
                                for j in range(m):
                                    S[yt + j] += cli * S[xi + j]
                        else:
                            for j in range(m):
                                S[yt + j] += Cm[l, i, b0 + j] * S[xi + j]
                    if has_D:  # feedthrough sees only delayed inputs (d >= 1 is enforced)
                        for j in range(m):
                            b = b0 + j
                            idd = pos - dsteps[b]
                            S[yt + j] += Dm[l, b] * (buf[_U(idd + M if idd < 0 else idd) * C + j] + S[F_DIN * C + j])
            if any_noise:
                for l in range(uL):
                    p = (LP0 + l * N_P) * C
                    for j in range(m):
                        S[p + P_YM * C + j] = S[p + P_YT * C + j]
                    for j in range(m):
                        b = b0 + j
                        if noise_std[b] > 0:
                            S[p + P_YM * C + j] += noise_std[b] * _normal(noise_seed[b], k, l)
            # ---- divergence (NaN/inf or beyond the bound), every 8 steps: NaN and inf propagate
            if check_div:
                for i in range(un):
                    xi = (xa + i) * C
                    for j in range(m):
                        S[F_ALIVE * C + j] *= 1.0 if abs(S[xi + j]) <= div_bound else 0.0
                for l in range(uL):
                    yt = (LP0 + l * N_P + P_YT) * C
                    for j in range(m):
                        S[F_ALIVE * C + j] *= 1.0 if abs(S[yt + j]) <= div_bound else 0.0
                if all_alive:
                    for j in range(m):
                        all_alive = all_alive and S[F_ALIVE * C + j] != 0.0
            # ---- safety monitor
            if monitor:
                for j in range(m):
                    if S[F_TRIP * C + j] != 0.0 or S[F_ALIVE * C + j] == 0.0:
                        continue
                    b = b0 + j
                    trip = abs(S[F_R * C + j] - S[(LP0 + P_YT) * C + j]) > max_err
                    for l in range(uL):
                        trip = trip or abs(S[(LP0 + l * N_P + P_YT) * C + j]) > max_out
                    for i in range(un):
                        trip = trip or abs(S[(xa + i) * C + j]) > xbound[i]
                    if trip:
                        S[F_TRIP * C + j] = 1.0
                        S[(A0 + M_TRIP) * C + j] = 1.0
                        S[(A0 + M_TRIPT) * C + j] = t
                        if safe_mode == 1:
                            for l in range(uL):
                                p = (LP0 + l * N_P) * C + j
                                S[p + P_KP * C] = fb_kp[l, b]
                                S[p + P_KI * C] = fb_ki[l, b] * dt
                                S[p + P_KB * C] = fb_kb[l, b] * dt
                                S[p + P_AL * C] = fb_tf[l, b] / (fb_tf[l, b] + dt)
                                S[p + P_BE * C] = fb_kd[l, b] / (fb_tf[l, b] + dt)
            # ---- controllers, outer loop first; each output is the next loop's setpoint
            for l in range(uL):
                p = (LP0 + l * N_P) * C
                # the setpoint row: the reference, or the outer loop's output
                sprow = F_R * C if l == 0 else (LP0 + (l - _1) * N_P + P_VOUT) * C
                if l == uL - _1 and sf:
                    for j in range(m):
                        b = b0 + j
                        sp = S[sprow + j]
                        e = sp - S[p + ymf * C + j]
                        v = S[F_UOP * C + j] + nr[b] * (sp - y_op[l, b])
                        for i in range(un):
                            v -= K[i, b] * (S[(xa + i) * C + j] - x_op[i, b])
                        zt = S[F_Z * C + j] + dt * e
                        vu = v + kint[b] * zt
                        vs = _min(_max(vu, S[F_ULO * C + j]), S[F_UHI * C + j])
                        if vs != vu and e * kint[b] * (vu - vs) > 0:
                            vs = _min(_max(v + kint[b] * S[F_Z * C + j], S[F_ULO * C + j]), S[F_UHI * C + j])
                        else:
                            S[F_Z * C + j] = zt
                        S[p + P_SP * C + j] = sp
                        S[p + P_VOUT * C + j] = vs
                    continue
                mode = aw[l]
                if k == 0:
                    for j in range(m):  # no derivative kick at start (inner setpoints are known only now)
                        S[p + P_EDP * C + j] = S[p + P_CW * C + j] * S[sprow + j] - S[p + ymf * C + j]
                backcalc = mode == AW_BACKCALC
                clamp = mode == AW_CLAMP
                # the setpoint is copied into this loop's own rows first: the stage loop then touches
                # only rows at compile-time distances from p, and it measured ~1.4x faster per core
                for j in range(m):
                    S[p + P_SP * C + j] = S[sprow + j]
                for j in range(m):
                    sp = S[p + P_SP * C + j]
                    y = S[p + ymf * C + j]
                    e = sp - y
                    ed = S[p + P_CW * C + j] * sp - y
                    dterm = S[p + P_AL * C + j] * S[p + P_D * C + j] + S[p + P_BE * C + j] * (ed - S[p + P_EDP * C + j])
                    S[p + P_EDP * C + j] = ed
                    S[p + P_D * C + j] = dterm
                    pterm = S[p + P_KP * C + j] * (S[p + P_BW * C + j] * sp - y)
                    iold = S[p + P_I * C + j]
                    it = iold + S[p + P_KI * C + j] * e
                    if backcalc:
                        it += S[p + P_KB * C + j] * S[p + P_AWE * C + j]
                    vu = pterm + it + dterm
                    vlo = S[p + P_LO * C + j]
                    vhi = S[p + P_HI * C + j]
                    vs = _min(_max(vu, vlo), vhi)
                    if clamp:
                        # conditional integration: do not integrate further into saturation
                        hold = (vs != vu) & (e * (vu - vs) * S[p + P_KI * C + j] > 0)
                        it = (iold + 0.0) if hold else it  # + 0.0: see the step metrics below
                        vu = pterm + it + dterm
                        vs = _min(_max(vu, vlo), vhi)
                    S[p + P_I * C + j] = it
                    S[p + P_AWE * C + j] = vs - vu
                    S[p + P_VOUT * C + j] = vs
            # ---- actuator: rate limit, safety hold, dead candidates at rest
            vout = (LP0 + (uL - _1) * N_P + P_VOUT) * C
            hold_safe = monitor and safe_mode == 0
            for j in range(m):
                uprev = S[F_UPREV * C + j]
                u = S[vout + j]
                if has_rate:
                    u = _min(_max(u, uprev - rate * dt), uprev + rate * dt)
                if hold_safe:
                    u = u_safe if S[F_TRIP * C + j] > 0.0 else u
                uop = S[F_UOP * C + j]  # loaded unconditionally: no masked load
                u = u if S[F_ALIVE * C + j] > 0.0 else uop
                S[F_U * C + j] = u
            # the applied input also goes to the delay line, in a loop of its own, so that the
            # actuator and metrics loops touch only the chunk state ``S``
            for j in range(m):
                buf[upos * C + j] = S[F_U * C + j]
            if aw[L - 1] == AW_BACKCALC:
                awe = (LP0 + (uL - _1) * N_P + P_AWE) * C
                for j in range(m):
                    S[awe + j] += S[F_U * C + j] - S[vout + j]  # track what was applied
            # ---- metrics, masked by alive (streaming: no trace kept). Conditions combine
            # with & and | (not and/or): short-circuit branches cost 2x in the vectorised loop.
            y0row = (LP0 + P_YT) * C
            if k == 0:
                for j in range(m):
                    S[F_Y0 * C + j] = S[y0row + j]
                    span = target[b0 + j] - S[F_Y0 * C + j]
                    S[F_INVSPAN * C + j] = 1.0 / span if span != 0.0 else 0.0
                    if span == 0.0:  # no step to measure: step metrics never start
                        S[F_KST * C + j] = np.inf
            for j in range(m):
                a = S[F_ALIVE * C + j]
                u = S[F_U * C + j]
                y0 = S[y0row + j]
                e0 = S[F_R * C + j] - y0
                ae = abs(e0)
                du = u - S[F_UOP * C + j]
                # integrals of a candidate that dies are replaced by inf at the end: no alive mask needed
                S[(A0 + M_IAE) * C + j] += ae * dt
                S[(A0 + M_ISE) * C + j] += e0 * e0 * dt
                S[(A0 + M_ITAE) * C + j] += t * ae * dt
                S[(A0 + M_EFFORT) * C + j] += du * du * dt
                S[(A0 + M_TV) * C + j] += abs(u - S[F_UPREV * C + j])
                S[(A0 + M_PEAKU) * C + j] = _max(S[(A0 + M_PEAKU) * C + j] + 0.0, abs(du))
                S[(A0 + M_SAT) * C + j] += a * ((u <= S[F_ULO * C + j]) | (u >= S[F_UHI * C + j]))
                S[(A0 + M_LOAD) * C + j] += (k >= S[F_KLD * C + j]) * ae * dt
                S[F_UPREV * C + j] = u
                # step metrics relative to the final reference value
                dev = (y0 - S[F_Y0 * C + j]) * S[F_INVSPAN * C + j]
                act = (k >= S[F_KST * C + j]) & (a > 0.0)
                # "+ 0.0" (exact here) keeps LLVM from turning "store the new value or the old one"
                # into a masked store, which is microcoded and several times slower on AMD cores
                pk = S[F_PEAK * C + j] + 0.0
                S[F_PEAK * C + j] = _max(pk, dev) if act else pk
                t10 = S[F_T10 * C + j] + 0.0
                S[F_T10 * C + j] = t if (act & (t10 < 0) & (dev >= 0.1)) else t10
                t90 = S[F_T90 * C + j] + 0.0
                S[F_T90 * C + j] = t if (act & (t90 < 0) & (dev >= 0.9)) else t90
                last = S[F_LAST * C + j] + 0.0
                S[F_LAST * C + j] = k if (act & (abs(dev - 1.0) >= 0.02)) else last
            # ---- plant input held over this sample: ua = u[k-d], ub = u[k-d-1] (+ input disturbance)
            if shared_delay:
                ia = pos - dsteps[b0]
                ia = ia + M if ia < 0 else ia
                ib = ia - 1 if ia > 0 else M - 1
                for j in range(m):
                    S[F_UA * C + j] = buf[_U(ia) * C + j] + S[F_DIN * C + j]
                if has_G1:  # the previous input only matters with a fractional delay
                    for j in range(m):
                        S[F_UB * C + j] = buf[_U(ib) * C + j] + S[F_DIN * C + j]
            else:
                for j in range(m):
                    ia = pos - dsteps[b0 + j]
                    ia = ia + M if ia < 0 else ia
                    ib = ia - 1 if ia > 0 else M - 1
                    S[F_UA * C + j] = buf[_U(ia) * C + j] + S[F_DIN * C + j]
                    S[F_UB * C + j] = buf[_U(ib) * C + j] + S[F_DIN * C + j]
            # ---- plant update into the next-state rows
            if nonlinear:
                # RK4 with the input held over the sample (whole-sample delays)
                for j in range(m):
                    inp[n, j] = S[F_UA * C + j]
                    for i in range(un):
                        inp[i, j] = S[(xa + i) * C + j]
                _run_tape(f_op, f_a, f_b, f_o, f_c, inp, wf, k1, mt)
                for i in range(un):
                    for j in range(m):
                        inp[i, j] = S[(xa + i) * C + j] + 0.5 * dt * k1[i, j]
                _run_tape(f_op, f_a, f_b, f_o, f_c, inp, wf, k2, mt)
                for i in range(un):
                    for j in range(m):
                        inp[i, j] = S[(xa + i) * C + j] + 0.5 * dt * k2[i, j]
                _run_tape(f_op, f_a, f_b, f_o, f_c, inp, wf, k3, mt)
                for i in range(un):
                    for j in range(m):
                        inp[i, j] = S[(xa + i) * C + j] + dt * k3[i, j]
                _run_tape(f_op, f_a, f_b, f_o, f_c, inp, wf, k4, mt)
                for i in range(un):
                    xi = (xa + i) * C
                    for j in range(m):
                        S[(xb + i) * C + j] = S[xi + j] + dt / 6.0 * (k1[i, j] + 2.0 * k2[i, j] + 2.0 * k3[i, j] + k4[i, j])
            elif shared_plant:
                for i in range(un):
                    xn = (xb + i) * C
                    g0 = G0[i, b0]
                    g1 = G1[i, b0]
                    if has_G1:
                        for j in range(m):
                            S[xn + j] = g0 * S[F_UA * C + j] + g1 * S[F_UB * C + j]
                    else:
                        for j in range(m):
                            S[xn + j] = g0 * S[F_UA * C + j]
                    for q in range(un):
                        a = Ad[i, q, b0]
                        if a != 0.0:
                            xq = (xa + q) * C
                            for j in range(m):
                                S[xn + j] += a * S[xq + j]
            else:
                for i in range(un):
                    xn = (xb + i) * C
                    if has_G1:
                        for j in range(m):
                            S[xn + j] = G0[i, b0 + j] * S[F_UA * C + j] + G1[i, b0 + j] * S[F_UB * C + j]
                    else:
                        for j in range(m):
                            S[xn + j] = G0[i, b0 + j] * S[F_UA * C + j]
                    for q in range(un):
                        xq = (xa + q) * C
                        for j in range(m):
                            S[xn + j] += Ad[i, q, b0 + j] * S[xq + j]
            if not all_alive:  # dead candidates are frozen at 0
                for i in range(un):
                    xn = (xb + i) * C
                    for j in range(m):
                        S[xn + j] *= S[F_ALIVE * C + j]
            xa, xb = xb, xa
            if want_traces:
                for j in range(m):
                    b = b0 + j
                    tr_u[k, b] = S[F_U * C + j]
                    for l in range(uL):
                        p = (LP0 + l * N_P) * C + j
                        tr_y[l, k, b] = S[p + P_YT * C]
                        tr_sp[l, k, b] = S[p + P_SP * C]

        # finish metrics
        for j in range(m):
            b = b0 + j
            for q in range(_U(len(METRICS))):
                out[q, b] = S[(A0 + q) * C + j]
            span = target[b] - S[F_Y0 * C + j]
            out[M_SAT, b] = S[(A0 + M_SAT) * C + j] / n_steps
            out[M_YFIN, b] = S[(LP0 + P_YT) * C + j]  # the output at the last step
            out[M_SSE, b] = abs(target[b] - out[M_YFIN, b])
            if span != 0.0:
                out[M_OVERSHOOT, b] = _max(0.0, S[F_PEAK * C + j] - 1.0) * 100.0
                t10 = S[F_T10 * C + j]
                t90 = S[F_T90 * C + j]
                out[M_RISE, b] = (t90 - t10) if (t10 >= 0 and t90 >= 0) else np.nan
                last = S[F_LAST * C + j]
                if last < n_steps - 1:
                    out[M_SETTLE, b] = (last + 1) * dt - k_step[b] * dt if last >= 0 else 0.0
                else:
                    out[M_SETTLE, b] = np.nan
            else:
                out[M_OVERSHOOT, b] = 0.0
                out[M_RISE, b] = np.nan
                out[M_SETTLE, b] = np.nan
            if S[F_ALIVE * C + j] == 0.0:
                out[M_DIV, b] = 1.0
                for q in (M_IAE, M_ISE, M_ITAE, M_EFFORT, M_TV, M_LOAD, M_PEAKU, M_SSE):
                    out[q, b] = np.inf
                out[M_OVERSHOOT, b] = np.nan
                out[M_YFIN, b] = np.nan
            if S[F_TRIP * C + j] == 0.0:
                out[M_TRIPT, b] = np.nan
    return out


def _compile(parallel: bool, lanes: int = CHUNK, name: str = ""):
    """Compile a variant of :func:`_kernel` with ``lanes`` candidates per chunk.

    A distinct function object and qualname per variant keeps numba's on-disk
    caches apart; ``CHUNK`` is frozen into the variant as a compile-time constant.
    """
    glb = dict(_kernel.__globals__, CHUNK=lanes)
    fn = types.FunctionType(_kernel.__code__, glb, "_kernel")
    fn.__qualname__ = name
    return nb.njit(cache=True, parallel=parallel, error_model="numpy", fastmath={"contract"})(fn)


#: Parallel over chunks (large batches) and serial (small batches: no thread start-up cost).
simulate_kernel_parallel = _compile(True, name="simulate_kernel_parallel")
simulate_kernel_serial = _compile(False, name="simulate_kernel_serial")
#: One lane per chunk, a compile-time count: every per-lane loop collapses to
#: straight-line code (no loop set-up or overlap checks per stage). Same source,
#: so the same control law.
simulate_kernel_single = _compile(False, lanes=1, name="simulate_kernel_single")


def simulate_kernel(*args):
    """Run the kernel: the single-lane variant for one candidate, serially for one chunk, else in parallel."""
    B = args[24].shape[0]  # u_op
    if B == 1:
        return simulate_kernel_single(*args)
    fn = simulate_kernel_parallel if B > CHUNK else simulate_kernel_serial
    return fn(*args)
