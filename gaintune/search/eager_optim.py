"""Adam for the RL agents without importing ``torch._dynamo`` (about 1 s off every tune).

torch.optim marks its methods and the functional ``adam`` with ``torch._disable_dynamo``, which
imports ``torch._dynamo`` (sympy, torch.fx, torch.distributed: ~1.0 s on the project machine) at
the first call, and ``Adam.step`` runs inside a grad-mode wrapper that imports it at every step
to mark graph breaks. gaintune never compiles with dynamo. Outside a ``torch.compile`` region
"run with dynamo disabled" and ``graph_break()`` do nothing, so skipping them leaves the same
arithmetic in the same order: the trained weights are bit-identical
(``tests/search/test_eager_optim.py``).

:func:`install` fills the cache slot that ``torch._disable_dynamo`` reads ("already disabled")
with the plain function, for the wrapped functions Adam uses; :class:`EagerAdam` is
``torch.optim.Adam`` with the grad-mode wrapper written out. Both only act when torch's
structure is the one this was written for (torch 2.13, pinned in pyproject.toml) and dynamo is
not loaded yet; otherwise they change nothing and torch imports dynamo as usual.
``GAINTUNE_TORCH_DYNAMO=1`` keeps torch's stock path (e.g. for a process that also compiles
models with ``torch.compile``).

In the plain case :class:`EagerAdam` also runs the update on flat moment buffers
(:meth:`EagerAdam._flat_step`): one op per moment for all parameters instead of one per tensor.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from typing import Any

import torch
import torch._compile
from torch.optim.adam import adam as _functional_adam
from torch.optim.optimizer import Optimizer

__all__ = ["EagerAdam", "install", "optimizer_class"]

_DISABLE_INNER = torch._compile._disable_dynamo(lambda: None).__code__  # the wrapper's code object
_SLOT = "__dynamo_disable"  # the attribute torch._disable_dynamo caches its disabled function in
_METHODS = ("add_param_group", "zero_grad", "state_dict", "load_state_dict")


def _disabled_wrappers(fn: Callable[..., Any]) -> list[Callable[..., Any]]:
    """``fn`` itself, or the functions its closure holds, that are ``torch._disable_dynamo`` wrappers."""
    if getattr(fn, "__code__", None) is _DISABLE_INNER:
        return [fn]
    cells = getattr(fn, "__closure__", None) or ()
    return [c.cell_contents for c in cells if getattr(c.cell_contents, "__code__", None) is _DISABLE_INNER]


def _targets() -> list[Any] | None:
    """The wrapped functions Adam calls (each with ``__wrapped__``), or None when torch is not laid out as expected."""
    found = []
    for name in _METHODS:
        found += _disabled_wrappers(getattr(Optimizer, name))
    found += _disabled_wrappers(_functional_adam)  # Adam.step's functional kernel
    if len(found) != len(_METHODS) + 1 or _plain_adam_step() is None:
        return None
    return found


def _plain_adam_step() -> Callable[..., Any] | None:
    """``Adam.step`` without the grad-mode wrapper (``_use_grad``) that imports dynamo at every step."""
    fn: Any = torch.optim.Adam.step  # possibly under torch's profiling hook, which keeps __wrapped__
    while fn is not None:
        if getattr(getattr(fn, "__code__", None), "co_name", "") == "_use_grad":
            return getattr(fn, "__wrapped__", None)
        fn = getattr(fn, "__wrapped__", None)
    return None


def _wanted() -> bool:
    wanted = os.environ.get("GAINTUNE_TORCH_DYNAMO", "") in ("1", "true", "yes")
    return not wanted and "torch._dynamo" not in sys.modules


def install() -> bool:
    """Let Adam run without importing ``torch._dynamo``; True when the fast path is active."""
    if not _wanted():
        return False
    targets = _targets()
    if targets is None:
        return False
    for wrapper in targets:
        plain = wrapper.__wrapped__
        if getattr(plain, _SLOT, None) is None:
            setattr(plain, _SLOT, plain)  # "already disabled": call the function itself
    return True


class EagerAdam(torch.optim.Adam):
    """``torch.optim.Adam`` whose ``step`` sets grad mode itself instead of through dynamo's wrapper,
    and updates all parameters' moments as one flat tensor (see :meth:`_flat_step`)."""

    #: (parameter ids, then what :meth:`_flat_state` returns)
    _flat: tuple | None = None

    def step(self, closure=None):
        """One Adam step over every parameter (flat when possible, else torch's own step)."""
        if _ADAM_STEP is None:  # a torch laid out differently (e.g. an agent saved here, loaded elsewhere)
            return super().step(closure)
        if closure is None and self._flat_step():
            return None
        prev = torch.is_grad_enabled()
        try:
            torch.set_grad_enabled(self.defaults["differentiable"])
            return _ADAM_STEP(self, closure)
        finally:
            torch.set_grad_enabled(prev)

    def _flat_step(self) -> bool:
        """Adam's update on one flat buffer per moment; False (nothing done) outside the plain case.

        torch's single-tensor Adam (the CPU default) runs ~8 small ops per parameter tensor; a
        policy has 13 of them, so the step was mostly per-op overhead (~0.34 ms, a fifth of a PPO
        gradient step). The moments live in two flat tensors whose slices are the per-parameter
        ``exp_avg``/``exp_avg_sq`` state (``state_dict`` is unchanged), so each element-wise op runs
        once on all parameters: the same arithmetic on every element, in the same order as torch's
        ``_single_tensor_adam`` (bit-identical, ``tests/search/test_eager_optim.py``). The plain case:
        one group of float32 CPU parameters, all with dense gradients, float hyper-parameters,
        no weight decay, amsgrad, maximize, capturable, differentiable, foreach or fused.
        """
        if len(self.param_groups) != 1:
            return False
        group = self.param_groups[0]
        params = group["params"]
        if (group["amsgrad"] or group["maximize"] or group["capturable"] or group["differentiable"]
                or group["foreach"] or group["fused"] or group["weight_decay"] != 0
                or not all(isinstance(group[k], float) for k in ("lr", "eps"))
                or not all(isinstance(b, float) for b in group["betas"])):
            return False
        for p in params:
            g = p.grad
            if (g is None or g.is_sparse or p.dtype != torch.float32 or p.device.type != "cpu"
                    or g.dtype != torch.float32 or g.device.type != "cpu"):
                return False
        flat = self._flat_state(params)
        if flat is None:
            return False
        m, v, steps, m_views, denom, d_views = flat
        beta1, beta2 = group["betas"]
        lr, eps = group["lr"], group["eps"]
        with torch.no_grad():
            grad = torch.cat([p.grad.reshape(-1) for p in params])
            steps += 1
            step = steps[0].item()
            m.lerp_(grad, 1 - beta1)
            v.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
            bias_correction1 = 1 - beta1**step
            bias_correction2 = 1 - beta2**step
            step_size = lr / bias_correction1
            bias_correction2_sqrt = bias_correction2**0.5
            torch.sqrt(v, out=denom).div_(bias_correction2_sqrt).add_(eps)  # (v.sqrt() / c).add_(eps), in place
            for p, mp, dp in zip(params, m_views, d_views, strict=True):
                p.addcdiv_(mp, dp, value=-step_size)
        return True

    def _flat_state(self, params: list[torch.Tensor]):
        """(exp_avg, exp_avg_sq, steps, exp_avg views, denominator, its views): flat tensors whose
        slices are the per-parameter state, built at the first step and rebuilt after
        ``load_state_dict``; None when the parameters' steps differ (state loaded from elsewhere:
        torch's own step then runs)."""
        flat = self._flat
        if flat is not None and flat[0] == [id(p) for p in params] and all(
                self.state[p].get("exp_avg") is mp for p, mp in zip(params, flat[4], strict=True)):
            return flat[1:]
        states = [self.state[p] for p in params]
        if all(len(st) == 0 for st in states):
            n = sum(p.numel() for p in params)
            m, v, steps = torch.zeros(n), torch.zeros(n), torch.zeros(len(params))
        elif all({"step", "exp_avg", "exp_avg_sq"} <= set(st) for st in states):
            counts = {float(st["step"]) for st in states}
            if len(counts) != 1:
                return None
            m = torch.cat([st["exp_avg"].reshape(-1) for st in states]).float()
            v = torch.cat([st["exp_avg_sq"].reshape(-1) for st in states]).float()
            steps = torch.full((len(params),), counts.pop())
        else:
            return None
        denom = torch.empty_like(m)
        offset, m_views, d_views = 0, [], []
        for i, (p, st) in enumerate(zip(params, states, strict=True)):
            n = p.numel()
            st["step"] = steps[i]
            st["exp_avg"] = m[offset:offset + n].view_as(p)
            st["exp_avg_sq"] = v[offset:offset + n].view_as(p)
            m_views.append(st["exp_avg"])
            d_views.append(denom[offset:offset + n].view_as(p))
            offset += n
        self._flat = ([id(p) for p in params], m, v, steps, m_views, denom, d_views)
        return self._flat[1:]


_ADAM_STEP = _plain_adam_step()


def optimizer_class() -> type[Optimizer] | None:
    """:class:`EagerAdam` when the fast path is active (after :func:`install`), else None (SB3's default)."""
    return EagerAdam if install() else None
