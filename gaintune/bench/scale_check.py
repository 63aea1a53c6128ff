"""Closed-loop stability of a loop graph's gains, for ``gaintune bench scaling`` where the verdict cannot be computed.

The spec's loops (cascades of parallel P/PI/PD/PID loops side by side, each chain ending at a plant
input) become one controller matrix K (plant inputs x measured outputs) in the convention of
:mod:`gaintune.verification.mimo_loop`, ``u = K (r - y)``: a chain
``u = C_n(... C_2(C_1 (r - y_1) - y_2) ... - y_n)`` puts ``C_n ... C_k`` at (its input, y_k).
:func:`gaintune.verification.mimo_stability.mimo_stability` then decides stability (Padé eigenvalues,
cross-checked by a generalised Nyquist count on the exact delays). Continuous time and linear:
saturations and the sample-and-hold are not in it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["cascade_controller", "closed_loop_stable"]


def _pid(loop: Any, g: dict[str, float]) -> Any:
    from gaintune.verification.mimo_loop import pid_entry

    if loop.form != "parallel" or loop.is_lq:
        raise ValueError(f"loop {loop.name}: only parallel P/PI/PD/PID loops are checked")
    kp, ki, kd = g.get("Kp", 0.0), g.get("Ki", 0.0), g.get("Kd", 0.0)
    tf = 0.0
    if kd:
        tf = loop.filter.Tf if loop.filter.Tf is not None else kd / (kp * (loop.filter.N or 10.0))
    return pid_entry(kp, ki, kd, tf)


def _chain(spec: Any, outer: int) -> list[int]:
    """Loop indices of the chain that starts at loop ``outer``, outer first, ending at a plant input."""
    from gaintune.spec.mimo import drive_target

    names, out, k = spec.loop_names, [outer], outer
    while True:
        kind, target = drive_target(spec.loops[k].drives)
        if kind == "input":
            return out
        k = names.index(target)
        out.append(k)


def cascade_controller(spec: Any, gains: dict[str, dict[str, float]], plant: Any) -> tuple[Any, list]:
    """K (a :class:`~gaintune.lti.mimo.DelayedSS`, measured outputs in, plant inputs out) and the pairing.

    Built in state space, one realisation per loop (a product of transfer functions per entry would
    repeat the inner loops' integrators as unobservable modes at s = 0). Loop k's error is
    ``e_k = out_(k-1) + v_k`` with ``v = r - y``: its setpoint is the outer loop's output.
    """
    from gaintune.lti.mimo import DelayedSS
    from gaintune.spec.mimo import chain_input
    from gaintune.verification.mimo_loop import LoopPair

    names, ins, outs = spec.loop_names, list(plant.input_names), list(plant.outputs)
    fed = {spec.loop_names.index(d.split(":", 1)[1]) for d in (lp.drives or "" for lp in spec.loops)
           if d.startswith("loop:")}
    blocks = [_pid(lp, gains[names[i]]).realisation() for i, lp in enumerate(spec.loops)]
    sizes = [b[0].shape[0] for b in blocks]
    start = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    n, nl = int(start[-1]), len(spec.loops)
    A, B = np.zeros((n, n)), np.zeros((n, len(outs)))  # K takes every plant output (unmeasured: zero columns)
    C, D = np.zeros((len(ins), n)), np.zeros((len(ins), len(outs)))
    for outer in (i for i in range(nl) if i not in fed):
        cx, dv = np.zeros(n), np.zeros(len(outs))  # the setpoint of the next loop, affine in (x, v)
        for k in _chain(spec, outer):
            Ak, Bk, Ck, Dk = blocks[k]
            ex, ev = cx.copy(), dv.copy()
            ev[outs.index(spec.loops[k].measure)] += 1.0
            s0, s1 = start[k], start[k + 1]
            A[s0:s1, s0:s1] += Ak
            A[s0:s1] += Bk[:, :1] @ ex[None]
            B[s0:s1] += Bk[:, :1] @ ev[None]
            cx, dv = Dk[0, 0] * ex, Dk[0, 0] * ev
            cx[s0:s1] += Ck[0]
        j = ins.index(chain_input(spec, outer))
        C[j], D[j] = cx, dv
    pairing = [LoopPair(names[i], str(lp.measure), str(chain_input(spec, i))) for i, lp in enumerate(spec.loops)]
    return DelayedSS(A, B, C, D, tuple(outs), tuple(ins)), pairing


def closed_loop_stable(spec: Any, gains: dict[str, dict[str, float]]) -> tuple[bool | None, str]:
    """(stable, how it was decided) for ``gains`` on ``spec``'s nominal plant; (None, why) when not checked."""
    from gaintune.plants import build_plant
    from gaintune.plants.mimo import as_mimo
    from gaintune.verification.mimo_loop import MimoLoop
    from gaintune.verification.mimo_stability import mimo_stability

    if all(lp.drives is None for lp in spec.loops):
        return None, "a single-input cascade: its verdict is the full verification's"
    try:
        mp = as_mimo(build_plant(spec.plant))
        K, pairing = cascade_controller(spec, gains, mp)
        st = mimo_stability(MimoLoop.build(mp.lti(), K, pairing))
    except (ValueError, np.linalg.LinAlgError) as exc:
        return None, f"not checked: {exc}"
    return bool(st.stable), f"{st.method}, max Re(pole) {st.max_real_pole:.3g}, {st.rhp_poles} RHP poles"
