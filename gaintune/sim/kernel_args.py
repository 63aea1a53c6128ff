"""The kernel's argument record: every array and flag of one batched rollout, by name.

:class:`KernelArgs` is what :meth:`gaintune.sim.Simulator.kernel_args` builds and
:func:`gaintune.sim.kernel.run_kernel` runs. Its fields are the compiled kernel's
parameters, in order (checked when the kernel is imported), so the record splats
straight into the kernel: ``simulate_kernel(*args)``. Arrays carry the batch of
B candidates on their LAST axis; L is the number of loops (outer first), n the
plant order, T = ``n_steps``.

This module imports no numba: building or inspecting a record does not load the compiler.

Example
-------
>>> from gaintune.spec import load_spec
>>> from gaintune.sim import Simulator
>>> from gaintune.sim.kernel import run_kernel
>>> spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}]})
>>> sim = Simulator(spec)
>>> args = sim.kernel_args(sim.layout.full([[1.14, 0.454]]))
>>> args.batch, args.kp.shape
(1, (1, 1))
>>> bool(run_kernel(args)[0, 0] == sim.run(sim.layout.full([[1.14, 0.454]])).metrics["iae"][0])
True
"""

from __future__ import annotations

import operator
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

__all__ = ["KernelArgs"]


class KernelArgs(NamedTuple):
    """Arguments of one kernel call (B candidates, one scenario), in the kernel's parameter order.

    Attributes
    ----------
    n_steps, dt, nonlinear
        Time steps T, sample time (s), and whether the plant is a casadi tape (RK4) rather than LTI.
    Ad, G0, G1, Cm, Dm
        LTI plant, exact ZOH with a fractional input delay: ``x[k+1] = Ad x + G0 u[k-d] + G1 u[k-d-1]``,
        measured outputs ``Cm x + Dm u[k-d]``. Shapes (n, n, B), (n, B), (n, B), (L, n, B), (L, B);
        unused zeros of shape (1, 1, 1) / (1, 1) for a nonlinear plant.
    f_op, f_a, f_b, f_o, f_c, f_nw
        Instruction tape of the nonlinear dynamics ``dx/dt = f(x, u, p)`` (see :mod:`gaintune.sim.tape`):
        op codes, operand and output slots (int64), constants, work rows.
    h_op, h_a, h_b, h_o, h_c, h_nw, h_nout
        Tape of the nonlinear output map ``y = h(x, u, p)``, and its number of outputs.
    P
        (n_params, B) plant parameters of each candidate (nonlinear plants; (0, B) otherwise).
    meas_idx
        (L,) int64: the plant output each loop measures.
    x_op, u_op, y_op
        Operating point: (n, B) state, (B,) input, (L, B) measured outputs. ``u_op`` sets the batch size.
    dsteps
        (B,) int64 whole-sample input delay d.
    kp, ki, kd, tf, bw, cw, kb, lo, hi
        (L, B) PID rows per loop: gains, derivative filter time constant, 2-DOF weights b and c,
        back-calculation gain 1/Tt, output limits (the innermost loop's come from ``u_lo``/``u_hi``).
    aw
        (L,) int64 anti-windup codes (0 none, 1 clamping, 2 back-calculation).
    sf, K, kint, nr
        State feedback on the innermost loop (LQR/LQI): flag, (n, B) gain, (B,) integral gain,
        (B,) reference gain.
    u_lo, u_hi, rate
        (B,) actuator limits (scaled per draw) and the rate limit (units/s; inf for none).
    sk0, sk1, soff, sslope
        (3, S, B) additive pieces of the reference, input and output disturbance: start and end
        steps (int64), offset and slope.
    dist_out_loops
        (L,) 1.0 where a loop measures the output the output disturbance acts on.
    noise_std, noise_seed
        (B,) measurement-noise standard deviation and counter-based seed of each candidate.
    max_err, max_out, xbound, div_bound, safe_mode, u_safe
        Safety monitor: error and output bounds, (n,) state bounds, divergence bound,
        action (1 fallback gains, 0 hold ``u_safe``) and the safe input.
    fb_kp, fb_ki, fb_kd, fb_tf, fb_kb
        (L, B) fallback PID rows switched in at a trip (``safe_mode == 1``).
    target, k_step, k_load
        (B,) metric anchors: final reference value, step start and load start (steps).
    want_traces, tr_y, tr_sp, tr_u
        Whether to record traces, into (L, T, B) outputs, (L, T, B) setpoints and (T, B) inputs
        (written in place; zero-size when not wanted).
    """

    n_steps: int
    dt: float
    nonlinear: bool
    Ad: np.ndarray
    G0: np.ndarray
    G1: np.ndarray
    Cm: np.ndarray
    Dm: np.ndarray
    f_op: np.ndarray
    f_a: np.ndarray
    f_b: np.ndarray
    f_o: np.ndarray
    f_c: np.ndarray
    f_nw: int
    h_op: np.ndarray
    h_a: np.ndarray
    h_b: np.ndarray
    h_o: np.ndarray
    h_c: np.ndarray
    h_nw: int
    h_nout: int
    P: np.ndarray
    meas_idx: np.ndarray
    x_op: np.ndarray
    u_op: np.ndarray
    y_op: np.ndarray
    dsteps: np.ndarray
    kp: np.ndarray
    ki: np.ndarray
    kd: np.ndarray
    tf: np.ndarray
    bw: np.ndarray
    cw: np.ndarray
    kb: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    aw: np.ndarray
    sf: bool
    K: np.ndarray
    kint: np.ndarray
    nr: np.ndarray
    u_lo: np.ndarray
    u_hi: np.ndarray
    rate: float
    sk0: np.ndarray
    sk1: np.ndarray
    soff: np.ndarray
    sslope: np.ndarray
    dist_out_loops: np.ndarray
    noise_std: np.ndarray
    noise_seed: np.ndarray
    max_err: float
    max_out: float
    xbound: np.ndarray
    div_bound: float
    safe_mode: int
    u_safe: float
    fb_kp: np.ndarray
    fb_ki: np.ndarray
    fb_kd: np.ndarray
    fb_tf: np.ndarray
    fb_kb: np.ndarray
    target: np.ndarray
    k_step: np.ndarray
    k_load: np.ndarray
    want_traces: bool
    tr_y: np.ndarray
    tr_sp: np.ndarray
    tr_u: np.ndarray

    @classmethod
    def from_fields(cls, *parts: Mapping[str, Any]) -> KernelArgs:
        """The record of the fields in ``parts`` (mappings of field name to value; later ones win).

        Every field must be given, and nothing else. Cheaper than ``KernelArgs(**a, **b)``,
        whose keyword matching over 69 parameters measured ~8 us, against ~3 us here
        (a single simulation costs ~0.1 ms).

        Raises
        ------
        TypeError
            When a field is missing or a name is not a field.
        """
        merged: dict[str, Any] = {}
        for part in parts:
            merged.update(part)
        if len(merged) == len(_FIELD_SET):  # then a missing field means an unknown name: KeyError below
            try:
                return cls._make(_GET_FIELDS(merged))
            except KeyError:
                pass
        missing, extra = sorted(_FIELD_SET - merged.keys()), sorted(merged.keys() - _FIELD_SET)
        raise TypeError(f"KernelArgs fields: missing {missing}, unknown {extra}")

    @property
    def batch(self) -> int:
        """Number of candidates B."""
        return self.u_op.shape[0]

    @property
    def n_loops(self) -> int:
        """Number of loops L."""
        return self.kp.shape[0]

    def with_traces(self) -> KernelArgs:
        """A copy that records traces, into fresh zeroed arrays (the kernel writes them in place)."""
        L, T, B = self.n_loops, self.n_steps, self.batch
        return self._replace(want_traces=True, tr_y=np.zeros((L, T, B)), tr_sp=np.zeros((L, T, B)),
                             tr_u=np.zeros((T, B)))


_FIELD_SET = frozenset(KernelArgs._fields)
_GET_FIELDS = operator.itemgetter(*KernelArgs._fields)
