"""A TD3 tuner's critic as plain arrays (``critic.npz``), so ``gaintune tuner update`` can continue from a
shipped folder without its torch agent.

A tuner's episodes are one step (gamma 0): the critic is a model of the reward of (context, gains),
the part of the agent an update would otherwise relearn from scratch before the actor may move.
:func:`critic_arrays` takes the first of TD3's twin Q-networks in float16 (half the size of float32,
far below the critic's own error; about 130 KB for the default 256x256 network); :func:`install_critic`
puts it into both twins and their targets (with gamma 0 the targets and the twin minimum play no
part: the regression target is the reward). ``critic.npz`` is read with ``allow_pickle=False`` and
its SHA-256 is checked against ``tuner.json``.
"""

from __future__ import annotations

import hashlib
import io
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.errors import SpecError
from gaintune.files import read_bytes_bounded

__all__ = ["FILE", "critic_arrays", "critic_bytes", "read_critic", "install_critic"]

FILE = "critic.npz"


def _linears(net: Any) -> list[Any]:
    import torch

    return [m for m in net if isinstance(m, torch.nn.Linear)]


def critic_arrays(agent: Any) -> dict[str, np.ndarray] | None:
    """The first Q-network's layers as ``w0, b0, w1, b1, ...`` (float16); None for an agent without a critic (PPO)."""
    critic = getattr(agent.policy, "critic", None)
    if critic is None or not hasattr(critic, "q_networks"):
        return None
    out: dict[str, np.ndarray] = {}
    for i, m in enumerate(_linears(critic.q_networks[0])):
        out[f"w{i}"] = m.weight.detach().cpu().numpy().astype(np.float16)
        out[f"b{i}"] = m.bias.detach().cpu().numpy().astype(np.float16)
    return out


def critic_bytes(agent: Any) -> bytes | None:
    """:func:`critic_arrays` as the bytes of ``critic.npz`` (None without a critic)."""
    arrays = critic_arrays(agent)
    if arrays is None:
        return None
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # type: ignore[arg-type]  # numpy's stub takes **kwds as allow_pickle
    return buf.getvalue()


def read_critic(folder: Path, sha256: str | None) -> dict[str, np.ndarray] | None:
    """The critic arrays of a tuner folder (None when it has none); SpecError naming ``tuner`` when the file
    does not match the hash ``tuner.json`` records, or holds anything but plain arrays."""
    path = folder / FILE
    if sha256 is None or not path.is_file():
        return None
    raw = read_bytes_bounded(path, "tuner", limit=8 * 1024 * 1024)
    if hashlib.sha256(raw).hexdigest() != sha256:
        raise SpecError("tuner", f"{path} does not match the hash in tuner.json: the folder was changed or damaged; "
                        "retrain or restore it")
    try:
        with np.load(io.BytesIO(raw), allow_pickle=False) as f:
            return {k: np.asarray(f[k], dtype=np.float32) for k in f.files}
    except ValueError as exc:
        raise SpecError("tuner", f"{path} is damaged ({exc}); retrain it") from None


def install_critic(agent: Any, arrays: dict[str, np.ndarray]) -> None:
    """Put the critic arrays into every Q-network of a TD3 agent and of its target (SpecError when they do not fit)."""
    import torch

    nets = list(agent.policy.critic.q_networks) + list(agent.policy.critic_target.q_networks)
    n = len(arrays) // 2
    for net in nets:
        layers = _linears(net)
        if len(layers) != n or any(tuple(m.weight.shape) != arrays[f"w{i}"].shape for i, m in enumerate(layers)):
            raise SpecError("tuner", "the tuner's critic does not fit this agent's critic; retrain the tuner")
        with torch.no_grad():
            for i, m in enumerate(layers):
                m.weight.copy_(torch.as_tensor(arrays[f"w{i}"], dtype=m.weight.dtype))
                m.bias.copy_(torch.as_tensor(arrays[f"b{i}"], dtype=m.bias.dtype))
