"""The tuner's policy as plain arrays: a NumPy forward pass, no torch.

A trained stable-baselines3 actor (``MlpPolicy``: ``Linear -> tanh -> ... -> Linear``, the
deterministic action is the Gaussian mean clipped to [-1, 1]) is exported by
:func:`from_sb3` into weight and bias arrays; :class:`NumpyPolicy` evaluates them. The
artefact stores them in ``policy.npz`` (read with ``allow_pickle=False``: arrays only).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["NumpyPolicy", "from_sb3"]

def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0)


_ACTIVATIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {"tanh": np.tanh, "relu": _relu}


@dataclass(frozen=True)
class NumpyPolicy:
    """``a = out(W_n f(... f(W_1 x + b_1) ...) + b_n)`` with ``f`` the hidden activation.

    Attributes
    ----------
    weights, biases
        Per layer, ``W`` (out, in) and ``b`` (out,), input layer first.
    activation
        ``tanh`` or ``relu``.
    output
        ``clip`` (to [-1, 1]: a Gaussian policy's mean, as SB3 clips it) or ``tanh`` (TD3's actor).
    """

    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    activation: str = "tanh"
    output: str = "clip"

    def __post_init__(self) -> None:
        if self.activation not in _ACTIVATIONS:
            raise ValueError(f"activation must be one of {sorted(_ACTIVATIONS)}, got {self.activation!r}")
        if self.output not in ("clip", "tanh"):
            raise ValueError(f"output must be 'clip' or 'tanh', got {self.output!r}")
        if len(self.weights) != len(self.biases) or not self.weights:
            raise ValueError("need one bias per weight matrix, at least one layer")
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            if w.ndim != 2 or b.shape != (w.shape[0],):
                raise ValueError(f"layer {i}: weight {w.shape} and bias {b.shape} do not fit")
            if i and w.shape[1] != self.weights[i - 1].shape[0]:
                given = self.weights[i - 1].shape[0]
                raise ValueError(f"layer {i} takes {w.shape[1]} inputs, layer {i - 1} gives {given}")

    @property
    def n_in(self) -> int:
        return int(self.weights[0].shape[1])

    @property
    def n_out(self) -> int:
        return int(self.weights[-1].shape[0])

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """Actions (B, n_out) in [-1, 1] for inputs (B, n_in) (or one input vector)."""
        h = np.atleast_2d(np.asarray(x, dtype=float))
        f = _ACTIVATIONS[self.activation]
        for w, b in zip(self.weights[:-1], self.biases[:-1], strict=True):
            h = f(h @ w.T + b)
        a = h @ self.weights[-1].T + self.biases[-1]
        return np.tanh(a) if self.output == "tanh" else np.clip(a, -1.0, 1.0)

    def arrays(self) -> dict[str, np.ndarray]:
        """``W0, b0, W1, b1, ...`` for ``np.savez``."""
        out: dict[str, np.ndarray] = {}
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            out[f"W{i}"], out[f"b{i}"] = w, b
        return out

    @classmethod
    def from_arrays(cls, arrays: Any, activation: str, output: str = "clip") -> NumpyPolicy:
        """The policy from ``W0, b0, ...`` (an ``np.load`` result or a dict)."""
        n = sum(1 for k in arrays if str(k).startswith("W"))
        try:
            ws = tuple(np.asarray(arrays[f"W{i}"], dtype=float) for i in range(n))
            bs = tuple(np.asarray(arrays[f"b{i}"], dtype=float) for i in range(n))
        except KeyError as exc:
            raise ValueError(f"missing array {exc}") from None
        return cls(ws, bs, activation, output)


def from_sb3(agent: Any) -> NumpyPolicy:
    """The deterministic actor of an SB3 agent as plain arrays: PPO/A2C's ``MlpPolicy`` (the Gaussian mean,
    clipped) or TD3's actor (``mu``, ending in tanh)."""
    import torch

    pol = agent.policy
    if hasattr(pol, "actor") and hasattr(pol.actor, "mu"):  # TD3: Linear, act, ..., Linear, Tanh
        body = list(pol.actor.mu)
        if not isinstance(body[-1], torch.nn.Tanh):
            raise ValueError("TD3 actor without a final tanh")
        body, output = body[:-1], "tanh"
    else:
        body, output = [*pol.mlp_extractor.policy_net, pol.action_net], "clip"
    layers = [m for m in body if isinstance(m, torch.nn.Linear)]
    acts = {type(m).__name__ for m in body if not isinstance(m, torch.nn.Linear)}
    activation = {"Tanh": "tanh", "ReLU": "relu"}.get(next(iter(acts), "Tanh"))
    if activation is None or len(acts) > 1:
        raise ValueError(f"cannot export activations {sorted(acts)}")
    with torch.no_grad():
        ws = tuple(m.weight.detach().cpu().double().numpy().copy() for m in layers)
        bs = tuple(m.bias.detach().cpu().double().numpy().copy() for m in layers)
    return NumpyPolicy(ws, bs, activation, output)
