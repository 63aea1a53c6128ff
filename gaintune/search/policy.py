"""A trained tuner: the saved policy answers gains for a plant in its training range, verified, in milliseconds.

A search with domain randomisation (``randomize.params``) trains a policy whose input is the
plant's parameters, normalised to the training ranges (:func:`gaintune.sim.draws.context`). Kept
with the spec it was trained on, that policy gives gains for another plant of the same family
without a new search: instant gains for a new plant, and, over a grid of parameters, a gain
schedule. :class:`PolicyTuner` loads the agent and the training problem once; each
:meth:`PolicyTuner.answer` then maps the parameters to the policy's gains, moves them onto the
requirement boundary as the search did (:mod:`gaintune.evaluation.boundary_estimate`), and verifies them on the plant
at those parameters. As everywhere in gaintune, only a ``pass`` releases the gains
(:attr:`PolicyAnswer.accepted_gains`).

The action is read in the training search box (the box of the training spec's nominal plant),
so the policy means what it meant when it was trained.
"""

from __future__ import annotations

import json
import math
import threading
import time
from pathlib import Path

import numpy as np

from gaintune.envs.problem import GainProblem
from gaintune.envs.vec import BatchedGainVecEnv
from gaintune.errors import SpecError
from gaintune.evaluation.boundary_estimate import onto_boundary_estimate
from gaintune.evaluation.evaluator import Evaluator
from gaintune.plants import build_plant
from gaintune.search.agents import load_agent
from gaintune.search.result import PolicyAnswer
from gaintune.sim import Simulator
from gaintune.sim import draws as draws_mod
from gaintune.spec import RandomizeSpec, TuningSpec, load_spec
from gaintune.verification import verify

__all__ = ["PolicyAnswer", "PolicyTuner"]


class PolicyTuner:
    """A saved agent and the spec it was trained on, loaded once.

    Parameters
    ----------
    agent_path
        The ``agent.zip`` a tune wrote (``gaintune tune --out DIR``).
    spec
        The spec it was trained on (``DIR/result.json`` holds it; :meth:`from_run` reads both).

    Raises
    ------
    SpecError
        Naming ``agent``: the file is missing, not an agent, needs unpickling (refused: agent files are
        read as weights only, :mod:`gaintune.search.agent_file`), or its agent was trained on other gains
        or context values, or by another algorithm than ``spec.search.algo``.
    """

    def __init__(self, agent_path: str | Path, spec: TuningSpec) -> None:
        self.spec = spec
        self.problem = GainProblem(spec)  # the training box: the search box is a function of the spec
        # the spec's agent with the file's weights, read as weights only: nothing in the file is executed
        env = BatchedGainVecEnv(self.problem, spec.search.n_envs, seed=spec.search.seed)
        self.agent = load_agent(agent_path, spec, env, field="agent")
        self.ranges = {name: d.box for name, d in spec.randomize.params.items()}
        self._lock = threading.Lock()  # one answer at a time: SB3's predict switches the policy's mode

    @classmethod
    def from_run(cls, folder: str | Path) -> PolicyTuner:
        """Load ``folder/agent.zip`` with the spec of ``folder/result.json`` (a ``gaintune tune --out`` folder)."""
        folder = Path(folder)
        try:
            data = json.loads((folder / "result.json").read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise SpecError("run", f"{folder} holds no readable result.json ({type(exc).__name__}); give the folder "
                            "a 'gaintune tune --out' wrote") from None
        if not isinstance(data, dict) or not isinstance(data.get("spec"), dict):
            raise SpecError("run", f"{folder / 'result.json'} is not a gaintune result (no spec)")
        return cls(folder / "agent.zip", load_spec(data["spec"]))

    def spec_at(self, params: dict[str, float]) -> TuningSpec:
        """The training spec with its nominal plant parameters replaced by ``params`` (names checked)."""
        for name, value in params.items():
            if name not in self.ranges:
                known = sorted(self.ranges) or "none"
                raise SpecError(f"params.{name}", f"not a parameter the policy was trained over "
                                f"(randomize.params: {known}); it cannot say how {name!r} changes the gains")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise SpecError(f"params.{name}", f"must be a finite number, got {value!r}")
        data = self.spec.model_dump(mode="json")
        data["plant"]["params"] = {**data["plant"].get("params", {}), **{k: float(v) for k, v in params.items()}}
        return TuningSpec.model_validate(data)

    def answer(self, params: dict[str, float] | None = None) -> PolicyAnswer:
        """The policy's gains for the plant at ``params`` (unnamed parameters keep their nominal values), verified
        there."""
        t0 = time.perf_counter()
        spec = self.spec_at(params or {})
        try:
            plant = build_plant(spec.plant)
        except SpecError as exc:  # e.g. T = 0 drops the plant's order: say which parameters did it
            raise SpecError("params", f"the plant at {params} cannot be built: {exc}") from None
        layout = self.problem.layout
        obs = draws_mod.context(self.spec, plant, draws_mod.nominal(spec, plant, 1))  # the training ranges normalise
        with self._lock:
            action = np.asarray(self.agent.predict(obs, deterministic=True)[0], dtype=float).reshape(-1)
        # the answer is for this one plant: its requirements hold on it, not over the training family
        spec = spec.model_copy(update={"randomize": RandomizeSpec()})
        tuned = layout.action_to_tuned(action)[None, :]
        if spec.search.repair:  # scored as the search scored its samples: on the boundary of this plant
            tuned = onto_boundary_estimate(Evaluator(spec, Simulator(spec, plant, layout)), tuned).tuned
        gains = layout.to_dict(layout.full(tuned[0]))
        report = verify(spec, gains, plant=plant, layout=layout, cache=False)
        values = dict(zip(plant.param_names, map(float, plant.param_vector()), strict=True))
        outside = [n for n, (lo, hi) in self.ranges.items() if not lo <= values[n] <= hi]
        return PolicyAnswer(params={n: values[n] for n in self.ranges},
                            gains=gains, verification=report, outside=outside,
                            elapsed_ms=1e3 * (time.perf_counter() - t0))

    def schedule(self, grid: dict[str, list[float]], max_points: int | None = None) -> list[PolicyAnswer]:
        """One answer per point of the product of ``grid`` (parameter -> values): a gain schedule.

        Raises SpecError naming ``params.<name>`` for a value that is no number, and ``params`` for a
        grid of more than ``max_points`` points."""
        names = list(grid)
        axes = []
        for n in names:
            try:
                axes.append(np.atleast_1d(np.asarray(grid[n], dtype=float)))
            except (TypeError, ValueError):
                raise SpecError(f"params.{n}", f"values must be numbers, got {grid[n]!r}") from None
        count = int(np.prod([a.size for a in axes])) if axes else 1
        if max_points is not None and count > max_points:
            raise SpecError("params", f"the grid has {count:,} points, more than {max_points:,}; give fewer values")
        if not names:
            return [self.answer()]
        points = np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(names), -1).T
        return [self.answer(dict(zip(names, map(float, p), strict=True))) for p in points]
