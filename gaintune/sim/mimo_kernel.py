"""The compiled (numba) closed-loop kernel for plants with several inputs and loops wired as a graph.

One call simulates candidates ``b_lo <= b < b_hi`` of a batch (the batch on the LAST axis of
every per-candidate array), one candidate after the other. Per step ``k``, as the single-input
kernel (:mod:`gaintune.sim.kernel`) does:

1. the outputs ``y = C x[k]`` (a strictly proper plant: no feedthrough);
2. divergence (NaN, inf or beyond ``div_bound``: the candidate is dead, its metrics inf) and the
   safety monitor (a trip holds every actuator at its safe value);
3. the loops in graph order (a loop's setpoint is a reference, or the output of the loop that
   drives it), each with the discrete PID law of :mod:`gaintune.controllers.pid`;
4. the actuators: ``W v`` (the loops' outputs, through the static decoupler when there is one),
   saturation, rate limit; each into its input's delay line;
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

__all__ = ["MIMO_METRICS", "mimo_kernel"]

#: Aggregate metric rows of the kernel's ``out``: the single-input kernel's names and meanings, the
#: integrals summed over every chain's outer error, effort and total variation over every actuator.
MIMO_METRICS = (
    "iae", "ise", "itae", "effort", "tv", "overshoot", "rise_time", "settling_time",
    "sse", "sat_frac", "peak_u", "load_iae", "diverged", "tripped", "trip_time", "y_final",
)
_IAE, _ISE, _ITAE, _EFF, _TV, _OS, _RISE, _SETTLE, _SSE, _SAT, _PEAKU, _LOAD, _DIV, _TRIP, _TRIPT, _YFIN = range(16)


@nb.njit(cache=True, nogil=True, error_model="numpy")
def mimo_kernel(b_lo, b_hi, n_steps, dt, pidx, Ad, bstart, bsize, Cm,
                ch_blk, ch_src, ch_du, ch_G0u, ch_G1u, ch_dd, ch_G0d, ch_G1d, dist_on,
                meas, parent, root_row, kp, ki, kd, tf, kb, bw, cw, lo, hi, aw, W, direct,
                u_lo, u_hi, rate, u_safe, ref, dist, roots, step_root, target, k_step, k_load,
                max_err, max_out, xbound, div_bound, safe_hold,
                out, chain_out, eff_out, want_traces, tr_y, tr_sp, tr_u):
    """Simulate candidates ``b_lo .. b_hi - 1``; metrics into ``out`` (16, B), ``chain_out`` (R, 3, B) and
    ``eff_out`` (m, B), traces into ``tr_*`` when ``want_traces``. Loops are indexed in graph order."""
    N = Ad.shape[1]
    p = Cm.shape[1]
    L = meas.shape[0]
    m = W.shape[0]
    nc = ch_blk.shape[0]
    nr = roots.shape[0]
    M = 2
    for q in range(ch_du.shape[0]):
        for c in range(nc):
            M = max(M, ch_du[q, c] + 2)
    monitor = max_err < np.inf or max_out < np.inf
    for i in range(N):
        monitor = monitor or xbound[i] < np.inf
    for b in range(b_lo, b_hi):
        q = pidx[b]
        x = np.zeros(N)
        xn = np.zeros(N)
        y = np.zeros(p)
        hist = np.zeros((m, M))
        integ = np.zeros(L)
        dterm = np.zeros(L)
        edp = np.zeros(L)
        awe = np.zeros(L)
        vout = np.zeros(L)
        sp = np.zeros(L)
        u = np.zeros(m)
        uprev = np.zeros(m)
        acc = np.zeros(16)
        chain = np.zeros((nr, 3))
        eff = np.zeros(m)
        alive = True
        tripped = False
        y0 = peak = 0.0
        invspan = 0.0
        t10 = t90 = last = -1.0
        pos = M - 1
        kst = k_step if target != 0.0 else n_steps + 1
        for k in range(n_steps):
            t = k * dt
            pos = pos + 1 if pos + 1 < M else 0
            for o in range(p):
                s = 0.0
                for i in range(N):
                    s += Cm[q, o, i] * x[i]
                y[o] = s
            for i in range(N):
                alive = alive and abs(x[i]) <= div_bound
            for o in range(p):
                alive = alive and abs(y[o]) <= div_bound
            if not alive:
                break
            if monitor and not tripped:
                trip = False
                for r in range(nr):
                    lr = roots[r]
                    trip = trip or abs(ref[root_row[lr], k] - y[meas[lr]]) > max_err
                for l in range(L):
                    trip = trip or abs(y[meas[l]]) > max_out
                for i in range(N):
                    trip = trip or abs(x[i]) > xbound[i]
                if trip:
                    tripped = True
                    acc[_TRIP] = 1.0
                    acc[_TRIPT] = t
            # ---- loops in graph order (the discrete law of gaintune.controllers.pid)
            for l in range(L):
                s_l = ref[root_row[l], k] if parent[l] < 0 else vout[parent[l]]
                sp[l] = s_l
                ym = y[meas[l]]
                e = s_l - ym
                ed = cw[l] * s_l - ym
                if k == 0:
                    edp[l] = ed  # no derivative kick at the start
                al = tf[l, b] / (tf[l, b] + dt)
                be = kd[l, b] / (tf[l, b] + dt)
                dv = al * dterm[l] + be * (ed - edp[l])
                edp[l] = ed
                dterm[l] = dv
                pterm = kp[l, b] * (bw[l] * s_l - ym)
                iold = integ[l]
                it = iold + ki[l, b] * dt * e
                if aw[l] == 2:
                    it += kb[l, b] * dt * awe[l]
                vu = pterm + it + dv
                vs = min(max(vu, lo[l, b]), hi[l, b])
                if aw[l] == 1 and vs != vu and e * (vu - vs) * ki[l, b] > 0:
                    it = iold
                    vu = pterm + it + dv
                    vs = min(max(vu, lo[l, b]), hi[l, b])
                integ[l] = it
                awe[l] = vs - vu
                vout[l] = vs
            # ---- actuators
            for j in range(m):
                v = 0.0
                for l in range(L):
                    v += W[j, l] * vout[l]
                v = min(max(v, u_lo[j]), u_hi[j])
                if rate[j] < np.inf:
                    v = min(max(v, uprev[j] - rate[j] * dt), uprev[j] + rate[j] * dt)
                if tripped and safe_hold:
                    v = u_safe[j]
                u[j] = v
                hist[j, pos] = v
            for l in range(L):
                if aw[l] == 2 and direct[l] >= 0:
                    awe[l] += u[direct[l]] - vout[l]  # track what was applied
            # ---- metrics
            for r in range(nr):
                lr = roots[r]
                e = sp[lr] - y[meas[lr]]
                chain[r, 0] += abs(e) * dt
                chain[r, 1] += e * e * dt
                chain[r, 2] += t * abs(e) * dt
                if k >= k_load:
                    acc[_LOAD] += abs(e) * dt
            sat = False
            for j in range(m):
                eff[j] += u[j] * u[j] * dt
                acc[_TV] += abs(u[j] - uprev[j])
                acc[_PEAKU] = max(acc[_PEAKU], abs(u[j]))
                sat = sat or u[j] <= u_lo[j] or u[j] >= u_hi[j]
                uprev[j] = u[j]
            acc[_SAT] += 1.0 if sat else 0.0
            ys = y[meas[step_root]]
            if k == 0:
                y0 = ys
                span = target - y0
                invspan = 1.0 / span if span != 0.0 else 0.0
            if k >= kst:
                dev = (ys - y0) * invspan
                peak = max(peak, dev)
                if t10 < 0 and dev >= 0.1:
                    t10 = t
                if t90 < 0 and dev >= 0.9:
                    t90 = t
                if abs(dev - 1.0) >= 0.02:
                    last = k
            if want_traces:
                for l in range(L):
                    tr_y[l, k, b] = y[meas[l]]
                    tr_sp[l, k, b] = sp[l]
                for j in range(m):
                    tr_u[j, k, b] = u[j]
            # ---- plant update: exact ZOH per channel, fractional delays
            for blk in range(bstart.shape[0]):
                s0 = bstart[blk]
                for i in range(s0, s0 + bsize[blk]):
                    s = 0.0
                    for c2 in range(s0, s0 + bsize[blk]):
                        s += Ad[q, i, c2] * x[c2]
                    xn[i] = s
            for c in range(nc):
                j = ch_src[c]
                ia = pos - ch_du[q, c]
                ia = ia + M if ia < 0 else ia
                ib = ia - 1 if ia > 0 else M - 1
                ua = hist[j, ia]
                ub = hist[j, ib]
                s0 = bstart[ch_blk[c]]
                for i in range(s0, s0 + bsize[ch_blk[c]]):
                    xn[i] += ch_G0u[q, c, i] * ua + ch_G1u[q, c, i] * ub
                if dist_on[j]:
                    ka = k - ch_dd[q, c]
                    da = dist[j, ka] if ka >= 0 else 0.0
                    db = dist[j, ka - 1] if ka >= 1 else 0.0
                    for i in range(s0, s0 + bsize[ch_blk[c]]):
                        xn[i] += ch_G0d[q, c, i] * da + ch_G1d[q, c, i] * db
            x, xn = xn, x
        # ---- finish
        for r in range(nr):
            for z in range(3):
                chain_out[r, z, b] = chain[r, z] if alive else np.inf
                acc[z] += chain[r, z]
        for j in range(m):
            eff_out[j, b] = eff[j] if alive else np.inf
            acc[_EFF] += eff[j]
        for z in range(16):
            out[z, b] = acc[z]
        out[_SAT, b] = acc[_SAT] / n_steps
        out[_YFIN, b] = y[meas[step_root]]
        out[_SSE, b] = abs(target - out[_YFIN, b])
        if invspan != 0.0:
            out[_OS, b] = max(0.0, peak - 1.0) * 100.0
            out[_RISE, b] = (t90 - t10) if (t10 >= 0 and t90 >= 0) else np.nan
            if last < n_steps - 1:
                out[_SETTLE, b] = (last + 1) * dt - kst * dt if last >= 0 else 0.0
            else:
                out[_SETTLE, b] = np.nan
        else:
            out[_OS, b] = 0.0
            out[_RISE, b] = np.nan
            out[_SETTLE, b] = np.nan
        if not alive:
            out[_DIV, b] = 1.0
            for z in (_IAE, _ISE, _ITAE, _EFF, _TV, _LOAD, _PEAKU, _SSE):
                out[z, b] = np.inf
            out[_OS, b] = np.nan
            out[_YFIN, b] = np.nan
        if not tripped:
            out[_TRIPT, b] = np.nan
