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


def _targets() -> list[Callable[..., Any]] | None:
    """The wrapped functions Adam calls, or None when torch is not laid out as expected."""
    found = []
    for name in _METHODS:
        found += _disabled_wrappers(getattr(Optimizer, name))
    found += _disabled_wrappers(_functional_adam)  # Adam.step's functional kernel
    if len(found) != len(_METHODS) + 1 or _plain_adam_step() is None:
        return None
    return found


def _plain_adam_step() -> Callable[..., Any] | None:
    """``Adam.step`` without the grad-mode wrapper (``_use_grad``) that imports dynamo at every step."""
    fn = torch.optim.Adam.step  # possibly under torch's profiling hook, which keeps __wrapped__
    while fn is not None:
        if getattr(getattr(fn, "__code__", None), "co_name", "") == "_use_grad":
            return getattr(fn, "__wrapped__", None)
        fn = getattr(fn, "__wrapped__", None)
    return None


def _wanted() -> bool:
    return os.environ.get("GAINTUNE_TORCH_DYNAMO", "") not in ("1", "true", "yes") and "torch._dynamo" not in sys.modules


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
    """``torch.optim.Adam`` whose ``step`` sets grad mode itself instead of through dynamo's wrapper."""

    def step(self, closure=None):  # type: ignore[override]
        if _ADAM_STEP is None:  # a torch laid out differently (e.g. an agent saved here, loaded elsewhere)
            return super().step(closure)
        prev = torch.is_grad_enabled()
        try:
            torch.set_grad_enabled(self.defaults["differentiable"])
            return _ADAM_STEP(self, closure)
        finally:
            torch.set_grad_enabled(prev)


_ADAM_STEP = _plain_adam_step()


def optimizer_class() -> type[Optimizer] | None:
    """:class:`EagerAdam` when the fast path is active (after :func:`install`), else None (SB3's default)."""
    return EagerAdam if install() else None
