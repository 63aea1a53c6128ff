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
import torch
from stable_baselines3 import A2C, DDPG, PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.vec_env import VecEnv

from gaintune.errors import SpecError
from gaintune.search.eager_optim import install as _install_eager_optim
from gaintune.search.eager_optim import optimizer_class as _eager_optimizer_class

__all__ = ["ALGOS", "agent_defaults", "make_agent", "load_agent"]

# The batched simulator owns the cores. torch's intra-op pool on top of numba's made each
# PPO update 16x slower (measured: a 200-simulation search took 11.4 s instead of 0.7 s).
# Changing the count per call rebuilds the pool, so it is set once, here.
torch.set_num_threads(int(os.environ.get("GAINTUNE_TORCH_THREADS", "1")))

#: Replay-buffer cap of the off-policy agents (SB3's own default size): a buffer holds every step
#: of the search up to this, the oldest are overwritten beyond it.
REPLAY_MAX = 1_000_000

ALGOS: dict[str, type[BaseAlgorithm]] = {"ppo": PPO, "sac": SAC, "td3": TD3, "a2c": A2C, "ddpg": DDPG}


def agent_defaults(algo: str, n_envs: int, dim: int, budget_steps: int) -> dict[str, Any]:
    """Documented default hyper-parameters per algorithm (see docs/search.md)."""
    net = [64, 64]
    if algo == "ppo":
        # one rollout = one step of every env; SB3's PPO needs a minibatch of 2 or more, so a single
        # env collects 2 steps per update
        return dict(
            n_steps=1 if n_envs > 1 else 2, batch_size=max(n_envs, 2), n_epochs=10, learning_rate=3e-3, gamma=0.0, gae_lambda=1.0,
            clip_range=0.2, ent_coef=0.0, vf_coef=0.5, max_grad_norm=0.5, normalize_advantage=True,
            policy_kwargs=dict(net_arch=dict(pi=net, vf=net), log_std_init=-1.0, ortho_init=True),
        )
    if algo == "a2c":
        return dict(
            n_steps=1, learning_rate=3e-3, gamma=0.0, gae_lambda=1.0, ent_coef=0.0, normalize_advantage=True,
            policy_kwargs=dict(net_arch=dict(pi=net, vf=net), log_std_init=-1.0),
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
    kw = agent_defaults(algo, env.num_envs, env.action_space.shape[0], budget_steps)
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


def load_agent(path: str | Path, env: VecEnv | None = None, *, field: str = "warm_start",
               shapes: tuple[tuple[int, ...], tuple[int, ...]] | None = None) -> BaseAlgorithm:
    """Load a saved agent zip (any of :data:`ALGOS`, tried in turn) and attach ``env`` to it.

    ``shapes``: the (action, observation) shapes the agent must have when there is no ``env``
    to take them from.

    Raises
    ------
    SpecError
        Naming ``field``: the file is missing or not a saved agent, or the agent was trained on
        another number of gains or context values than ``env`` has (other loops, or other
        randomised parameters), which a warm start cannot bridge.
    """
    path = Path(path)
    if not path.is_file():
        raise SpecError(field, f"no saved agent at {path} (give the agent.zip a tune wrote with --out)")
    try:  # the saved spaces first: a mismatch is a message about the spec, not five failed loads
        data, _, _ = load_from_zip_file(path, device="cpu")
        saved = (tuple(data["action_space"].shape), tuple(data["observation_space"].shape))
    except Exception as exc:  # not a zip, no data, no spaces: whatever it is, it is no saved agent
        raise SpecError(field, f"{path} is not an agent saved by gaintune ({type(exc).__name__})") from None
    want = (env.action_space.shape, env.observation_space.shape) if env is not None else shapes
    if want is not None and saved != tuple(map(tuple, want)):
        raise SpecError(field, f"the agent at {path} was trained on {_count(saved)}; this spec has {_count(want)}. "
                        "A trained agent serves only the same loops, tuned gains and randomised parameters")
    _install_eager_optim()  # loading restores the optimizer state: keep torch._dynamo unloaded
    errors = []
    for name, cls in ALGOS.items():
        try:
            agent = cls.load(path, env=env, device="cpu")
        except Exception as exc:  # SB3 raises various errors for a file of another algorithm class
            errors.append(f"{name}: {type(exc).__name__}")
        else:
            return _silenced(agent)
    raise SpecError(field, f"{path} is not an agent saved by gaintune ({'; '.join(errors)})")


def _count(shapes: tuple) -> str:
    act, obs = shapes
    return f"{int(np.prod(act))} tuned gains and {int(np.prod(obs))} context value(s)"
