"""stable-baselines3 agents with defaults tuned for gain search.

Gain search with one-step episodes is a contextual bandit: each episode is
one gain set scored once. The defaults below follow from that:

* updates after every batched call (``n_steps=1`` per env, so one rollout is
  ``n_envs`` episodes) and several epochs on it - sample efficiency matters,
  simulations are the budget;
* ``gamma`` is irrelevant (episodes are one step) and the value function is a
  baseline of the context only;
* the policy mean starts at action 0, the classical-rule centre of the
  log-gain bounds, with a moderate exploration std that the policy gradient
  then shrinks (PPO), or with entropy tuning (SAC);
* small tanh networks: with no randomisation the observation is constant and
  the policy mean is effectively a free vector; with randomisation it is a
  smooth function of the context.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import stable_baselines3
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.preprocessing import get_action_dim
from stable_baselines3.common.save_util import recursive_getattr
from stable_baselines3.common.vec_env import VecEnv

from gaintune.errors import SpecError
from gaintune.search.agent_file import load_module_state, load_optimizer_state, load_variables, read_agent_file
from gaintune.search.algos import ALGO_NAMES
from gaintune.search.eager_optim import install as _install_eager_optim
from gaintune.search.eager_optim import optimizer_class as _eager_optimizer_class
from gaintune.spec import TuningSpec

__all__ = ["ALGOS", "agent_defaults", "exploration_log_std", "make_agent", "load_agent", "load_weights"]

# The batched simulator owns the cores. torch's intra-op pool on top of numba's made each
# PPO update 16x slower (measured: a 200-simulation search took 11.4 s instead of 0.7 s).
# Changing the count per call rebuilds the pool, so it is set once, here.
torch.set_num_threads(int(os.environ.get("GAINTUNE_TORCH_THREADS", "1")))

#: Replay-buffer cap of the off-policy agents (SB3's own default size): a buffer holds every step
#: of the search up to this, the oldest are overwritten beyond it.
REPLAY_MAX = 1_000_000

#: The stable-baselines3 class of every algorithm name (:data:`gaintune.search.algos.ALGO_NAMES`).
ALGOS: dict[str, type[BaseAlgorithm]] = {name: getattr(stable_baselines3, name.upper()) for name in ALGO_NAMES}


#: Gain count up to which the policy's initial exploration is ``log_std_init = -1`` (a PID loop has 3).
EXPLORATION_DIM = 3


def exploration_log_std(dim: int) -> float:
    """Initial log std of the Gaussian policy for ``dim`` tuned gains: -1 up to :data:`EXPLORATION_DIM` gains,
    then 0.25 less per doubling of the gain count (-1.5 at 12 gains).

    With e^-1 (a factor 3.5 on each gain) every one of 32 samples of the six-loop cascade's 12 gains
    missed a requirement, three quarters unstable, and RL alone ended at 1.07-1.12 x the reference
    optimum; at -1.5 it ends at 1.021-1.025, at -2 at 1.020-1.096 (docs/search.md, "Scaling").

    >>> exploration_log_std(2), exploration_log_std(3), exploration_log_std(12), exploration_log_std(48)
    (-1.0, -1.0, -1.5, -2.0)
    """
    return -1.0 - 0.25 * float(np.log2(max(dim, EXPLORATION_DIM) / EXPLORATION_DIM))


def agent_defaults(algo: str, n_envs: int, dim: int, budget_steps: int) -> dict[str, Any]:
    """Documented default hyper-parameters per algorithm (see docs/search.md)."""
    net = [64, 64]
    log_std = exploration_log_std(dim)
    if algo == "ppo":
        # one rollout = one step of every env; SB3's PPO needs a minibatch of 2 or more, so a single
        # env collects 2 steps per update
        return dict(
            n_steps=1 if n_envs > 1 else 2, batch_size=max(n_envs, 2), n_epochs=10, learning_rate=3e-3, gamma=0.0,
            gae_lambda=1.0, clip_range=0.2, ent_coef=0.0, vf_coef=0.5, max_grad_norm=0.5, normalize_advantage=True,
            policy_kwargs=dict(net_arch=dict(pi=net, vf=net), log_std_init=log_std, ortho_init=True),
        )
    if algo == "a2c":
        return dict(
            n_steps=1, learning_rate=3e-3, gamma=0.0, gae_lambda=1.0, ent_coef=0.0, normalize_advantage=True,
            policy_kwargs=dict(net_arch=dict(pi=net, vf=net), log_std_init=log_std),
        )
    off = dict(
        learning_rate=1e-3, buffer_size=min(max(budget_steps, 1000), REPLAY_MAX), learning_starts=min(4 * n_envs, 256),
        batch_size=256, gamma=0.0, tau=0.05, train_freq=1, gradient_steps=max(1, n_envs // 4),
        policy_kwargs=dict(net_arch=net),
    )
    if algo == "sac":
        off.update(ent_coef="auto", target_entropy=-float(dim) * 2.0)
        return off
    noise = NormalActionNoise(np.zeros(dim), 0.2 * np.ones(dim))
    off.update(action_noise=noise)
    if algo == "td3":
        off.update(target_policy_noise=0.05, target_noise_clip=0.1, policy_delay=2)
    return off


def iterative_defaults(algo: str, n_envs: int, horizon: int) -> dict[str, Any]:
    """Changes for the multi-step iterative env: returns over a short horizon instead of one-step bandits."""
    if algo in ("ppo", "a2c"):
        kw: dict[str, Any] = dict(n_steps=horizon, gamma=0.95, gae_lambda=0.95)
        if algo == "ppo":
            kw["batch_size"] = n_envs * horizon
        return kw
    return dict(gamma=0.95)


def make_agent(
    algo: str, env: VecEnv, seed: int, budget_steps: int, overrides: dict[str, Any] | None = None, horizon: int = 1
) -> BaseAlgorithm:
    """Build an SB3 agent on the batched env with gain-search defaults (plus ``overrides``)."""
    cls = ALGOS[algo]
    kw = agent_defaults(algo, env.num_envs, get_action_dim(env.action_space), budget_steps)
    if horizon > 1:
        kw.update(iterative_defaults(algo, env.num_envs, horizon))
    kw.update(overrides or {})
    policy_kwargs = dict(kw.get("policy_kwargs") or {})
    eager = _eager_optimizer_class() if algo == "ppo" and "optimizer_class" not in policy_kwargs else None
    if eager is not None:  # A2C uses RMSprop, SAC and TD3 build optimizers of their own: unchanged
        # Same Adam arithmetic without importing torch._dynamo (~1 s): gaintune/search/eager_optim.py.
        # SB3 gives its default Adam eps=1e-5 (ActorCriticPolicy); keep that for the subclass.
        policy_kwargs.setdefault("optimizer_kwargs", {"eps": 1e-5})
        kw["policy_kwargs"] = {**policy_kwargs, "optimizer_class": eager}
    return _silenced(cls("MlpPolicy", env, seed=seed, verbose=0, device="cpu", **kw))


def _silenced(agent: BaseAlgorithm) -> BaseAlgorithm:
    """Give ``agent`` a logger that writes nowhere.

    Without one, ``learn()`` builds SB3's default logger, which creates an empty ``SB3-<date>``
    folder in the temp directory on every call, even at ``verbose=0``. gaintune reads nothing
    from that logger.
    """
    agent.set_logger(Logger(folder=None, output_formats=[]))
    return agent


def load_agent(path: str | Path, spec: TuningSpec, env: VecEnv | None = None, *, field: str = "warm_start",
               budget_steps: int = 1) -> BaseAlgorithm:
    """The agent ``spec`` builds (``search.algo`` with gaintune's defaults), holding the weights saved at ``path``.

    Nothing in the file is executed: see :func:`load_weights`.

    Parameters
    ----------
    path
        An ``agent.zip`` a tune wrote.
    spec
        The spec the agent serves; its ``search`` section sets the algorithm, seed and parallel envs.
    env
        The env to attach; by default the spec's batched env (:class:`~gaintune.envs.BatchedGainVecEnv`).
    field
        The field a :class:`~gaintune.errors.SpecError` names.
    budget_steps
        Steps the agent will train for (sizes an off-policy replay buffer).
    """
    if env is None:
        from gaintune.envs.problem import GainProblem
        from gaintune.envs.vec import BatchedGainVecEnv

        env = BatchedGainVecEnv(GainProblem(spec), spec.search.n_envs, seed=spec.search.seed)
    return load_weights(make_agent(spec.search.algo, env, spec.search.seed, budget_steps), path, field=field)


def load_weights(agent: BaseAlgorithm, path: str | Path, *, field: str = "warm_start") -> BaseAlgorithm:
    """Put the weights of the agent file at ``path`` into ``agent``, which :func:`make_agent` built from the spec.

    The file is read as weights only (:func:`gaintune.search.agent_file.read_agent_file`): nothing in
    it is unpickled or executed. The policy weights must fit ``agent`` exactly (names, shapes, types)
    and be finite. The optimizer states and SAC's learned entropy coefficient are restored when the
    file has them (a warm start then continues as the saved training would have); a file without them
    starts them afresh. Hyper-parameters (learning rate, ...) are the spec's, never the file's.

    Raises
    ------
    SpecError
        Naming ``field``: the file is missing, too large, not an agent zip or needs unpickling; or its
        agent was trained on other numbers of gains or context values, or by another algorithm or
        network than ``agent`` has.
    """
    saved = read_agent_file(path, field)
    want = (tuple(agent.action_space.shape or ()), tuple(agent.observation_space.shape or ()))
    if saved.shapes is not None and saved.shapes != want:
        raise SpecError(field, f"the agent at {path} was trained on {_count(saved.shapes)}; this spec has "
                        f"{_count(want)}. A trained agent serves only the same loops, tuned gains and randomised "
                        "parameters")
    misfit = f"the weights in {path} do not fit the {agent.__class__.__name__} agent this spec builds"
    modules, variables = agent._get_torch_save_params()
    _install_eager_optim()  # loading an optimizer state: keep torch._dynamo unloaded
    for name in modules:
        target = recursive_getattr(agent, name)
        if isinstance(target, torch.optim.Optimizer):
            if name in saved.states:
                problem = load_optimizer_state(target, saved.states[name])
                if problem:
                    raise SpecError(field, f"{misfit}: its optimizer state {name} {problem}. Give an agent trained "
                                    "with this search.algo")
            continue
        if name not in saved.states:
            raise SpecError(field, f"{misfit}: it has no {name}.pth")
        problem = load_module_state(target, saved.states[name])
        if problem:
            raise SpecError(field, f"{misfit} ({problem}). Give an agent trained with this search.algo "
                            "and the default network")
    load_variables(agent, variables, saved.states.get("pytorch_variables"))
    if saved.num_timesteps is not None:  # the steps trained so far: an off-policy agent skips its random warm-up
        agent.num_timesteps = saved.num_timesteps
    return agent


def _count(shapes: tuple) -> str:
    act, obs = shapes
    return f"{int(np.prod(act))} tuned gains and {int(np.prod(obs))} context value(s)"
