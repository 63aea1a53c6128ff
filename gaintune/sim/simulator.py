"""The :class:`Simulator`: B gain sets (each with its own draw) in one compiled call.

Example
-------
>>> from gaintune.spec import load_spec
>>> from gaintune.sim import Simulator
>>> spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}]})
>>> sim = Simulator(spec)
>>> res = sim.run(sim.layout.full([[1.14, 0.454]]))
>>> round(float(res.metrics["iae"][0]), 2) > 0
True
"""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np

from gaintune.classical.timescale import resolve_scenarios
from gaintune.controllers.layout import GainLayout
from gaintune.plants.plant import Plant, build_plant, is_mimo_plant
from gaintune.sim import draws as draws_mod
from gaintune.sim.build import SimSetup
from gaintune.sim.draws import Draws
from gaintune.sim.kernel import METRICS, run_kernel
from gaintune.sim.kernel_args import KernelArgs
from gaintune.sim.result import SimResult
from gaintune.spec import ScenarioSpec, TuningSpec
from gaintune.spec.mimo import is_graph

__all__ = ["Simulator", "SimResult", "KernelArgs", "METRICS", "simulate", "needs_mimo"]


def needs_mimo(spec: TuningSpec, plant) -> bool:
    """Whether ``spec`` on ``plant`` runs on the MIMO simulator (:mod:`gaintune.sim.mimo`).

    It does for a MIMO plant, or loops that say what they drive;
    ``plant`` None asks the spec alone. Here, not in :mod:`gaintune.sim.mimo`: a single-input
    problem does not import the MIMO simulator.
    """
    return (is_mimo_plant(plant) or is_graph(spec) or spec.actuators is not None
            or spec.decoupler is not None or spec.feedforward is not None
            or any(sc.disturbance.state is not None for sc in spec.scenarios))


class Simulator:
    """Compiled closed-loop simulator for one spec.

    Parameters
    ----------
    spec
        The tuning problem. Scenarios without ``dt``/``horizon`` get them from the plant
        (:func:`gaintune.classical.timescale.resolve_scenarios`); :attr:`spec` is that resolved spec.
    plant, layout
        Reuse already-built objects (optional).
    """

    def __new__(cls, spec: TuningSpec, plant: Plant | None = None, layout: GainLayout | None = None) -> Any:
        # the one dispatch: several inputs, or loops wired as a graph, run on the MIMO simulator, which
        # has this interface (gaintune.sim.mimo); every caller (evaluator, search, API) stays as it is
        if cls is Simulator:
            built = plant if plant is not None else build_plant(spec.plant)
            if needs_mimo(spec, built):
                from gaintune.sim.mimo import MimoSimulator

                return MimoSimulator(spec, built, layout)
            obj = super().__new__(cls)
            obj._built = built  # type: ignore[attr-defined]  # read once by __init__
            return obj
        return super().__new__(cls)

    def __init__(self, spec: TuningSpec, plant: Plant | None = None, layout: GainLayout | None = None) -> None:
        plant = plant or getattr(self, "_built", None)
        self.plant = plant or build_plant(spec.plant)
        self.spec = spec = resolve_scenarios(spec, self.plant)
        self.layout = layout or GainLayout(spec, self.plant.states)
        self.setup = SimSetup.build(spec, self.plant, self.layout)
        self._memo: dict = {}
        self._single: dict = {}  # (draw set and scenario, gains) -> kernel output of one untraced candidate

    def nominal_draws(self, n: int = 1) -> Draws:
        return draws_mod.nominal(self.spec, self.plant, n, seed=self.spec.search.seed)

    def _prepared(self, d: Draws, sc: ScenarioSpec) -> dict:
        """Everything the kernel needs that does not depend on the gains, memoised per draw set.

        Optimisers and the RL environment re-use the same draws call after
        call, so the plant, signal and limit arrays are built once per draw set.
        """
        h = hashlib.blake2b(digest_size=16)
        for name in Draws.__dataclass_fields__:
            h.update(np.ascontiguousarray(getattr(d, name)).tobytes())
        key = (h.hexdigest(), sc.model_dump_json())
        return self._memoised(key, lambda: {**self._prepare(d, sc), "key": key})

    def _memoised(self, key: tuple, build) -> dict:
        """The prepared arguments under ``key``, built on a miss (the memo is bounded)."""
        hit = self._memo.get(key)
        if hit is None:
            if len(self._memo) > 64:
                self._memo.clear()
            hit = self._memo[key] = build()
        return hit

    def _prepare(self, d: Draws, sc: ScenarioSpec) -> dict:
        """The gain-independent kernel arguments of one draw set and scenario.

        ``fields`` holds them by :class:`KernelArgs` field name; ``pa`` keeps the
        plant arrays the controller arrays are built from (the linear models); :meth:`_prepared`
        adds ``key``, the draw set's and scenario's content key.
        """
        pb, spec = self.setup, self.spec
        pa, sg = pb.plant_arrays(d, sc), pb.signal_arrays(d, sc)
        act = spec.actuator
        lo, hi = act.limits if act.limits is not None else (-np.inf, np.inf)
        xb = np.full(self.plant.order, np.inf)
        for name, bound in spec.safety.state_bounds.items():
            xb[self.plant.states.index(name)] = bound
        meas = np.array(pb.meas, dtype=np.int64)
        f, h = pb.f_tape, pb.h_tape
        empty = np.zeros(0, dtype=np.int64)
        B, L = len(d), len(spec.loops)
        fields = dict(
            n_steps=sc.n_steps, dt=sc.dt, nonlinear=f is not None,
            Ad=pa["Ad"], G0=pa["G0"], G1=pa["G1"], Cm=pa["Cm"], Dm=pa["Dm"],
            f_op=f.op if f else empty, f_a=f.a if f else empty, f_b=f.b if f else empty, f_o=f.o if f else empty,
            f_c=f.c if f else np.zeros(0), f_nw=f.n_work if f else 1,
            h_op=h.op if h else empty, h_a=h.a if h else empty, h_b=h.b if h else empty, h_o=h.o if h else empty,
            h_c=h.c if h else np.zeros(0), h_nw=h.n_work if h else 1, h_nout=h.n_out if h else 1,
            P=np.ascontiguousarray(d.params.T) if f is not None else np.zeros((0, B)),
            meas_idx=meas,
            x_op=pa["x_op"], u_op=pa["u_op"], y_op=pa["y_op"], dsteps=pa["dsteps"],
            u_lo=np.where(np.isfinite(lo), lo * d.act_scale, -np.inf),
            u_hi=np.where(np.isfinite(hi), hi * d.act_scale, np.inf),
            rate=act.rate_limit if act.rate_limit is not None else np.inf,
            sk0=sg["sk0"], sk1=sg["sk1"], soff=sg["soff"], sslope=sg["sslope"],
            dist_out_loops=(meas == meas[0]).astype(float),
            noise_std=np.full(B, sc.noise_std), noise_seed=d.noise_seed,
            max_err=spec.safety.max_abs_error or np.inf, max_out=spec.safety.max_abs_output or np.inf, xbound=xb,
            div_bound=spec.safety.divergence_bound, safe_mode=1 if spec.safety.action == "fallback" else 0,
            u_safe=act.safe_value,
            target=sg["target"] + pa["y_op"][0], k_step=sg["k_step"], k_load=sg["k_load"],
            # no traces: zero-size arrays, shared by every call on this draw set
            want_traces=False, tr_y=np.zeros((L, 0, B)), tr_sp=np.zeros((L, 0, B)), tr_u=np.zeros((0, B)),
        )
        return dict(pa=pa, fields=fields)

    def kernel_args(
        self,
        full_gains: np.ndarray,
        draws: Draws | None = None,
        scenario: ScenarioSpec | int = 0,
        traces: bool = False,
    ) -> KernelArgs:
        """The kernel's arguments for B full gain vectors on one scenario, exactly as :meth:`run` passes them.

        Parameters
        ----------
        full_gains
            (B, n_gains) full gain vectors (see :meth:`GainLayout.full`), or one vector.
        draws
            Each candidate's plant sample and signals (default: nominal).
        scenario
            Index into ``spec.scenarios``, or a scenario.
        traces
            Allocate trace arrays and ask the kernel to fill them.

        Returns
        -------
        KernelArgs
            Run it with :func:`gaintune.sim.kernel.run_kernel`. The gain-independent
            arrays are shared with later calls on the same draws: treat them as read-only.
        """
        full = np.atleast_2d(np.asarray(full_gains, dtype=float))
        prep = self._prep(full.shape[0], draws, scenario)
        return self._args(full, prep, traces)

    def _prep(self, B: int, draws: Draws | None, scenario: ScenarioSpec | int) -> dict:
        """The prepared gain-independent arguments of B candidates on ``draws`` (default nominal) and a scenario."""
        sc = self.spec.scenarios[scenario] if isinstance(scenario, int) else scenario
        if draws is None and isinstance(scenario, int):
            # nominal draws: keyed without hashing them (the single-simulation case)
            # ... and shared with the same draws passed explicitly (an evaluator's nominal draws)
            return self._memoised(("nominal", B, scenario), lambda: self._prepared(self.nominal_draws(B), sc))
        d = draws if draws is not None else self.nominal_draws(B)
        if len(d) != B:
            raise ValueError(f"draws has {len(d)} rows for {B} gain sets")
        return self._prepared(d, sc)

    def _args(self, full: np.ndarray, prep: dict, traces: bool) -> KernelArgs:
        """The kernel's arguments: ``prep`` (:meth:`_prep`) with the controller arrays of ``full``."""
        B = full.shape[0]
        pb = self.setup
        ca = pb.controller_arrays(full, prep["pa"])
        args = KernelArgs.from_fields(prep["fields"], ca, pb.fallback_arrays(B, ca, prep["pa"]))
        return args.with_traces() if traces else args

    def _run_one(self, full: np.ndarray, prep: dict) -> np.ndarray:
        """The kernel's output for one untraced candidate, memoised on its draw set, scenario and gains.

        A tuner's answer simulates the gains it returns twice on this simulator: the boundary move's cost
        comparison, then the verification's nonlinear check on the same nominal draw. The kernel is
        deterministic (noise comes from the draw's seed), so the second is the first's output (a copy).
        """
        key = (prep["key"], full.tobytes())
        hit = self._single.get(key)
        if hit is None:
            if len(self._single) > 16:
                self._single.clear()
            hit = self._single[key] = run_kernel(self._args(full, prep, False))
        return hit.copy()

    def run(
        self,
        full_gains: np.ndarray,
        draws: Draws | None = None,
        scenario: ScenarioSpec | int = 0,
        traces: bool = False,
    ) -> SimResult:
        """Simulate B full gain vectors (B, n_gains) on one scenario.

        ``draws`` gives each candidate its plant sample and signals (default:
        nominal). Diverging candidates are flagged, never raised.
        """
        full = np.atleast_2d(np.asarray(full_gains, dtype=float))
        sc = self.spec.scenarios[scenario] if isinstance(scenario, int) else scenario
        prep = self._prep(full.shape[0], draws, scenario)
        if not traces and full.shape[0] == 1:
            out = self._run_one(full, prep)
        else:
            args = self._args(full, prep, traces)
            out = run_kernel(args)
        metrics = {name: out[i] for i, name in enumerate(METRICS)}
        metrics["diverged"] = metrics["diverged"].astype(bool)
        metrics["tripped"] = metrics["tripped"].astype(bool)
        res = SimResult(sc.name, metrics)
        if traces:
            res.t = np.arange(args.n_steps) * sc.resolved_dt
            names = [lp.name for lp in self.spec.loops]
            for i, nm in enumerate(names):
                res.traces[f"y.{nm}"] = args.tr_y[i].T
                res.traces[f"sp.{nm}"] = args.tr_sp[i].T
            res.traces["u"] = args.tr_u.T
        return res


def simulate(
    spec: TuningSpec, full_gains: np.ndarray, draws: Draws | None = None, traces: bool = False
) -> list[SimResult]:
    """Simulate every scenario of ``spec`` for a batch of full gain vectors."""
    sim = Simulator(spec)
    return [sim.run(full_gains, draws, i, traces) for i in range(len(spec.scenarios))]
