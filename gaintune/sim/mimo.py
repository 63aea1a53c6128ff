"""The batched closed-loop simulator for plants with several inputs and loops wired as a graph.

:class:`MimoSimulator` has the interface of :class:`gaintune.sim.Simulator` (``spec``, ``plant``,
``layout``, ``nominal_draws``, ``run`` returning a :class:`~gaintune.sim.SimResult` with the same
metric names), so the evaluator, the reward, the optimisers and the search use it unchanged:
``Simulator(spec)`` returns one for a spec that needs it (:func:`gaintune.sim.simulator.needs_mimo`).

Metrics: the single-input names, where ``iae``/``ise``/``itae`` sum the integrals of every chain's
outer error (``iae.<loop>`` etc. per chain, by its outer loop), ``effort`` and ``tv`` sum over the
actuators (``effort.<input>`` per input), and the step-response marks (overshoot, rise and
settling time, ``y_final``, ``sse``) are those of the chain the scenario's reference steps.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass

import numpy as np

from gaintune.controllers.layout import GainLayout
from gaintune.controllers.pid import pid_params
from gaintune.errors import SpecError
from gaintune.lti.mimo import TfMatrix
from gaintune.plants.mimo import MimoPlant, as_mimo
from gaintune.sim import draws as draws_mod
from gaintune.sim.build import discretize, profile_pieces
from gaintune.sim.draws import Draws
from gaintune.sim.mimo_blocks import BlockMatrices, check_block_inputs
from gaintune.sim.mimo_kernel import LANES, MIMO_METRICS, mimo_kernel
from gaintune.sim.mimo_ode import ode_rows, ode_tapes
from gaintune.sim.result import SimResult
from gaintune.spec import ProfileSpec, ScenarioSpec, TuningSpec, check_delay_samples
from gaintune.spec.mimo import drive_target, is_graph

__all__ = ["MimoSimulator", "Architecture", "architecture", "plant_channels"]

AW_CODES = {"none": 0, "clamping": 1, "back_calculation": 2}


@dataclass(frozen=True)
class Architecture:
    """The loop graph resolved against the plant.

    ``order`` lists the spec's loop indices drivers first; the other per-loop arrays are in that
    order: ``parent`` (position of the driving loop, -1 for a chain's outer loop), ``meas`` (output
    index), ``drives`` (input index, -1 for a setpoint). ``roots`` are positions of outer loops.
    ``W`` (m, L) maps the loops' outputs to the plant inputs (identity or the decoupler; tuned entries
    at their spec value or bounds' centre: :mod:`gaintune.sim.mimo_blocks` gives each candidate's).
    """

    order: tuple[int, ...]
    parent: np.ndarray
    meas: np.ndarray
    drives: np.ndarray
    roots: np.ndarray
    W: np.ndarray


def _drives(spec: TuningSpec, plant: MimoPlant) -> list[tuple[str, str]]:
    """(kind, target) per spec loop: the explicit ``drives``, or today's single cascade."""
    if is_graph(spec):
        return [drive_target(lp.drives or "") for lp in spec.loops]
    if len(plant.inputs) != 1:
        raise SpecError("loops", f"the plant has {len(plant.inputs)} inputs ({', '.join(plant.input_names)}): say "
                        "what each loop drives (drives: <input> or drives: loop:<name>)")
    names = spec.loop_names
    return [("loop", names[i + 1]) for i in range(len(names) - 1)] + [("input", plant.input_names[0])]


def architecture(spec: TuningSpec, plant: MimoPlant) -> Architecture:
    """Resolve the spec's loops against the plant (names checked; SpecError naming the field)."""
    names, inputs = spec.loop_names, plant.input_names
    check_block_inputs(spec, inputs)
    drv = _drives(spec, plant)
    for i, (kind, target) in enumerate(drv):
        if kind == "input" and target not in inputs:
            raise SpecError(f"loops[{i}].drives", f"the plant has no input {target!r}; inputs: {', '.join(inputs)}")
    for i, lp in enumerate(spec.loops):
        if lp.is_lq:
            raise SpecError(f"loops[{i}].type", "state-feedback loops are not supported on this simulator yet")
        if lp.measure is not None and lp.measure not in plant.outputs:
            raise SpecError(f"loops[{i}].measure", f"the plant has no output {lp.measure!r}; outputs: "
                            f"{', '.join(plant.outputs)}")
    driver = {names.index(t): i for i, (kind, t) in enumerate(drv) if kind == "loop"}
    order: list[int] = []
    pending = [i for i in range(len(names)) if i not in driver]
    while pending:  # breadth first from the outer loops: a driver always comes first
        i = pending.pop(0)
        order.append(i)
        pending += [k for k, d in driver.items() if d == i]
    pos = {i: k for k, i in enumerate(order)}
    parent = np.array([pos[driver[i]] if i in driver else -1 for i in order], dtype=np.int64)
    meas = np.array([plant.outputs.index(spec.loops[i].measure or plant.outputs[0]) for i in order], dtype=np.int64)
    drives = np.array([inputs.index(drv[i][1]) if drv[i][0] == "input" else -1 for i in order], dtype=np.int64)
    W = np.zeros((len(inputs), len(order)))
    for k, j in enumerate(drives):
        if j >= 0:
            W[j, k] = 1.0
    if spec.decoupler is not None:
        W = _decoupled(spec, inputs, drives, W)
    return Architecture(tuple(order), parent, meas, drives, np.flatnonzero(parent < 0).astype(np.int64), W)


def _decoupled(spec: TuningSpec, inputs: list[str], drives: np.ndarray, W: np.ndarray) -> np.ndarray:
    dec = spec.decoupler
    assert dec is not None
    cols = [inputs.index(n) for n in dec.inputs]
    Wd = np.array(dec.values(), dtype=float)
    out = W.copy()
    for a, ja in enumerate(cols):  # row: the plant input; column: the loop output driving input jb
        out[ja, :] = 0.0
        for b, jb in enumerate(cols):
            out[ja, :] += Wd[a, b] * (drives == jb)
    return out


# ----------------------------------------------------------------- the plant


def plant_channels(lti, dt: float, act_delay: np.ndarray, dist_state: int = -1):
    """Discretised blocks and channels of one plant form (see :mod:`gaintune.sim.mimo_kernel`).

    Returns a dict of Ad (N, N), C (p, N), block starts and sizes, and per channel its block,
    source input, and (delay steps, G0, G1) for the actuator path (plant + actuator delay) and
    for the disturbance path (plant delay only). ``dist_state`` >= 0 (state space only) adds a
    channel with source ``m`` (the state disturbance) into that state's derivative.
    """
    blocks, chans = [], []  # (A,), (block, input, B column, plant delay)
    # a disturbance passes a transfer-function entry's delay (part of that path), but enters a state-space
    # plant after its input delay, as in the single-input simulator
    dist_delay = isinstance(lti, TfMatrix)
    if isinstance(lti, TfMatrix):
        Cs = []
        for i, row in enumerate(lti.entries):
            for j, e in enumerate(row):
                if e.is_zero:
                    continue
                A, B, C, _ = e.realisation()
                blocks.append(A)
                chans.append((len(blocks) - 1, j, B[:, 0], e.delay))
                Cs.append((i, C[0]))
    else:
        if np.any(lti.output_delays > 0):
            raise SpecError("plant", "output delays are not supported by the simulator; give input delays")
        blocks.append(lti.A)
        chans = [(0, j, lti.B[:, j], float(lti.input_delays[j])) for j in range(lti.shape[1])]
        if dist_state >= 0:
            chans.append((0, lti.shape[1], np.eye(lti.A.shape[0])[dist_state], 0.0))
    sizes = np.array([a.shape[0] for a in blocks], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    N, p = int(sizes.sum()), lti.shape[0]
    Ad = np.zeros((N, N))
    Cm = np.zeros((p, N))
    if isinstance(lti, TfMatrix):
        for (i, c), s0, n in zip(Cs, starts, sizes, strict=True):
            Cm[i, s0:s0 + n] = c
    else:
        Cm[:, :] = lti.C
    nc = len(chans)
    out = {k: np.zeros((nc, N)) for k in ("G0u", "G1u", "G0d", "G1d")}
    du, dd = np.zeros(nc, dtype=np.int64), np.zeros(nc, dtype=np.int64)
    for c, (blk, j, bcol, delay) in enumerate(chans):
        s0, n = starts[blk], sizes[blk]
        A, Bc = blocks[blk][None], bcol.reshape(1, n, 1)
        act = act_delay[j] if j < len(act_delay) else 0.0
        for tag, d in (("u", delay + act), ("d", delay if dist_delay else 0.0)):
            a_d, g0, g1, steps = discretize(A, Bc, dt, np.array([d]))
            Ad[s0:s0 + n, s0:s0 + n] = a_d[0]
            out[f"G0{tag}"][c, s0:s0 + n] = g0[0]
            out[f"G1{tag}"][c, s0:s0 + n] = g1[0]
            (du if tag == "u" else dd)[c] = steps[0]
    return dict(Ad=Ad, Cm=Cm, bstart=starts, bsize=sizes, ch_blk=np.array([c[0] for c in chans], dtype=np.int64),
                ch_src=np.array([c[1] for c in chans], dtype=np.int64), ch_du=du, ch_dd=dd, **out)


def _signal(p: ProfileSpec, dt: float, n_steps: int) -> np.ndarray:
    """The profile's value at every step (the additive pieces of the single-input simulator)."""
    v = np.zeros(n_steps)
    k = np.arange(n_steps)
    for k0, k1, off, slope in profile_pieces(p, dt, n_steps):
        on = (k >= k0) & (k < k1)
        v += np.where(on, off + slope * (k - k0) * dt, 0.0)
    return v


def _refuse_unsupported(spec: TuningSpec) -> None:
    """What this simulator does not do yet, refused by field (never a silent difference)."""
    rz = spec.randomize
    for name in ("delay", "actuator_scale", "reference_kinds", "reference_amplitude", "disturbance_size",
                 "disturbance_time"):
        if getattr(rz, name):
            raise SpecError(f"randomize.{name}", "a plant with several inputs or a loop graph randomises plant "
                            "parameters only so far (randomize.params); remove this entry")
    if spec.safety.action == "fallback":
        raise SpecError("safety.action", "fallback gains are not supported with several inputs or a loop graph "
                        "yet; use hold (every actuator to its safe_value)")
    for i, sc in enumerate(spec.scenarios):
        if sc.disturbance.kind != "none" and sc.disturbance.entry == "output":
            raise SpecError(f"scenarios[{i}].disturbance.entry", "with several inputs or a loop graph a disturbance "
                            "enters at a plant input (entry: input, input: <name>)")
        if sc.noise_std > 0:
            raise SpecError(f"scenarios[{i}].noise_std", "measurement noise is not simulated with several inputs "
                            "or a loop graph yet; set it to 0")


class MimoSimulator:
    """Compiled closed-loop simulator for a MIMO plant or a loop graph (the :class:`gaintune.sim.Simulator`
    interface).

    Parameters
    ----------
    spec
        The tuning problem; scenarios without dt/horizon get them from the plant.
    plant, layout
        Reuse already-built objects (optional). A single-input plant is viewed as a one-input MIMO plant.
    """

    def __init__(self, spec: TuningSpec, plant=None, layout: GainLayout | None = None) -> None:
        from gaintune.classical.timescale import resolve_scenarios
        from gaintune.plants import build_plant

        built = plant if plant is not None else build_plant(spec.plant)
        self.spec = spec = resolve_scenarios(spec, built)
        self.plant = built
        self.mimo = as_mimo(built)
        _refuse_unsupported(spec)
        self.arch = architecture(spec, self.mimo)
        self.layout = layout or GainLayout(spec, built.states, plant=built)
        self.blocks = BlockMatrices(spec, self.layout, self.arch.W, self.arch.drives, self.arch.order,
                                    self.mimo.input_names)
        for sc in spec.scenarios:
            for j, d in enumerate(self._act_delays()):
                check_delay_samples(d, sc.resolved_dt, f"actuators.{self.mimo.input_names[j]}.delay")
        self._plants: dict[tuple, dict] = {}
        self._arrays: dict[tuple, dict] = {}
        self._tapes = ode_tapes(self.mimo)
        for i, sc in enumerate(spec.scenarios):
            self._dist_state(sc, i)

    def _dist_state(self, sc: ScenarioSpec, where: int | None) -> int:
        """Index of the state the scenario's disturbance enters (-1: none); SpecError naming the field."""
        name = sc.disturbance.state
        if name is None or sc.disturbance.kind == "none":
            return -1
        field = f"scenarios[{where}].disturbance.state" if where is not None else "disturbance.state"
        if isinstance(self.mimo.lti(), TfMatrix):
            raise SpecError(field, "a transfer-function matrix has no named states; disturb an input instead")
        if name not in self.mimo.states:
            raise SpecError(field, f"the plant has no state {name!r}; states: {', '.join(self.mimo.states)}")
        return self.mimo.states.index(name)

    def nominal_draws(self, n: int = 1) -> Draws:
        """The nominal plant and scenario, ``n`` times."""
        return draws_mod.nominal(self.spec, self.plant, n, seed=self.spec.search.seed)

    # ------------------------------------------------------------- arrays
    def _actuator(self, j: int):
        name = self.mimo.input_names[j]
        acts = self.spec.actuators or {}
        if name in acts:
            return acts[name]
        if len(self.mimo.inputs) == 1 and self.spec.actuators is None:
            a = self.spec.actuator
            return type("Act", (), {"limits": a.limits, "rate_limit": a.rate_limit, "delay": 0.0,
                                    "safe_value": a.safe_value})
        return None

    def _ode_delays(self, dt: float) -> np.ndarray:
        """Whole-sample actuator delays of a nonlinear plant (its RK4 holds each input over a sample)."""
        if not self.mimo.nonlinear:
            return np.zeros(0, dtype=np.int64)
        return np.round(self._act_delays() / dt).astype(np.int64)  # as the single-input nonlinear path

    def _act_delays(self) -> np.ndarray:
        return np.array([getattr(self._actuator(j), "delay", 0.0) or 0.0 for j in range(len(self.mimo.inputs))])

    def _plant_arrays(self, params: np.ndarray, dt: float, dstate: int) -> dict:
        """Channels of the plant at each distinct parameter row, stacked: (P, ...) and the row of each candidate."""
        rows, pidx = np.unique(np.atleast_2d(params), axis=0, return_inverse=True)
        per = []
        for r in rows:
            key = (float(dt), dstate, *map(float, r))
            hit = self._plants.get(key)
            if hit is None:
                if len(self._plants) > 64:
                    self._plants.clear()
                values = dict(zip(self.mimo.param_names, r, strict=True))
                if self.mimo.nonlinear:
                    hit = ode_rows(self.mimo, values, r)
                else:
                    hit = plant_channels(self.mimo.lti(values), dt, self._act_delays(), dstate)
                    hit.update({k: np.zeros(0) for k in ("Pq", "x_op", "u_op", "y_op")})  # ODE-only rows
                self._plants[key] = hit
            per.append(hit)
        shapes = {k: {np.shape(p[k]) for p in per} for k in ("Ad", "Cm", "ch_du")}
        if any(len(v) > 1 for v in shapes.values()):
            raise SpecError("randomize.params", "the plant's structure (order of an entry) changes across the "
                            "randomised range; structural parameters cannot be randomised")
        out = {k: np.stack([p[k] for p in per]) for k in ("Ad", "Cm", "ch_du", "ch_dd", "G0u", "G1u", "G0d", "G1d",
                                                         "Pq", "x_op", "u_op", "y_op")}
        out.update({k: per[0][k] for k in ("bstart", "bsize", "ch_blk", "ch_src")})
        out["pidx"] = np.ascontiguousarray(pidx.reshape(-1), dtype=np.int64)
        out["cand"], out["chunk_start"] = _chunks(out["pidx"])
        return out

    def _memo(self, key: tuple, build) -> dict:
        """Gain-independent arrays under ``key`` (plant per draw set, signals per scenario), built on a miss:
        optimisers and the RL environment call again and again with the same draws."""
        hit = self._arrays.get(key)
        if hit is None:
            if len(self._arrays) > 64:
                self._arrays.clear()
            hit = self._arrays[key] = build()
        return hit

    def _controller_arrays(self, full: np.ndarray) -> dict:
        spec, arch, B = self.spec, self.arch, full.shape[0]
        cols: dict[int, dict[str, np.ndarray]] = {}
        for k, slot in enumerate(self.layout.slots):
            cols.setdefault(slot.loop, {})[slot.name] = full[:, k]
        L = len(arch.order)
        arr = {k: np.zeros((L, B)) for k in ("kp", "ki", "kd", "tf", "kb", "lo", "hi")}
        bw, cw, aw = np.zeros(L), np.zeros(L), np.zeros(L, dtype=np.int64)
        direct = np.full(L, -1, dtype=np.int64)
        for pos, i in enumerate(arch.order):
            lp = spec.loops[i]
            pp = pid_params(lp, cols.get(i, {}))
            for name, v in (("kp", pp.Kp), ("ki", pp.Ki), ("kd", pp.Kd), ("tf", pp.Tf)):
                arr[name][pos] = v
            tt = np.broadcast_to(np.asarray(pp.Tt, dtype=float), (B,))
            arr["kb"][pos] = np.where(np.isfinite(tt), 1.0 / tt, 0.0)
            bw[pos], cw[pos], aw[pos] = pp.b, pp.c, AW_CODES[lp.anti_windup]
            lo, hi = -np.inf, np.inf
            j = int(arch.drives[pos])
            if lp.output_limits is not None:
                lo, hi = lp.output_limits
            elif j >= 0 and spec.decoupler is None:
                act = self._actuator(j)
                if act is not None and act.limits is not None:
                    lo, hi = act.limits
            if j >= 0 and spec.decoupler is None:
                direct[pos] = j
            arr["lo"][pos], arr["hi"][pos] = lo, hi
        return dict(**arr, bw=bw, cw=cw, aw=aw, direct=direct)

    def _signals(self, sc: ScenarioSpec, where: int | None) -> dict:
        spec, arch, n, dt = self.spec, self.arch, sc.n_steps, sc.resolved_dt
        names = [spec.loop_names[i] for i in arch.order]
        roots = list(arch.roots)
        ref_name = sc.reference.loop or names[roots[0]]
        step_pos = names.index(ref_name)
        if step_pos not in roots:
            raise SpecError(f"scenarios[{where}].reference.loop", f"loop {ref_name!r} takes its setpoint from "
                            "another loop; a reference steps the outer loop of a chain")
        root_row = np.zeros(len(names), dtype=np.int64)
        for r, pos in enumerate(roots):
            root_row[pos] = r
        ref = np.zeros((len(roots), n))
        full_ref = _signal(sc.reference, dt, n + 1)
        ref[roots.index(step_pos)] = full_ref[:n]
        pieces = profile_pieces(sc.reference, dt, n)
        k_step = pieces[0][0] if pieces and pieces[0][0] <= n else 0
        m = len(self.mimo.inputs)
        dist, dist_on = np.zeros((m + 1, n)), np.zeros(m + 1, dtype=np.bool_)  # row m: a state disturbance
        k_load = n + 1
        if sc.disturbance.kind != "none":
            j = m if self._dist_state(sc, where) >= 0 else self.mimo.input_names.index(
                sc.disturbance.input or self.mimo.input_names[0])
            dist[j], dist_on[j] = _signal(sc.disturbance, dt, n), True
            dp = profile_pieces(sc.disturbance, dt, n)
            k_load = dp[0][0] if dp and dp[0][0] <= n else n + 1
        return dict(ref=ref, root_row=root_row, roots=np.array(roots, dtype=np.int64), step_root=step_pos,
                    target=float(full_ref[n]), k_step=int(k_step), k_load=int(k_load), dist=dist, dist_on=dist_on)

    # ---------------------------------------------------------------- run
    def run(self, full_gains: np.ndarray, draws: Draws | None = None, scenario: ScenarioSpec | int = 0,
            traces: bool = False) -> SimResult:
        """Simulate B full gain vectors (B, n_gains) on one scenario (nominal plant unless ``draws``).

        Diverging candidates are flagged (metrics inf), never raised.
        """
        full = np.atleast_2d(np.asarray(full_gains, dtype=float))
        B = full.shape[0]
        where = scenario if isinstance(scenario, int) else None
        sc = self.spec.scenarios[scenario] if isinstance(scenario, int) else scenario
        d = draws if draws is not None else self.nominal_draws(B)
        if len(d) != B:
            raise ValueError(f"draws has {len(d)} rows for {B} gain sets")
        n, dt = sc.n_steps, sc.resolved_dt
        params = d.params if d.params.size else np.zeros((B, 0))
        dstate = self._dist_state(sc, where)
        pa = self._memo(("plant", dt, dstate, params.shape, params.tobytes()),
                        lambda: self._plant_arrays(params, dt, dstate))
        ca = self._controller_arrays(full)
        W, F = self.blocks.matrices(full)
        sg = self._memo(("signals", where, sc.model_dump_json()), lambda: self._signals(sc, where))
        m, L = len(self.mimo.inputs), len(self.arch.order)
        acts = [self._actuator(j) for j in range(m)]
        lim = [a.limits if a is not None and a.limits is not None else (-np.inf, np.inf) for a in acts]
        rate = np.array([a.rate_limit if a is not None and a.rate_limit is not None else np.inf for a in acts])
        u_safe = np.array([a.safe_value if a is not None else 0.0 for a in acts])
        xb = np.full(self.mimo.order, np.inf)
        for name, bound in self.spec.safety.state_bounds.items():
            xb[self.mimo.states.index(name)] = bound
        s = self.spec.safety
        out = np.zeros((len(MIMO_METRICS), B))
        chain_out = np.zeros((len(sg["roots"]), 3, B))
        eff_out = np.zeros((m, B))
        shape = (n, B) if traces else (0, B)
        tr_y, tr_sp, tr_u = np.zeros((L, *shape)), np.zeros((L, *shape)), np.zeros((m, *shape))
        args = (pa["cand"], pa["chunk_start"], n, dt, pa["pidx"], pa["Ad"], pa["bstart"], pa["bsize"], pa["Cm"],
                pa["ch_blk"], pa["ch_src"],
                pa["ch_du"], pa["G0u"], pa["G1u"], pa["ch_dd"], pa["G0d"], pa["G1d"], sg["dist_on"],
                self.arch.meas, self.arch.parent, sg["root_row"], ca["kp"], ca["ki"], ca["kd"], ca["tf"], ca["kb"],
                ca["bw"], ca["cw"], ca["lo"], ca["hi"], ca["aw"], W, F, ca["direct"],
                np.array([x[0] for x in lim], dtype=float), np.array([x[1] for x in lim], dtype=float), rate, u_safe,
                sg["ref"], sg["dist"], sg["roots"], sg["step_root"], sg["target"], sg["k_step"], sg["k_load"],
                s.max_abs_error or np.inf, s.max_abs_output or np.inf, xb, s.divergence_bound, s.action == "hold",
                out, chain_out, eff_out, traces, tr_y, tr_sp, tr_u, self.mimo.nonlinear, *self._tapes[0],
                *self._tapes[1], pa["Pq"], pa["x_op"], pa["u_op"], pa["y_op"], self._ode_delays(dt), dstate)
        _run_threaded(args)
        return self._result(sc, out, chain_out, eff_out, traces, tr_y, tr_sp, tr_u)

    def _result(self, sc: ScenarioSpec, out, chain_out, eff_out, traces, tr_y, tr_sp, tr_u) -> SimResult:
        metrics = {name: out[i] for i, name in enumerate(MIMO_METRICS)}
        metrics["diverged"] = metrics["diverged"].astype(bool)
        metrics["tripped"] = metrics["tripped"].astype(bool)
        names = [self.spec.loop_names[i] for i in self.arch.order]
        for r, pos in enumerate(self.arch.roots):
            for z, what in enumerate(("iae", "ise", "itae")):
                metrics[f"{what}.{names[pos]}"] = chain_out[r, z]
        for j, name in enumerate(self.mimo.input_names):
            metrics[f"effort.{name}"] = eff_out[j]
        res = SimResult(sc.name, metrics)
        if traces:
            res.t = np.arange(sc.n_steps) * sc.resolved_dt
            for pos, nm in enumerate(names):
                res.traces[f"y.{nm}"] = tr_y[pos].T
                res.traces[f"sp.{nm}"] = tr_sp[pos].T
            for j, name in enumerate(self.mimo.input_names):
                res.traces[f"u.{name}"] = tr_u[j].T
            res.traces["u"] = tr_u[0].T
        return res


_POOL_LOCK = threading.Lock()
_POOL: list = []


def _chunks(pidx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cand, chunk_start): the candidates grouped by plant, cut into chunks of at most LANES."""
    cand = np.argsort(pidx, kind="stable").astype(np.int64)
    starts: list[int] = []
    edges = np.flatnonzero(np.diff(pidx[cand])) + 1
    for lo, hi in zip(np.r_[0, edges], np.r_[edges, len(cand)], strict=True):
        starts.extend(range(int(lo), int(hi), LANES))
    return cand, np.array([*starts, len(cand)], dtype=np.int64)


def _run_threaded(args: tuple) -> None:
    """Run the kernel's chunks on :func:`~gaintune.sim.threads.sim_threads` threads (it releases the GIL)."""
    from gaintune.sim.threads import sim_threads

    n_chunks = len(args[1]) - 1
    n = min(sim_threads(), n_chunks)
    if n == 1:
        mimo_kernel(0, n_chunks, *args)
        return
    from concurrent.futures import ThreadPoolExecutor

    with _POOL_LOCK:
        if not _POOL or _POOL[0][0] != os.getpid():
            _POOL[:] = [(os.getpid(), ThreadPoolExecutor(max_workers=n, thread_name_prefix="gaintune-mimo"))]
        pool = _POOL[0][1]
    edges = [n_chunks * i // n for i in range(n + 1)]
    futures = [pool.submit(mimo_kernel, lo, hi, *args) for lo, hi in zip(edges[1:-1], edges[2:], strict=True)]
    mimo_kernel(edges[0], edges[1], *args)
    for f in futures:
        f.result()
