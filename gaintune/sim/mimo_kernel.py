"""The compiled (numba) closed-loop kernel for plants with several inputs and loops wired as a graph.

One call simulates the chunks ``c_lo <= c < c_hi`` of a batch. A chunk is up to :data:`LANES`
candidates with the same plant (the caller groups candidates by plant: ``cand`` lists them chunk
by chunk, ``chunk_start`` where each chunk begins), so the plant's coefficients are scalars in the
time loop and every per-step operation is a loop over the chunk's lanes (contiguous, which LLVM
vectorises), as in the single-input kernel (:mod:`gaintune.sim.kernel`). Per step ``k``:

1. the outputs ``y = C x[k]`` (a strictly proper plant: no feedthrough);
2. divergence every 8 steps (NaN, inf or beyond ``div_bound``: the lane is dead, its state held at
   0, its metrics inf) and the safety monitor (a trip holds every actuator at its safe value);
3. the loops in graph order (a loop's setpoint is a reference, or the output of the loop that
   drives it), each with the discrete PID law of :mod:`gaintune.controllers.pid`; the feedforward
   ``F r`` is computed first, so a clamping loop that drives an input directly holds its integrator
   when that input saturates on its output plus the feedforward, as when its own limits saturate;
4. the actuators: ``W v + F r`` (the loops' outputs, through the static decoupler when there is one,
   plus the reference feedforward), saturation, rate limit; each into its input's delay line.
   ``W`` is (1, m, L) for the whole batch or (B, m, L), one per candidate (tuned decoupler entries);
   ``F`` likewise, or (0, m, L) without feedforward (:mod:`gaintune.sim.mimo_blocks`);
5. the metrics;
6. the exact ZOH update ``x[k+1] = Ad x[k] + sum_c (G0_c u_c[k-d_c] + G1_c u_c[k-d_c-1])`` over
   the plant's channels c (one per transfer-function entry, or per input of a state-space
   plant), each with its own fractional delay; an input disturbance passes the same channels
   with a transfer-function entry's delay (not the actuator's; a state-space plant's input delay
   neither, as in the single-input simulator).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from gaintune.sim.mimo_ode_kernel import ode_outputs, ode_rk4

__all__ = ["MIMO_METRICS", "LANES", "mimo_kernel"]

#: Candidates per chunk.
LANES = 32

#: Aggregate metric rows of the kernel's ``out``: the single-input kernel's names and meanings, the
#: integrals summed over every chain's outer error, effort and total variation over every actuator.
MIMO_METRICS = (
    "iae", "ise", "itae", "effort", "tv", "overshoot", "rise_time", "settling_time",
    "sse", "sat_frac", "peak_u", "load_iae", "diverged", "tripped", "trip_time", "y_final",
)
_IAE, _ISE, _ITAE, _EFF, _TV, _OS, _RISE, _SETTLE, _SSE, _SAT, _PEAKU, _LOAD, _DIV, _TRIP, _TRIPT, _YFIN = range(16)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def mimo_kernel(c_lo, c_hi, cand, chunk_start, n_steps, dt, pidx, Ad, bstart, bsize, Cm,
                ch_blk, ch_src, ch_du, ch_G0u, ch_G1u, ch_dd, ch_G0d, ch_G1d, dist_on,
                meas, parent, root_row, kp, ki, kd, tf, kb, bw, cw, lo, hi, aw, W, F, direct,
                u_lo, u_hi, rate, u_safe, ref, dist, roots, step_root, target, k_step, k_load,
                max_err, max_out, xbound, div_bound, safe_hold,
                out, chain_out, eff_out, want_traces, tr_y, tr_sp, tr_u,
                nonlin, f_op, f_a, f_b, f_o, f_c, nwf, h_op, h_a, h_b, h_o, h_c, nwh, Pq, x_op, u_op, y_op, ud,
                dstate):
    """Simulate chunks ``c_lo .. c_hi - 1``; metrics into ``out`` (16, B), ``chain_out`` (R, 3, B) and
    ``eff_out`` (m, B), traces into ``tr_*`` when ``want_traces``. Loops are indexed in graph order.

    ``dist`` and ``dist_on`` have a row per input and one more, the state disturbance: a channel of
    its own for a linear plant, added to the derivative of state ``dstate`` for a nonlinear one
    (``nonlin``: the ODE tapes ``f_*``, ``h_*`` with ``Pq``, ``x_op``, ``u_op``, ``y_op`` per plant
    row and ``ud`` whole-sample actuator delays; see :mod:`gaintune.sim.mimo_ode_kernel`)."""
    N = Ad.shape[1]
    p = Cm.shape[1]
    L = meas.shape[0]
    m = W.shape[1]
    n_ff = F.shape[0]
    nc = ch_blk.shape[0]
    nr = roots.shape[0]
    M = 2
    for q in range(ch_du.shape[0]):
        for c in range(nc):
            M = max(M, ch_du[q, c] + 2)
    for a in range(ud.shape[0]):
        M = max(M, ud[a] + 2)
    n_ode = x_op.shape[1] if nonlin else 0
    n_par = Pq.shape[1]
    monitor = max_err < np.inf or max_out < np.inf
    for i in range(N):
        monitor = monitor or xbound[i] < np.inf
    C = LANES
    for ck in range(c_lo, c_hi):
        b0 = chunk_start[ck]
        nl = chunk_start[ck + 1] - b0
        q = pidx[cand[b0]]
        x = np.zeros((N, C))
        xn = np.zeros((N, C))
        y = np.zeros((p, C))
        hist = np.zeros((m + 1, M, C))  # row m: the state-disturbance channel's (always 0) input
        g = np.zeros((9, L, C))  # per loop: kp, ki*dt, kb*dt, alpha, beta, lo, hi, and the state below
        integ = np.zeros((L, C))
        dterm = np.zeros((L, C))
        edp = np.zeros((L, C))
        awe = np.zeros((L, C))
        vout = np.zeros((L, C))
        sp = np.zeros((L, C))
        u = np.zeros((m, C))
        uprev = np.zeros((m, C))
        acc = np.zeros((16, C))
        chain = np.zeros((nr, 3, C))
        eff = np.zeros((m, C))
        alive = np.ones(C)
        trip = np.zeros(C)
        mark = np.zeros((5, C))  # y0, invspan, t10, t90, last
        u_held = np.zeros((m, C))  # nonlinear: the absolute inputs held over the last sample
        inp = np.zeros((n_ode + m + n_par, C))
        wf = np.zeros((nwf, C))
        wh = np.zeros((nwh, C))
        hout = np.zeros((p, C))
        kk = np.zeros((4, n_ode, C))
        Wc = np.zeros((m, L, C))  # this chunk's W (and F), lane by lane
        Fc = np.zeros((m, L, C if n_ff > 0 else 0))
        ffu = np.zeros((m, C))  # the feedforward part of each input (the anti-windup leaves it out)
        for j in range(nl):
            b = cand[b0 + j]
            wb = b if W.shape[0] > 1 else 0
            fb = b if n_ff > 1 else 0
            for a in range(m):
                for l in range(L):
                    Wc[a, l, j] = W[wb, a, l]
                    if n_ff > 0:
                        Fc[a, l, j] = F[fb, a, l]
        if nonlin:
            for j in range(nl):
                for i in range(n_ode):
                    x[i, j] = x_op[q, i]
                for a in range(m):
                    u_held[a, j] = u_op[q, a]
                for r in range(n_par):
                    inp[n_ode + m + r, j] = Pq[q, r]
        for j in range(nl):
            b = cand[b0 + j]
            for l in range(L):
                g[0, l, j] = kp[l, b]
                g[1, l, j] = ki[l, b] * dt
                g[2, l, j] = kb[l, b] * dt
                g[3, l, j] = tf[l, b] / (tf[l, b] + dt)
                g[4, l, j] = kd[l, b] / (tf[l, b] + dt)
                g[5, l, j] = lo[l, b]
                g[6, l, j] = hi[l, b]
                g[7, l, j] = ki[l, b]
            mark[2, j] = -1.0
            mark[3, j] = -1.0
            mark[4, j] = -1.0
        kst = k_step if target != 0.0 else n_steps + 1
        pos = M - 1
        for k in range(n_steps):
            t = k * dt
            pos = pos + 1 if pos + 1 < M else 0
            if nonlin:
                ode_outputs(x, u_held, inp, n_ode, m, nl, h_op, h_a, h_b, h_o, h_c, wh, hout, y_op[q], y)
            for o in range(p if not nonlin else 0):
                for j in range(nl):
                    y[o, j] = 0.0
                for i in range(N):
                    cv = Cm[q, o, i]
                    if cv != 0.0:
                        for j in range(nl):
                            y[o, j] += cv * x[i, j]
            if (k & 7) == 0 or k == n_steps - 1:
                for i in range(N):
                    for j in range(nl):
                        alive[j] = alive[j] if abs(x[i, j]) <= div_bound else 0.0
                for o in range(p):
                    for j in range(nl):
                        alive[j] = alive[j] if abs(y[o, j]) <= div_bound else 0.0
            if monitor:
                for j in range(nl):
                    hit = False
                    for r in range(nr):
                        lr = roots[r]
                        hit = hit or abs(ref[root_row[lr], k] - y[meas[lr], j]) > max_err
                    for l in range(L):
                        hit = hit or abs(y[meas[l], j]) > max_out
                    for i in range(N):
                        hit = hit or abs(x[i, j]) > xbound[i]
                    if hit and trip[j] == 0.0 and alive[j] > 0.0:
                        trip[j] = 1.0
                        acc[_TRIP, j] = 1.0
                        acc[_TRIPT, j] = t
            # ---- the feedforward of this step, known before the loops (the roots' setpoints are references)
            for a in range(m if n_ff > 0 else 0):
                for j in range(nl):
                    ffu[a, j] = 0.0
                for r in range(nr):
                    lr = roots[r]
                    rv = ref[root_row[lr], k]
                    for j in range(nl):
                        ffu[a, j] += Fc[a, lr, j] * rv
            # ---- loops in graph order (the discrete law of gaintune.controllers.pid)
            for l in range(L):
                pl = parent[l]
                if pl < 0:
                    rv = ref[root_row[l], k]
                    for j in range(nl):
                        sp[l, j] = rv
                else:
                    for j in range(nl):
                        sp[l, j] = vout[pl, j]
                ml = meas[l]
                bwl, cwl = bw[l], cw[l]
                if k == 0:
                    for j in range(nl):
                        edp[l, j] = cwl * sp[l, j] - y[ml, j]  # no derivative kick at the start
                clamp, backcalc = aw[l] == 1, aw[l] == 2
                # a clamping loop that drives an input directly also judges that input's saturation of v + ff
                da = direct[l]
                clamp_ff = clamp and n_ff > 0 and da >= 0
                alo, ahi = (u_lo[da], u_hi[da]) if clamp_ff else (-np.inf, np.inf)
                for j in range(nl):
                    s_l = sp[l, j]
                    ym = y[ml, j]
                    e = s_l - ym
                    ed = cwl * s_l - ym
                    dv = g[3, l, j] * dterm[l, j] + g[4, l, j] * (ed - edp[l, j])
                    edp[l, j] = ed
                    dterm[l, j] = dv
                    pterm = g[0, l, j] * (bwl * s_l - ym)
                    iold = integ[l, j]
                    it = iold + g[1, l, j] * e
                    if backcalc:
                        it += g[2, l, j] * awe[l, j]
                    vu = pterm + it + dv
                    vs = min(max(vu, g[5, l, j]), g[6, l, j])
                    if clamp and vs != vu and e * (vu - vs) * g[7, l, j] > 0:
                        it = iold
                        vu = pterm + it + dv
                        vs = min(max(vu, g[5, l, j]), g[6, l, j])
                    if clamp_ff:
                        tot = vs + ffu[da, j]
                        ts = min(max(tot, alo), ahi)
                        if ts != tot and e * (tot - ts) * g[7, l, j] > 0:
                            it = iold
                            vu = pterm + it + dv
                            vs = min(max(vu, g[5, l, j]), g[6, l, j])
                    integ[l, j] = it
                    awe[l, j] = vs - vu
                    vout[l, j] = vs
            # ---- actuators
            for a in range(m):
                ulo, uhi, ra = u_lo[a], u_hi[a], rate[a] * dt
                for j in range(nl):
                    v = 0.0
                    for l in range(L):
                        v += Wc[a, l, j] * vout[l, j]
                    if n_ff > 0:
                        v += ffu[a, j]
                    v = min(max(v, ulo), uhi)
                    if ra < np.inf:
                        v = min(max(v, uprev[a, j] - ra), uprev[a, j] + ra)
                    if safe_hold and trip[j] > 0.0:
                        v = u_safe[a]
                    v = v if alive[j] > 0.0 else 0.0
                    u[a, j] = v
                    hist[a, pos, j] = v
            for l in range(L):
                if aw[l] == 2 and direct[l] >= 0:
                    for j in range(nl):
                        if n_ff > 0:
                            awe[l, j] += u[direct[l], j] - ffu[direct[l], j] - vout[l, j]  # what was applied
                        else:
                            awe[l, j] += u[direct[l], j] - vout[l, j]  # track what was applied
            # ---- metrics
            for r in range(nr):
                lr = roots[r]
                ml = meas[lr]
                for j in range(nl):
                    e = sp[lr, j] - y[ml, j]
                    chain[r, 0, j] += abs(e) * dt
                    chain[r, 1, j] += e * e * dt
                    chain[r, 2, j] += t * abs(e) * dt
                    if k >= k_load:
                        acc[_LOAD, j] += abs(e) * dt
            for j in range(nl):
                sat = 0.0
                for a in range(m):
                    ua = u[a, j]
                    eff[a, j] += ua * ua * dt
                    acc[_TV, j] += abs(ua - uprev[a, j])
                    acc[_PEAKU, j] = max(acc[_PEAKU, j], abs(ua))
                    sat = 1.0 if (ua <= u_lo[a] or ua >= u_hi[a]) else sat
                    uprev[a, j] = ua
                acc[_SAT, j] += sat * alive[j]
            ms = meas[step_root]
            if k == 0:
                for j in range(nl):
                    mark[0, j] = y[ms, j]
                    span = target - y[ms, j]
                    mark[1, j] = 1.0 / span if span != 0.0 else 0.0
            if k >= kst:
                for j in range(nl):
                    if alive[j] > 0.0:
                        dev = (y[ms, j] - mark[0, j]) * mark[1, j]
                        acc[_OS, j] = max(acc[_OS, j], dev)  # the peak, turned into overshoot at the end
                        if mark[2, j] < 0 and dev >= 0.1:
                            mark[2, j] = t
                        if mark[3, j] < 0 and dev >= 0.9:
                            mark[3, j] = t
                        if abs(dev - 1.0) >= 0.02:
                            mark[4, j] = k
            if want_traces:
                for j in range(nl):
                    b = cand[b0 + j]
                    for l in range(L):
                        tr_y[l, k, b] = y[meas[l], j]
                        tr_sp[l, k, b] = sp[l, j]
                    for a in range(m):
                        tr_u[a, k, b] = u[a, j]
            # ---- plant update: exact ZOH per channel, fractional delays
            for blk in range(bstart.shape[0]):
                s0 = bstart[blk]
                s1 = s0 + bsize[blk]
                for i in range(s0, s1):
                    for j in range(nl):
                        xn[i, j] = 0.0
                    for c2 in range(s0, s1):
                        av = Ad[q, i, c2]
                        if av != 0.0:
                            for j in range(nl):
                                xn[i, j] += av * x[c2, j]
            for c in range(nc):
                a = ch_src[c]
                ia = pos - ch_du[q, c]
                ia = ia + M if ia < 0 else ia
                ib = ia - 1 if ia > 0 else M - 1
                s0 = bstart[ch_blk[c]]
                for i in range(s0, s0 + bsize[ch_blk[c]]):
                    g0, g1 = ch_G0u[q, c, i], ch_G1u[q, c, i]
                    for j in range(nl):
                        xn[i, j] += g0 * hist[a, ia, j] + g1 * hist[a, ib, j]
                if dist_on[a]:
                    ka = k - ch_dd[q, c]
                    da = dist[a, ka] if ka >= 0 else 0.0
                    db = dist[a, ka - 1] if ka >= 1 else 0.0
                    for i in range(s0, s0 + bsize[ch_blk[c]]):
                        dv = ch_G0d[q, c, i] * da + ch_G1d[q, c, i] * db
                        for j in range(nl):
                            xn[i, j] += dv
            if nonlin:
                _ode_update(k, pos, M, m, nl, dt, x, xn, u_held, inp, hist, ud, u_op[q], dist, dist_on, dstate,
                            f_op, f_a, f_b, f_o, f_c, wf, kk, n_ode)
            for i in range(N):
                for j in range(nl):
                    xn[i, j] *= alive[j]  # dead lanes held at rest
            x, xn = xn, x
        _finish(nl, b0, cand, n_steps, dt, kst, target, alive, trip, acc, chain, eff, mark, y, meas, step_root,
                out, chain_out, eff_out)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _ode_update(k, pos, M, m, nl, dt, x, xn, ua, inp, hist, ud, u_op_q, dist, dist_on, dstate,
                f_op, f_a, f_b, f_o, f_c, wf, kk, n_ode):
    """Nonlinear plant: the held inputs (operating point + delayed actuator + input disturbance), then RK4."""
    for a in range(m):
        ia = pos - ud[a]
        ia = ia + M if ia < 0 else ia
        da = dist[a, k] if dist_on[a] else 0.0
        for j in range(nl):
            ua[a, j] = u_op_q[a] + hist[a, ia, j] + da
    dv = dist[m, k] if dist_on[m] else 0.0
    ode_rk4(x, xn, ua, inp, n_ode, m, nl, dt, f_op, f_a, f_b, f_o, f_c, wf, kk[0], kk[1], kk[2], kk[3], dstate, dv)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _finish(nl, b0, cand, n_steps, dt, kst, target, alive, trip, acc, chain, eff, mark, y, meas, step_root,
            out, chain_out, eff_out):
    """The chunk's metric rows into ``out``, ``chain_out`` and ``eff_out`` (dead lanes: inf)."""
    for j in range(nl):
        b = cand[b0 + j]
        dead = alive[j] == 0.0
        for r in range(chain.shape[0]):
            for z in range(3):
                chain_out[r, z, b] = np.inf if dead else chain[r, z, j]
                acc[z, j] += chain[r, z, j]
        for a in range(eff.shape[0]):
            eff_out[a, b] = np.inf if dead else eff[a, j]
            acc[_EFF, j] += eff[a, j]
        for z in range(16):
            out[z, b] = acc[z, j]
        out[_SAT, b] = acc[_SAT, j] / n_steps
        out[_YFIN, b] = y[meas[step_root], j]
        out[_SSE, b] = abs(target - out[_YFIN, b])
        if mark[1, j] != 0.0:
            out[_OS, b] = max(0.0, acc[_OS, j] - 1.0) * 100.0
            t10, t90, last = mark[2, j], mark[3, j], mark[4, j]
            out[_RISE, b] = (t90 - t10) if (t10 >= 0 and t90 >= 0) else np.nan
            if last < n_steps - 1:
                out[_SETTLE, b] = (last + 1) * dt - kst * dt if last >= 0 else 0.0
            else:
                out[_SETTLE, b] = np.nan
        else:
            out[_OS, b] = 0.0
            out[_RISE, b] = np.nan
            out[_SETTLE, b] = np.nan
        if dead:
            out[_DIV, b] = 1.0
            for z in (_IAE, _ISE, _ITAE, _EFF, _TV, _LOAD, _PEAKU, _SSE):
                out[z, b] = np.inf
            out[_OS, b] = np.nan
            out[_YFIN, b] = np.nan
        if trip[j] == 0.0:
            out[_TRIPT, b] = np.nan
