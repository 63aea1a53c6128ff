"""The MIMO feedback loop: plant, controller and loop pairing, and its responses.

Convention (as MATLAB's ``feedback(G*K, eye(n))``): negative feedback ``u = K (r - y)`` with the
plant ``G`` (p x m, :mod:`gaintune.lti.mimo`) and the controller ``K`` (m x p: plant outputs in,
plant inputs out). The loop pairing names, per loop, the plant output it measures and the plant
input it drives (loops of one cascade share the input their chain ends at). Only those channels
are in the loop: ``Gs = G[outputs, inputs]`` and ``Ks = K[inputs, outputs]`` (loop k on the
diagonal when every loop has its own input). Then, at the plant outputs,
``L_o = Gs Ks``, ``S_o = (I + L_o)^-1``, ``T_o = I - S_o``; at the plant inputs ``L_i = Ks Gs``,
``S_i = (I + L_i)^-1``, ``T_i = I - S_i``.

:func:`decentralised_pid` builds the usual controller, a PID law with a derivative filter on each
loop, ``C(s) = Kp + Ki/s + Kd s/(Tf s + 1)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from gaintune.lti.mimo import DelayedSS, MimoLti, TfEntry, TfMatrix
from gaintune.verification.mimo_plant import plant_eigvals, plant_parts, register_transient, registered
from gaintune.verification.mimo_products import ProductPlan, product_plan, sparse_product
from gaintune.verification.mimo_tf import _tf_realisation, _tf_response, _tf_values

__all__ = ["LoopPair", "PidLoop", "MimoLoop", "pid_entry", "decentralised_pid", "response", "solve_points",
           "hidden_modes", "char_freqs", "closed_loop_matrix"]


@dataclass(frozen=True)
class LoopPair:
    """One loop of the pairing: its name, the plant output it measures and the plant input it drives
    (names, or indices into the plant's outputs and inputs)."""

    name: str
    output: str | int
    input: str | int


@dataclass(frozen=True)
class PidLoop(LoopPair):
    """A loop with its PID gains: ``C(s) = Kp + Ki/s + Kd s/(Tf s + 1)`` (Tf > 0 when Kd != 0)."""

    Kp: float = 0.0
    Ki: float = 0.0
    Kd: float = 0.0
    Tf: float = 0.0


def pid_entry(Kp: float, Ki: float = 0.0, Kd: float = 0.0, Tf: float = 0.0) -> TfEntry:
    """The transfer function ``Kp + Ki/s + Kd s/(Tf s + 1)`` as one entry (descending powers of s).

    Raises
    ------
    ValueError
        A non-finite gain, or a derivative without a filter (Tf <= 0: an improper controller).
    """
    g = {"Kp": Kp, "Ki": Ki, "Kd": Kd, "Tf": Tf}
    bad = [k for k, v in g.items() if not np.isfinite(v)]
    if bad:
        raise ValueError(f"PID gain {bad[0]} = {g[bad[0]]} is not finite: give a finite number")
    if Kd != 0 and not Tf > 0:
        raise ValueError(f"PID with Kd = {Kd} needs a derivative filter Tf > 0 (got Tf = {Tf}): set Tf, e.g. Kd/Kp/10")
    if Kd != 0:  # (Kp (Tf s + 1) s + Ki (Tf s + 1) + Kd s^2) / (s (Tf s + 1))
        num = np.array([Kp * Tf + Kd, Kp + Ki * Tf, Ki])
        den = np.array([Tf, 1.0, 0.0])
        if Ki == 0:
            num, den = num[:2], den[:2]
        return TfEntry(num, den)
    if Ki != 0:
        return TfEntry(np.array([Kp, Ki]), np.array([1.0, 0.0]))
    return TfEntry(np.array([float(Kp)]), np.array([1.0]))


def _index(names: tuple[str, ...], key: str | int, what: str, loop: str) -> int:
    """Index of ``key`` (a name or an index) among ``names``; ValueError naming the loop and the choices."""
    if isinstance(key, int | np.integer) and not isinstance(key, bool):
        if 0 <= int(key) < len(names):
            return int(key)
    elif key in names:
        return names.index(str(key))
    raise ValueError(f"loop {loop!r}: {what} {key!r} is not a plant {what}; choose one of {list(names)} "
                     f"(or an index 0..{len(names) - 1})")


def decentralised_pid(plant: MimoLti, loops: Sequence[PidLoop]) -> TfMatrix:
    """The decentralised controller: an m x p transfer-function matrix, loop k's PID law from its
    output to its input, zero elsewhere. Its inputs are named after the plant outputs, its outputs
    after the plant inputs."""
    p, m = plant.shape
    zero = TfEntry(np.array([0.0]), np.array([1.0]))
    rows = [[zero] * p for _ in range(m)]
    for lp in loops:
        i = _index(plant.outputs, lp.output, "output", lp.name)
        j = _index(plant.inputs, lp.input, "input", lp.name)
        rows[j][i] = pid_entry(lp.Kp, lp.Ki, lp.Kd, lp.Tf)
    return TfMatrix(tuple(tuple(r) for r in rows), inputs=plant.outputs, outputs=plant.inputs)


def solve_points(M: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``np.linalg.solve`` over a stack of points, with inf where a point's matrix is singular.

    A pole exactly on the grid (an integrator's at s = 0) makes numpy raise for the whole stack;
    the figures read an infinite response there instead (an infinite loop gain: S = 0).
    """
    try:
        return np.linalg.solve(M, rhs)
    except np.linalg.LinAlgError:
        n_points = M.shape[0]  # both stacks hold one matrix per point (rhs may be a broadcast view)
        out = np.empty((n_points, *rhs.shape[-2:]), dtype=complex)
        for k in range(n_points):
            try:
                out[k] = np.linalg.solve(M[k], rhs[k])
            except np.linalg.LinAlgError:
                out[k] = np.inf
        return out


def response(sys: MimoLti, s: np.ndarray, rows: Sequence[int] | None = None,
             cols: Sequence[int] | None = None) -> np.ndarray:
    """``sys[rows, cols]`` at the complex points ``s``: (len(s), len(rows), len(cols)), exact delays
    (any s, not only s = jw; all rows or columns when None)."""
    s = np.asarray(s, dtype=complex).ravel()
    p, m = sys.shape
    r = list(range(p)) if rows is None else list(rows)
    c = list(range(m)) if cols is None else list(cols)
    if isinstance(sys, TfMatrix):
        return _tf_response(sys, s, tuple(r), tuple(c))
    n = sys.A.shape[0]
    G = np.broadcast_to(sys.D[np.ix_(r, c)].astype(complex), (s.size, len(r), len(c))).copy()
    if n:  # (a pole exactly at some s gives inf/NaN there, as meant)
        B = sys.B[:, c]
        X = solve_points(s[:, None, None] * np.eye(n) - sys.A[None], np.broadcast_to(B, (s.size, n, len(c))))
        G += sys.C[r][None] @ X
    G *= np.exp(-s[:, None] * sys.output_delays[r][None, :])[:, :, None]
    G *= np.exp(-s[:, None] * sys.input_delays[c][None, :])[:, None, :]
    return G


def _rank(X: np.ndarray, scale: float, tol: float = 1e-7) -> int:
    """Numerical rank of X: singular values above ``tol * scale``."""
    if X.size == 0 or scale <= 0:
        return 0
    return int(np.sum(np.linalg.svd(X, compute_uv=False) > tol * scale))


def hidden_modes(A: np.ndarray, B: np.ndarray, C: np.ndarray, floor: float) -> np.ndarray:
    """:func:`_hidden_modes`, remembered for a plant realisation of :mod:`.mimo_plant` (plant-only work)."""
    hit = registered(A, B, C)
    if hit is None:
        return _hidden_modes(A, B, C, floor)
    parts, order = hit
    return parts.memo(parts.hidden, (order, float(floor)), lambda: _hidden_modes(A, B, C, floor))


def _hidden_modes(A: np.ndarray, B: np.ndarray, C: np.ndarray, floor: float) -> np.ndarray:
    """The eigenvalues of A right of Re s = ``floor`` |lambda|max that (A, B) cannot reach or C cannot
    see: feedback between these inputs and outputs cannot move them.

    Eigenvector (PBH) test on the balanced realisation, per cluster of equal eigenvalues: the
    eigenvectors' rank minus the rank of C V (of W^H B for the left ones). A defective cluster
    (a Jordan chain) has nearly parallel eigenvectors, rank 1, and is not mistaken for hidden.
    Only these eigenvalues matter to a stability count, and the test stays well conditioned on
    the badly scaled Padé realisations where a Kalman decomposition does not."""
    if not A.size:
        return np.zeros(0, dtype=complex)
    ev = np.linalg.eigvals(A)
    if not np.any(ev.real > floor * max(1.0, float(np.max(np.abs(ev))))):
        return np.zeros(0, dtype=complex)  # nothing to test (the eigenvectors cost far more)
    from scipy.linalg import eig, matrix_balance

    Ab, T = matrix_balance(A, permute=False)
    t = np.diag(T)
    Bb, Cb = B / t[:, None], C * t[None, :]
    lam, vl, vr = eig(Ab, left=True, right=True)
    scale = max(1.0, float(np.max(np.abs(lam))))
    idx = np.nonzero(lam.real > floor * scale)[0]
    nb, nc = float(np.linalg.norm(Bb, 2)) if Bb.size else 0.0, float(np.linalg.norm(Cb, 2)) if Cb.size else 0.0
    out: list[complex] = []
    done: set[int] = set()
    for k in idx:
        if int(k) in done:
            continue
        cl = [int(j) for j in idx if abs(lam[j] - lam[k]) <= 1e-6 * max(1.0, abs(lam[k]))]
        done.update(cl)
        V = vr[:, cl] / np.linalg.norm(vr[:, cl], axis=0)
        W = vl[:, cl] / np.linalg.norm(vl[:, cl], axis=0)
        rv, rw = _rank(V, 1.0, 1e-6), _rank(W, 1.0, 1e-6)
        deficit = (rv - _rank(Cb @ V, nc)) + (rw - _rank(W.conj().T @ Bb, nb))
        out += [complex(lam[k])] * min(len(cl), deficit)
    return np.array(out, dtype=complex)


def _modal_form(P: DelayedSS, outs: list[int], ins: list[int]) -> tuple:
    """(ok, eigenvalues, C V, V^-1 B, D, output delays, input delays) of the channels ``outs`` x ``ins``
    (ok: the eigenvectors V are well conditioned; a zero D or delay is None)."""
    lam, V = np.linalg.eig(P.A)
    ok = bool(np.linalg.cond(V) < 1e8)
    D, d_out, d_in = P.D[np.ix_(outs, ins)], P.output_delays[outs], P.input_delays[ins]
    return (ok, lam, P.C[outs] @ V if ok else None, np.linalg.solve(V, P.B[:, ins]) if ok else None,
            D if np.any(D) else None, d_out if np.any(d_out) else None, d_in if np.any(d_in) else None)


def _check_controller(K: MimoLti, plant: MimoLti) -> None:
    p, m = plant.shape
    if K.shape != (m, p):
        raise ValueError(f"controller: shape {K.shape} must be (plant inputs, plant outputs) = ({m}, {p})")


@dataclass
class MimoLoop:
    """The loop: plant, controller and the resolved pairing.

    ``loop_outs[k]``, ``loop_ins[k]``: loop k's output and input; ``outs`` and ``ins``: the measured
    outputs and the driven inputs, each once, in the order of the loops. Each output is measured by
    one loop; several loops may name the same input (a cascade: its chain ends at that input), so
    the loop channels need not be square."""

    plant: MimoLti
    controller: MimoLti
    names: list[str]
    loop_outs: list[int]
    loop_ins: list[int]
    outs: list[int]
    ins: list[int]
    _real: dict[int, tuple[tuple, tuple]] = field(default_factory=dict, repr=False)
    _modal: tuple | None = field(default=None, repr=False)
    _diag: bool | None = field(default=None, repr=False)
    _plans: dict[str, ProductPlan] = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, plant: MimoLti, controller: MimoLti, pairing: Sequence[LoopPair]) -> MimoLoop:
        """Resolve the pairing against the plant's names; each output is measured by one loop only."""
        _check_controller(controller, plant)
        if not pairing:
            raise ValueError("pairing: at least one loop (name, output, input) is needed")
        names = [lp.name for lp in pairing]
        louts = [_index(plant.outputs, lp.output, "output", lp.name) for lp in pairing]
        lins = [_index(plant.inputs, lp.input, "input", lp.name) for lp in pairing]
        dup = {plant.outputs[i] for i in louts if louts.count(i) > 1}
        if dup:
            raise ValueError(f"pairing: plant output {sorted(dup)[0]!r} is measured by more than one loop; "
                             "each loop needs its own output")
        if len(set(names)) != len(names):
            raise ValueError("pairing: loop names must be distinct")
        ins = list(dict.fromkeys(lins))
        loop = cls(plant, controller, names, louts, lins, list(louts), ins)
        loop.check_controller_paths(np.array([0.1, 1.0, 10.0]))
        return loop

    @property
    def n_out(self) -> int:
        """Number of measured outputs (= loops)."""
        return len(self.outs)

    @property
    def n_in(self) -> int:
        """Number of driven inputs."""
        return len(self.ins)

    @property
    def n_small(self) -> int:
        """The smaller side: det(I + Ks Gs) = det(I + Gs Ks) is taken there."""
        return min(self.n_in, self.n_out)

    def input_label(self, k: int) -> str:
        """Name of input break k: the loop driving input ``ins[k]`` (loops sharing it joined by '+')."""
        return "+".join(nm for nm, j in zip(self.names, self.loop_ins, strict=True) if j == self.ins[k])

    def channels(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Gs, Ks) at ``s``: (len(s), n, n) each, loop k on the diagonal."""
        return self._plant_channels(np.asarray(s, dtype=complex).ravel()), response(self.controller, s, self.ins,
                                                                                    self.outs)

    def _plant_channels(self, s: np.ndarray) -> np.ndarray:
        """Gs at ``s``; a state-space plant through its eigendecomposition (one solve per frequency
        costs far more for many loops), unless the eigenvectors are ill conditioned."""
        P = self.plant
        if not isinstance(P, DelayedSS) or P.A.shape[0] == 0:
            return response(P, s, self.outs, self.ins)
        if self._modal is None:
            parts = plant_parts(P, tuple(self.outs), tuple(self.ins))
            if parts.modal is None:  # plant-only: once per plant object
                parts.modal = _modal_form(P, self.outs, self.ins)
            self._modal = parts.modal
        ok, lam, CV, VB, D, d_out, d_in = self._modal
        if not ok:
            return response(P, s, self.outs, self.ins)
        with np.errstate(all="ignore"):
            G = (CV[None] * (1.0 / (s[:, None] - lam[None, :]))[:, None, :]) @ VB
            if D is not None:
                G += D[None]
            if d_out is not None:
                G *= np.exp(-s[:, None] * d_out[None, :])[:, :, None]
            if d_in is not None:
                G *= np.exp(-s[:, None] * d_in[None, :])[:, None, :]
        return G

    def diagonal_controller(self) -> bool:
        """Whether the loops are decentralised: one input per loop and the controller's loop channels
        diagonal (probed at 1e-2..1e2 rad/s)."""
        if self._diag is None and self.n_in != self.n_out:
            self._diag = False
        if self._diag is None:
            K = np.abs(response(self.controller, 1j * np.logspace(-2, 2, 5), self.ins, self.outs))
            off = K.sum() - np.trace(K, axis1=1, axis2=2).sum()
            self._diag = bool(off <= 1e-12 * max(1.0, float(K.sum())))
        return self._diag

    def check_controller_paths(self, w: np.ndarray) -> None:
        """Refuse a controller path from or to a channel outside the pairing (it would close a loop
        the pairing does not name), checked on the frequencies ``w``."""
        K = np.abs(response(self.controller, 1j * np.asarray(w, dtype=float)))
        inside = K[:, self.ins][:, :, self.outs]
        with np.errstate(invalid="ignore"):
            outside = float(np.nansum(K) - np.nansum(inside))
        if outside > 1e-12 * max(1.0, float(np.nansum(inside))):
            raise ValueError("controller: it has a path from an output or to an input that no loop of the pairing "
                             "uses; add that loop to the pairing or remove the path")

    def loop_gains(self, s: np.ndarray, side: str) -> np.ndarray:
        """L at ``s``: ``Ks Gs`` (side "input") or ``Gs Ks`` ("output"), (len(s), n, n)."""
        s = np.asarray(s, dtype=complex).ravel()
        if self.diagonal_controller():  # a row or column scaling, not a product
            Gs = self._plant_channels(s)
            K = self.controller
            if isinstance(K, TfMatrix):
                k = np.zeros((s.size, self.n_in), dtype=complex)
                ra, _, v = _tf_values(K, s, tuple(self.ins), tuple(self.outs))
                k[:, ra] = v
            else:
                k = np.diagonal(response(K, s, self.ins, self.outs), axis1=1, axis2=2)
            with np.errstate(all="ignore"):
                return k[:, :, None] * Gs if side == "input" else Gs * k[:, None, :]
        if isinstance(self.controller, TfMatrix):
            return self._sparse_loop_gains(s, side)
        Gs, Ks = self.channels(s)
        with np.errstate(all="ignore"):
            return Ks @ Gs if side == "input" else Gs @ Ks

    def _plant_entries(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, columns, values (len(s), entries)) of Gs: a transfer matrix's nonzero entries, else all."""
        if isinstance(self.plant, TfMatrix):
            return _tf_values(self.plant, s, tuple(self.outs), tuple(self.ins))
        Gs = self._plant_channels(s)
        rows, cols = np.divmod(np.arange(self.n_out * self.n_in), self.n_in)
        return rows, cols, Gs.reshape(s.size, -1)

    def outputs_by_inputs(self) -> bool:
        """Whether output-side figures are taken on the smaller input side from :meth:`input_side`: fewer
        inputs than outputs (a cascade), a transfer-matrix controller, and this class's own responses (a
        subclass with its own, the sampled loop, keeps the output-side solve)."""
        cls = type(self)
        own = cls.loop_gains is MimoLoop.loop_gains and cls.channels is MimoLoop.channels
        return own and self.n_in < self.n_out and isinstance(self.controller, TfMatrix)

    def input_side(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(L_i = Ks Gs, Gs, Ks) at ``s`` from one evaluation of the entries."""
        s = np.asarray(s, dtype=complex).ravel()
        K = self.controller
        if not self.outputs_by_inputs() or self.diagonal_controller() or not isinstance(K, TfMatrix):
            Gs, Ks = self.channels(s)
            return self.loop_gains(s, "input"), Gs, Ks
        entries = (*_tf_values(K, s, tuple(self.ins), tuple(self.outs)), *self._plant_entries(s))
        return self._sparse_loop_gains(s, "input", entries), *self._dense_channels(s, entries)

    def input_side_rows(self, s: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(L_i, Gs[p, k[p], :], Ks[p, :, k[p]]) at the points ``s``: what an output row's zoom reads, without
        the dense Gs and Ks of every point (73 MB at the 110-gain train's 4,752 zoom points)."""
        s = np.asarray(s, dtype=complex).ravel()
        K = self.controller
        if not self.outputs_by_inputs() or self.diagonal_controller() or not isinstance(K, TfMatrix):
            return self._rows_of_dense(s, k)
        entries = (*_tf_values(K, s, tuple(self.ins), tuple(self.outs)), *self._plant_entries(s))
        return self._sparse_loop_gains(s, "input", entries), *self._channel_rows(k, entries)

    def _rows_of_dense(self, s: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`input_side_rows` from the dense :meth:`input_side`."""
        L, Gs, Ks = self.input_side(s)
        p = np.arange(s.size)
        return L, Gs[p, k, :], Ks[p, :, k]

    def _channel_rows(self, k: np.ndarray, entries: tuple) -> tuple[np.ndarray, np.ndarray]:
        """(Gs[p, k[p], :], Ks[p, :, k[p]]) from the nonzero ``entries`` = (kr, kc, kv, gr, gc, gv): the same
        values :meth:`_dense_channels` would hold there."""
        kr, kc, kv, gr, gc, gv = entries
        g_row = np.zeros((kv.shape[0], self.n_in), dtype=complex)
        k_col = np.zeros((kv.shape[0], self.n_in), dtype=complex)
        p, e = np.nonzero(np.asarray(gr)[None, :] == k[:, None])
        g_row[p, np.asarray(gc)[e]] = gv[p, e]
        p, e = np.nonzero(np.asarray(kc)[None, :] == k[:, None])
        k_col[p, np.asarray(kr)[e]] = kv[p, e]
        return g_row, k_col

    def _dense_channels(self, s: np.ndarray, entries: tuple) -> tuple[np.ndarray, np.ndarray]:
        """(Gs, Ks) as dense arrays from the nonzero ``entries`` = (kr, kc, kv, gr, gc, gv) at ``s``."""
        kr, kc, kv, gr, gc, gv = entries
        Gs = np.zeros((s.size, self.n_out, self.n_in), dtype=complex)
        Gs[:, gr, gc] = gv
        Ks = np.zeros((s.size, self.n_in, self.n_out), dtype=complex)
        Ks[:, kr, kc] = kv
        return Gs, Ks

    def _sparse_loop_gains(self, s: np.ndarray, side: str, entries: tuple | None = None) -> np.ndarray:
        """L from the nonzero entries of Ks and Gs only (:mod:`.mimo_products`); ``entries``: theirs at ``s``
        when known. Where an entry is not finite (a pole on the point) the dense product stands, whose
        inf * 0 = NaN the figures expect."""
        assert isinstance(self.controller, TfMatrix)
        if entries is None:
            entries = (*_tf_values(self.controller, s, tuple(self.ins), tuple(self.outs)), *self._plant_entries(s))
        kr, kc, kv, gr, gc, gv = entries
        plan = self._plans.get(side)
        if plan is None:
            plan = (product_plan(kr, kc, gr, gc, (self.n_in, self.n_in)) if side == "input"
                    else product_plan(gr, gc, kr, kc, (self.n_out, self.n_out)))
            self._plans[side] = plan
        L = sparse_product(plan, kv, gv) if side == "input" else sparse_product(plan, gv, kv)
        bad = ~(np.all(np.isfinite(kv), axis=1) & np.all(np.isfinite(gv), axis=1))
        if bad.any():
            Gs, Ks = self.channels(s[bad])
            with np.errstate(all="ignore"):
                L[bad] = Ks @ Gs if side == "input" else Gs @ Ks
        return L

    def sensitivity(self, s: np.ndarray, side: str) -> np.ndarray:
        """S at ``s`` on one side ("input" or "output"), (len(s), n, n)."""
        with np.errstate(all="ignore"):
            return np.linalg.inv(np.eye(self.n_in if side == "input" else self.n_out) + self.loop_gains(s, side))

    def sensitivities(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(S_i, S_o) at ``s``: input- and output-side sensitivities (len(s), n, n)."""
        return self.sensitivity(s, "input"), self.sensitivity(s, "output")

    def realisations(self, pade_order: int) -> tuple[tuple, tuple]:
        """Delay-free realisations (A, B, C, D) of the plant's loop channels (delays as Padé approximants
        of ``pade_order``; 0 drops them) and of the controller's loop channels."""
        if pade_order in self._real:
            return self._real[pade_order]
        plant = plant_parts(self.plant, tuple(self.outs), tuple(self.ins)).realisation(pade_order)
        ctrl = next(iter(self._real.values()))[1] if self._real else self._controller_realisation()
        self._real[pade_order] = (plant, ctrl)
        return plant, ctrl

    def _controller_realisation(self) -> tuple:
        """(A, B, C, D) of the controller's loop channels, delay-free whatever the Padé order: one object
        for every order, known to :func:`~.mimo_plant.plant_memo` while this loop is checked."""
        K = self.controller
        if isinstance(K, TfMatrix):  # only the entries in the loop (a big sparse matrix realises slowly)
            ctrl = _tf_realisation(K, self.ins, self.outs)
        else:
            Kc = K.pade_ss(0)
            ctrl = (Kc.A, Kc.B[:, self.outs], Kc.C[self.ins], Kc.D[np.ix_(self.ins, self.outs)])
        register_transient(K, ctrl)
        return ctrl

    def max_delay(self) -> float:
        """The largest delay of the loop channels (0 without delays; plant-only, found once per plant)."""
        parts = plant_parts(self.plant, tuple(self.outs), tuple(self.ins))
        if parts.max_delay is None:
            P = self.plant
            if isinstance(P, TfMatrix):
                parts.max_delay = max((P.entries[i][j].delay for i in self.outs for j in self.ins), default=0.0)
            else:
                assert isinstance(P, DelayedSS)
                parts.max_delay = float(P.input_delays[self.ins].max(initial=0.0)
                                        + P.output_delays[self.outs].max(initial=0.0))
        return parts.max_delay


def char_freqs(loop: MimoLoop) -> np.ndarray:
    """Characteristic frequencies (rad/s) of the loop: magnitudes of the plant's and the controller's
    poles, of the controller's zeros (PID corners) and 1/T of the largest delay ([1.0] when none)."""
    (Ap, _, _, _), (Ak, _, _, _) = loop.realisations(0)
    f = [np.abs(plant_eigvals(A)) for A in (Ap, Ak) if A.size]
    K = loop.controller
    if isinstance(K, TfMatrix):
        f += [np.abs(np.roots(e.num)) for row in K.entries for e in row if not e.is_zero and e.num.size > 1]
    T = loop.max_delay()
    if T > 0:
        f.append(np.array([1.0 / T]))
    allf = np.concatenate(f) if f else np.zeros(0)
    kept = allf[np.isfinite(allf) & (allf > 1e-12)]
    return kept if kept.size else np.array([1.0])


def closed_loop_matrix(plant: tuple, ctrl: tuple) -> np.ndarray:
    """State matrix of u = K (r - y), y = G u, from the realisations (A, B, C, D) of G and K."""
    A, B, C, D = plant
    Ak, Bk, Ck, Dk = ctrl
    # u = E (Ck xk - Dk C x): the algebraic loop through both feedthroughs
    E = np.linalg.inv(np.eye(D.shape[1]) + Dk @ D)
    Fx, Fk = -E @ Dk @ C, E @ Ck
    Yx, Yk = C + D @ Fx, D @ Fk
    return np.block([[A + B @ Fx, B @ Fk], [-Bk @ Yx, Ak - Bk @ Yk]])
