"""Training a tuner: TD3 (or PPO) on the per-context bandit, checkpointed, exported to NumPy, validated, saved.

:func:`train` runs a stable-baselines3 agent on :class:`gaintune.tuners.env.ContextBanditVecEnv`
(one step per episode, a fresh plant of the family per episode, the reward that plant's own
``-log(cost)`` after the boundary move). TD3, the default, learns a critic of the reward of
(context, gains) and a deterministic actor that climbs it: the actor's answer for each context
moves to that context's best gains. PPO is kept for comparison (``algo: ppo``); on the FOTD family
it places the answer less precisely for the same episodes (docs/tuners.md). After every
:attr:`TrainSettings.chunk` episodes the agent is saved (SB3's format, read back as weights only)
with the run's state and a training-curve point (and with :attr:`TrainSettings.curve_every` a point
every that many episodes, the training unchanged); a killed run given the same output folder resumes
from there. At the end the actor is exported to plain arrays (checked against torch on random
inputs), validated on held-out contexts against their own optimum, and written atomically as a
tuner folder.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from gaintune.errors import SpecError, problem_details
from gaintune.files import read_text_bounded, write_atomic
from gaintune.provenance import versions
from gaintune.tuners import artefact
from gaintune.tuners.artefact import Artefact
from gaintune.tuners.box import fit_box
from gaintune.tuners.mlp import NumpyPolicy, from_sb3
from gaintune.tuners.problems import TunerProblem
from gaintune.tuners.validation import answer_cost, context_optimum, validate

__all__ = ["TrainSettings", "train", "EXPORT_TOL"]

#: Largest difference allowed between the NumPy policy and torch's deterministic action.
EXPORT_TOL = 1e-6
#: Largest starting exploration noise of an update (the warm policy already answers near the optimum).
UPDATE_NOISE = 0.05
#: Episodes of an update from a folder without agent.zip whose gradient steps train the fresh critic only.
CRITIC_WARMUP = 512
#: Gradient steps per environment step of an update. Its actor and critic start near the answer, so each
#: simulation's data is worth more steps (they refine a nearly right model instead of fitting noise),
#: and simulations are what an update must save (docs/tuners.md, "update").
UPDATE_GRADIENT_STEPS = 128


@dataclass(frozen=True)
class TrainSettings:
    """Training settings of a tuner (defaults chosen on the FOTD family, docs/tuners.md).

    ``algo`` is ``td3`` (default: a deterministic actor on a learned reward model, which is what a
    one-step bandit needs to place the answer precisely) or ``ppo``. Exploration noise (TD3's action
    noise, PPO's policy std) is annealed geometrically from ``noise_start`` to ``noise_end`` over the
    run, so the answer settles as the policy improves. The training curve has a point at the end of every
    ``chunk`` (the checkpoint and noise-schedule step) and, with ``curve_every``, also every ``curve_every``
    episodes: a measurement only (``gaintune bench tuners --update`` reads it finely), the training is the same.
    """

    episodes: int = 36_000
    seed: int = 0
    algo: str = "td3"
    n_envs: int = 64
    contexts_per_step: int = 8
    chunk: int = 4096
    n_steps: int = 16
    noise_start: float = 0.2
    noise_end: float = 0.02
    learning_rate: float = 1e-3
    batch_size: int = 256
    gradient_steps: int = 32
    net_arch: tuple[int, ...] = (64, 64)
    critic_arch: tuple[int, ...] = (256, 256)
    validation: int = 24
    curve_contexts: int = 8
    curve_every: int | None = None

    def __post_init__(self) -> None:
        if self.algo not in ("td3", "ppo"):
            raise SpecError("algo", f"a tuner trains with td3 or ppo, not {self.algo!r}")
        if self.episodes < 1 or self.n_envs % self.contexts_per_step:
            raise SpecError("episodes", "need episodes >= 1 and n_envs a multiple of contexts_per_step")
        if self.curve_every is not None and self.curve_every < 1:
            raise SpecError("curve_every", f"episodes between curve points must be >= 1, got {self.curve_every}")

    def key(self, problem: TunerProblem) -> str:
        """Hash of what a checkpoint depends on: the problem, its box and these settings."""
        assert problem.box is not None
        d = {"problem": problem.as_dict(), "box": problem.box.as_dict(), "settings": self.__dict__}
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=list).encode()).hexdigest()[:16]

    def noise(self, done: int) -> float:
        """Exploration noise after ``done`` episodes."""
        f = min(max(done / self.episodes, 0.0), 1.0)
        return math.exp(math.log(self.noise_start) * (1 - f) + math.log(self.noise_end) * f)


def _make_agent(env: Any, s: TrainSettings) -> Any:
    import torch

    torch.set_num_threads(1)  # a 64-unit network: threads cost more than they give
    if s.algo == "ppo":
        from stable_baselines3 import PPO

        agent = PPO("MlpPolicy", env, n_steps=s.n_steps, batch_size=s.batch_size,
                    n_epochs=10, learning_rate=s.learning_rate, gamma=0.0, gae_lambda=1.0, seed=s.seed, verbose=0,
                    device="cpu", policy_kwargs={"net_arch": list(s.net_arch)})
        agent.policy.log_std.requires_grad_(False)  # annealed by the schedule instead
        return agent
    from stable_baselines3 import TD3

    # gamma 0: an episode is one step, so the critic learns the reward of (context, gains) itself
    return TD3("MlpPolicy", env, learning_rate=s.learning_rate, buffer_size=200_000,
               learning_starts=min(1024, max(s.episodes // 4, s.n_envs)),
               batch_size=s.batch_size, gamma=0.0, train_freq=1, gradient_steps=s.gradient_steps, policy_delay=2,
               target_policy_noise=0.05, target_noise_clip=0.1, seed=s.seed, verbose=0, device="cpu",
               policy_kwargs={"net_arch": {"pi": list(s.net_arch), "qf": list(s.critic_arch)}})


def _set_noise(agent: Any, s: TrainSettings, done: int) -> None:
    """Anneal the exploration noise to its value after ``done`` episodes."""
    sd = s.noise(done)
    n_act = int(agent.action_space.shape[0])
    if s.algo == "ppo":
        agent.policy.log_std.data[:] = math.log(sd)
    else:
        from stable_baselines3.common.noise import NormalActionNoise

        agent.action_noise = NormalActionNoise(np.zeros(n_act), sd * np.ones(n_act))


class _Checkpoint:
    """The resumable state of a run: ``<out>.training/agent.zip`` and ``state.json``."""

    def __init__(self, out: Path, key: str) -> None:
        self.dir = out.with_name(f".{out.name}.training")
        self.key = key

    def damaged(self, why: str) -> SpecError:
        """The error of a checkpoint that cannot be resumed: what is wrong, and the two ways out."""
        return SpecError("resume", f"the checkpoint {self.dir} is damaged ({why}); delete that folder, or start "
                         "afresh without resuming (gaintune tuner train --no-resume)")

    def load(self) -> dict[str, Any] | None:
        """The saved state of this run; None when there is none or it is another problem's or settings' run.

        Raises
        ------
        SpecError
            Naming ``resume``: the checkpoint is damaged (:meth:`damaged`).
        """
        path = self.dir / "state.json"
        if not path.exists():  # no checkpoint yet (a run killed before its first state was written)
            return None
        try:
            state = json.loads(read_text_bounded(path, "resume"))
        except SpecError as exc:
            raise self.damaged(exc.message) from None
        except (ValueError, RecursionError):  # not JSON (RecursionError: nested too deep to read)
            raise self.damaged("state.json is not JSON") from None
        if not isinstance(state, dict) or not isinstance(state.get("key"), str):
            raise self.damaged("state.json is not a training state: no run key")
        if state["key"] != self.key:  # another run's: this one starts afresh and replaces it
            return None
        why = _state_problem(state)
        if why:
            raise self.damaged(f"state.json: {why}")
        return state

    def save(self, agent: Any, state: dict[str, Any]) -> None:
        from gaintune.search.agent_file import save_agent

        self.dir.mkdir(parents=True, exist_ok=True)
        save_agent(agent, self.dir / "agent.zip")
        write_atomic(self.dir / "state.json", json.dumps({**state, "key": self.key}))

    def clear(self) -> None:
        import shutil

        shutil.rmtree(self.dir, ignore_errors=True)


_Count = Annotated[int, Field(ge=0, strict=True)]  # strict: JSON's true and false are not counts
_Number = Annotated[float, Field(strict=True)]  # a JSON number (an int too), not a bool or a string


class _SavedPoint(BaseModel):
    """One training-curve point as a checkpoint saves it (its figures may be NaN or null: recorded only)."""

    model_config = ConfigDict(extra="allow")
    episodes: _Count
    sims: _Count
    elapsed_s: Annotated[_Number, Field(allow_inf_nan=False)]
    reward: _Number | None = None
    median_ratio: _Number | None = None


class _SavedState(BaseModel):
    """The fields of a checkpoint's state.json that a resumed run reads and records."""

    model_config = ConfigDict(extra="allow")
    episodes: _Count
    sims: _Count
    elapsed_s: Annotated[_Number, Field(ge=0, allow_inf_nan=False)]
    resumed: _Count = 0
    curve: list[_SavedPoint]


def _state_problem(state: Mapping[str, Any]) -> str:
    """What is wrong with a saved training state ('' when nothing): its first field that does not validate."""
    try:
        _SavedState.model_validate(state)
    except ValidationError as exc:
        first = problem_details(exc)[0]
        return f"{first['loc']}: {first['msg']}"
    return ""


def _curve_point(problem: TunerProblem, policy: NumpyPolicy, curve_set: list[tuple[dict[str, float], float]]
                 ) -> float:
    """Median cost / optimum of the policy on the fixed curve contexts."""
    ratios = [answer_cost(problem, policy, ctx)[0] / opt for ctx, opt in curve_set]
    return float(np.median(ratios))


def _exported(agent: Any, n_in: int, seed: int) -> NumpyPolicy:
    """The actor as arrays, checked against torch's deterministic action on random inputs."""
    pol = from_sb3(agent)
    x = np.random.default_rng(seed).uniform(-1.5, 1.5, (256, n_in)).astype(np.float32)
    ref = agent.predict(x, deterministic=True)[0]
    err = float(np.max(np.abs(pol(x) - ref)))
    if err > EXPORT_TOL:
        raise RuntimeError(f"the NumPy policy differs from torch's by {err:.2e} (> {EXPORT_TOL:g})")
    return pol


def train(problem: TunerProblem, out: str | Path, settings: TrainSettings | None = None, *, name: str | None = None,
          on_progress: Callable[[int, int, dict[str, Any]], None] | None = None, resume: bool = True,
          warm_start: str | Path | None = None, keep_agent: bool = True) -> Path:
    """Train a tuner for ``problem`` and write it to the folder ``out``; returns ``out``.

    ``on_progress(done, total, info)`` is called after every rollout (episodes done, episodes in
    all, and ``{"reward", "sims", "elapsed_s", "ratio"}``; ``ratio`` at checkpoints). With
    ``resume`` a checkpoint of the same problem and settings in ``.<out>.training`` is continued.
    ``warm_start`` is a tuner folder whose agent and gain box the training continues from
    (``gaintune tuner update``): same gains and number of context values, a changed family. A folder
    without ``agent.zip`` (the shipped tuners, kept small) gives its actor from ``policy.npz`` and its
    critic from ``critic.npz`` (a folder without either starts a fresh critic, trained alone first).
    ``keep_agent`` writes ``agent.zip`` into the tuner folder; a TD3 tuner always gets ``critic.npz``.
    """
    s = settings or TrainSettings()
    if warm_start is not None:  # the policy already answers: explore near it, learn more from each simulation
        s = dataclasses.replace(s, noise_start=min(s.noise_start, UPDATE_NOISE),
                                gradient_steps=max(s.gradient_steps, UPDATE_GRADIENT_STEPS))
    out = artefact.check_out(out)  # before the training: a folder it must not replace is refused now, not after
    env, agent, warmup = _setup(problem, s, warm_start)
    ckpt = _Checkpoint(out, s.key(problem))
    state = _start_state(ckpt, agent, env, s, resume)
    curve_set = _curve_set(problem, s)
    if not state["curve"]:  # where the run starts (a warm start's policy, or an untrained one)
        state["curve"].append({"episodes": 0, "sims": 0, "elapsed_s": 0.0, "reward": None,
                               "median_ratio": _curve_point(problem, from_sb3(agent), curve_set)})
    watch = _CurveWatch(problem, curve_set, state, env, s.curve_every)
    t0, base = time.perf_counter(), float(state["elapsed_s"])
    while state["episodes"] < s.episodes:
        chunk = min(s.chunk, s.episodes - int(state["episodes"]))
        if state["episodes"] < warmup:
            chunk = min(chunk, warmup - int(state["episodes"]))
        # a random critic would drag a trained actor off its answer: hold the actor until the critic has data
        if hasattr(agent, "policy_delay"):
            agent.policy_delay = 10**9 if state["episodes"] < warmup else 2
        _set_noise(agent, s, int(state["episodes"]))
        agent.learn(chunk, reset_num_timesteps=False,
                    callback=_progress_callback(on_progress, state, env, s, (t0, base), watch))
        state.update(episodes=int(agent.num_timesteps), sims=env.n_sims, elapsed_s=base + time.perf_counter() - t0)
        point = watch.add(agent, state["elapsed_s"])
        if on_progress:
            on_progress(int(state["episodes"]), s.episodes, {**point, "ratio": point["median_ratio"]})
        ckpt.save(agent, state)
    _write_artefact(out, name or out.name, problem, agent, s, state, warm_start, keep_agent)
    ckpt.clear()
    return out


def _setup(problem: TunerProblem, s: TrainSettings, warm_start: str | Path | None) -> tuple[Any, Any, int]:
    """(environment, agent, warm-up episodes): the gain box fitted (or taken from ``warm_start``) and the agent
    made, a warm start's actor and critic loaded. The warm-up episodes train the critic only (a fresh critic
    beside a trained actor)."""
    from gaintune.tuners.env import ContextBanditVecEnv

    if warm_start is None:
        fit_box(problem)
    else:
        _warm_box(problem, warm_start)
    env = ContextBanditVecEnv(problem, s.n_envs, s.contexts_per_step, seed=s.seed)
    agent = _make_agent(env, s)
    warmup = 0
    if warm_start is not None:
        warmup = _warm_agent(agent, Path(warm_start))
        agent.num_timesteps = 0
        if hasattr(agent, "learning_starts"):  # the actor already answers: no random warm-up episodes
            agent.learning_starts = s.n_envs
    return env, agent, warmup


def _start_state(ckpt: _Checkpoint, agent: Any, env: Any, s: TrainSettings, resume: bool) -> dict[str, Any]:
    """The run's state: a checkpoint's (its agent loaded, fresh contexts after its resume point) or a new one."""
    from gaintune.search.agents import load_weights

    if ckpt.dir.exists() and not ckpt.dir.is_dir():  # with or without resuming: the checkpoint is saved there
        raise SpecError("resume", f"{ckpt.dir} is not a folder, and the run saves its checkpoint there; delete it")
    state = ckpt.load() if resume else None
    if state is not None:
        try:
            load_weights(agent, ckpt.dir / "agent.zip", field="resume")
        except SpecError:  # its own advice (give the agent.zip a tune wrote) does not fit a checkpoint
            raise ckpt.damaged("its agent.zip is missing or cannot be loaded as this run's agent") from None
        env.rng = np.random.default_rng([s.seed, int(state["episodes"])])  # fresh contexts after the resume point
        env.n_sims = int(state["sims"])
    state = state or {"episodes": 0, "sims": 0, "elapsed_s": 0.0, "curve": [], "resumed": 0}
    state["resumed"] = state.get("resumed", 0) + (1 if state["episodes"] else 0)
    return state


def _write_artefact(out: Path, name: str, problem: TunerProblem, agent: Any, s: TrainSettings,
                    state: Mapping[str, Any], warm_start: str | Path | None, keep_agent: bool) -> None:
    """The exported policy validated on held-out contexts, and the tuner folder written (atomically)."""
    policy = _exported(agent, len(problem.variables), s.seed)
    val = validate(problem, policy, s.validation, s.seed)
    training = {"algo": s.algo, "settings": {**s.__dict__, "net_arch": list(s.net_arch),
                             "critic_arch": list(s.critic_arch)},
                "episodes": int(state["episodes"]), "sims": int(state["sims"]),
                "wall_s": round(float(state["elapsed_s"]), 1), "resumed": int(state["resumed"]),
                "curve": state["curve"]}
    if warm_start is not None:
        training["warm_start"] = str(warm_start)
    art = Artefact(name, problem, policy, training, val,
                   meta={"versions": versions(), "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())},
                   files=_files(agent, keep_agent))
    artefact.save(out, art)


def _files(agent: Any, keep_agent: bool) -> dict[str, bytes]:
    """The files beside the policy: the critic's arrays (TD3), and the agent when it is kept."""
    from gaintune.tuners.critic import FILE, critic_bytes

    crit = critic_bytes(agent)
    files = {FILE: crit} if crit is not None else {}
    if keep_agent:
        files["agent.zip"] = _agent_bytes(agent)
    return files


def _warm_agent(agent: Any, folder: Path) -> int:
    """Start ``agent`` from the tuner at ``folder``; returns the episodes whose gradient steps train the critic only.

    The folder's agent when it has one (``agent.zip``); else its actor from ``policy.npz`` and its critic
    from ``critic.npz`` (the shipped tuners); else the actor alone, and a fresh critic trained alone for
    :data:`CRITIC_WARMUP` episodes first (a random critic would drag the trained actor off its answer).
    """
    from gaintune.search.agents import load_weights
    from gaintune.tuners.critic import install_critic, read_critic

    if (folder / "agent.zip").is_file():
        load_weights(agent, folder / "agent.zip", field="tuner")
        return 0
    _actor_from(agent, artefact.load(folder).policy)
    crit = read_critic(folder, artefact.critic_sha256(folder))
    if crit is None:
        return CRITIC_WARMUP
    install_critic(agent, crit)
    return 0


def _agent_bytes(agent: Any) -> bytes:
    """The agent in SB3's zip format (read back as weights only by ``update``)."""
    import tempfile

    from gaintune.search.agent_file import save_agent

    with tempfile.TemporaryDirectory() as tmp:
        return save_agent(agent, Path(tmp) / "agent.zip").read_bytes()


def _actor_from(agent: Any, policy: NumpyPolicy) -> None:
    """Put the NumPy policy's weights into the agent's actor (and its target): a warm start without agent.zip."""
    import torch

    if not hasattr(agent.policy, "actor"):
        raise SpecError("tuner", "a tuner without agent.zip warm-starts a TD3 agent only")
    for mu in (agent.policy.actor.mu, agent.policy.actor_target.mu):
        layers = [m for m in mu if isinstance(m, torch.nn.Linear)]
        if [tuple(m.weight.shape) for m in layers] != [w.shape for w in policy.weights]:
            raise SpecError("tuner", "the tuner's policy layers do not fit this agent's actor; retrain it")
        with torch.no_grad():
            for m, w, b in zip(layers, policy.weights, policy.biases, strict=True):
                m.weight.copy_(torch.as_tensor(w, dtype=m.weight.dtype))
                m.bias.copy_(torch.as_tensor(b, dtype=m.bias.dtype))


def _warm_box(problem: TunerProblem, folder: str | Path) -> None:
    """Give ``problem`` the gain box of the tuner at ``folder`` (its policy's actions mean the same gains)."""
    old = artefact.load(artefact.resolve(folder))
    assert old.problem.box is not None
    was, now = [v.name for v in old.problem.variables], [v.name for v in problem.variables]
    if was != now:  # the same count was not enough: K swapped for tau trained the policy's K input on tau
        raise SpecError("spec.randomize", f"the tuner at {folder} varies {', '.join(was)}, this family "
                        f"{', '.join(now)}; update needs the same varying parameters, in that order")
    box = old.problem.box
    problem.box = None  # the gains its own spec tunes, before the old box bounds them
    slots = problem.tuned_slots()
    if set(slots) != set(box.slots):  # checked before the box is used: a PI box on a PID spec broke its shapes
        raise SpecError("spec.loops", f"the tuner at {folder} tunes {', '.join(f'{lp}.{g}' for lp, g in box.slots)}; "
                        f"this spec {', '.join(f'{lp}.{g}' for lp, g in slots)}")
    problem.box = box



def _curve_set(problem: TunerProblem, s: TrainSettings) -> list[tuple[dict[str, float], float]]:
    """Fixed contexts for the training curve, with their optimum (drawn apart from training and validation)."""
    from gaintune.evaluation.evaluator import Evaluator

    rng = np.random.default_rng([s.seed, 7])
    out = []
    for ctx in problem.draw(rng, s.curve_contexts):
        opt, _ = context_optimum(Evaluator(problem.spec_at(ctx)))
        if math.isfinite(opt) and opt > 0:
            out.append((ctx, opt))
    return out


class _CurveWatch:
    """Training-curve points: at the end of each chunk and, with ``curve_every``, whenever the episodes
    cross a multiple of it (taken as the next rollout starts, so after the last one's gradient steps)."""

    def __init__(self, problem: TunerProblem, curve_set: list[tuple[dict[str, float], float]],
                 state: dict[str, Any], env: Any, every: int | None) -> None:
        self.problem, self.curve_set, self.state, self.env, self.every = problem, curve_set, state, env, every

    def add(self, agent: Any, elapsed_s: float) -> dict[str, Any]:
        """Append the point of ``agent`` now (its episodes, the simulations so far) unless it has one; return it.

        The policy is scored as NumPy arrays on the fixed curve contexts: no random number is drawn, so the
        points never change the training (``test_curve_points_draw_no_random_numbers_the_training_uses``)."""
        curve = self.state["curve"]
        if curve and curve[-1]["episodes"] == int(agent.num_timesteps):
            return curve[-1]
        curve.append({"episodes": int(agent.num_timesteps), "sims": int(self.env.n_sims),
                      "elapsed_s": round(elapsed_s, 2), "reward": self.env.last.get("reward"),
                      "median_ratio": _curve_point(self.problem, from_sb3(agent), self.curve_set)})
        return curve[-1]

    def passed(self, agent: Any, elapsed_s: float) -> None:
        """Add a point when the episodes have crossed a multiple of ``curve_every`` since the last point (the
        curve always has one: the run's start, or the checkpoint's)."""
        last = int(self.state["curve"][-1]["episodes"])
        if self.every and int(agent.num_timesteps) // self.every > last // self.every:
            self.add(agent, elapsed_s)


def _progress_callback(on_progress: Any, state: dict[str, Any], env: Any, s: TrainSettings,
                       clock: tuple[float, float], watch: _CurveWatch) -> Any:
    from stable_baselines3.common.callbacks import BaseCallback

    t0, base = clock

    class _Cb(BaseCallback):
        def _on_step(self) -> bool:
            return True

        def _on_rollout_start(self) -> None:  # after the last rollout's gradient steps
            watch.passed(self.model, base + time.perf_counter() - t0)

        def _on_rollout_end(self) -> None:  # every env step for TD3, every rollout for PPO
            if on_progress:
                on_progress(int(self.model.num_timesteps), s.episodes,
                            {"reward": env.last.get("reward"), "sims": env.n_sims,
                             "elapsed_s": base + time.perf_counter() - t0})

    return _Cb()
