"""Agent files (``agent.zip``) read as weights only: nothing in a file is ever executed.

stable-baselines3 saves an agent as a zip of ``data`` (JSON whose entries that are no JSON, such
as the policy class, the spaces and the schedules, are cloudpickled into it), ``policy.pth`` (the
policy's state dict), one ``<name>.pth`` per optimizer state and ``pytorch_variables.pth``. SB3's
own ``load`` unpickles those ``data`` entries, so a foreign file can run any code it likes.
gaintune never calls it. :func:`read_agent_file` instead:

* reads the zip with the size cap of :mod:`gaintune.files` (:data:`~gaintune.files.MAX_INPUT_BYTES`),
  and the members it inflates share that cap, so a zip bomb is refused before it fills memory;
* loads every top-level ``.pth`` member with ``torch.load(weights_only=True)``: tensors, numbers,
  strings and containers of them, nothing else. A member that would need any other object (that is,
  real unpickling) is refused, and so is the whole file;
* reads ``data`` with plain :mod:`json` for its plain entries only (the saved spaces' shapes, the
  step count); its pickled entries are never decoded.

Everything else (algorithm, network, hyper-parameters) is rebuilt from the spec, and the weights
are checked against it before they are put in: :func:`gaintune.search.agents.load_weights`.
:func:`save_agent` writes SB3's own format, which this reader takes, atomically.
"""

from __future__ import annotations

import io
import json
import re
import warnings
import zipfile
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path
from typing import Any, TypeGuard

import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.save_util import recursive_getattr

from gaintune.errors import SpecError
from gaintune.files import MAX_INPUT_BYTES, read_bytes_bounded, write_atomic

__all__ = ["SavedAgent", "read_agent_file", "load_module_state", "load_optimizer_state", "load_variables",
           "save_agent"]


@dataclass
class SavedAgent:
    """What an agent file holds that can be read without executing anything.

    Attributes
    ----------
    states
        Member name without ``.pth`` (``policy``, ``policy.optimizer``, ``pytorch_variables``, ...)
        -> the weights-only object it holds.
    shapes
        ``(action shape, observation shape)`` from the plain JSON of ``data``; None when absent.
    num_timesteps
        Steps the agent was trained for (plain JSON of ``data``); None when absent.
    """

    path: Path
    states: dict[str, Any] = dc_field(default_factory=dict)
    shapes: tuple[tuple[int, ...], tuple[int, ...]] | None = None
    num_timesteps: int | None = None


def read_agent_file(path: str | Path, field: str, limit: int = MAX_INPUT_BYTES) -> SavedAgent:
    """Read the agent zip at ``path`` as weights only (see the module docstring).

    Raises
    ------
    SpecError
        Naming ``field``: no such file, larger than ``limit`` (the file or its inflated members),
        not a zip, no ``policy.pth``, or a member that is no plain weights (it would need unpickling).
    """
    path = Path(path)
    if not path.exists():
        raise SpecError(field, f"no saved agent at {path} (give the agent.zip a tune wrote with --out)")
    raw = read_bytes_bounded(path, field, limit)  # a device, pipe or oversized file is refused here
    try:
        with zipfile.ZipFile(io.BytesIO(raw)) as archive:
            return _read_archive(archive, path, field, limit)
    except SpecError:
        raise
    except Exception as exc:  # not a zip, a broken or encrypted member: whatever it is, it is no saved agent
        raise SpecError(field, f"{path} is not an agent saved by gaintune ({type(exc).__name__}); give the "
                        "agent.zip a tune wrote with --out") from None


def _read_archive(archive: zipfile.ZipFile, path: Path, field: str, limit: int) -> SavedAgent:
    members = {info.filename: info for info in archive.infolist()}
    if "policy.pth" not in members:
        raise SpecError(field, f"{path} holds no policy weights (policy.pth); give the agent.zip a tune wrote "
                               "with --out")
    inflate = _Inflater(archive, path, field, limit)
    saved = SavedAgent(path)
    for name, info in members.items():
        if name.endswith(".pth") and "/" not in name:  # SB3's members; other files are not read at all
            saved.states[name[:-4]] = _weights_only(inflate(info), name, path, field)
    if "data" in members:
        _read_plain_data(saved, inflate(members["data"]))
    return saved


class _Inflater:
    """Reads members whose inflated sizes add up to at most ``limit`` bytes (a zip bomb stops at the cap)."""

    def __init__(self, archive: zipfile.ZipFile, path: Path, field: str, limit: int) -> None:
        self.archive, self.left = archive, limit
        self.too_big = SpecError(field, f"{path}: the members of the zip inflate to more than {limit:,} bytes, "
                                 "the limit for an agent file")

    def __call__(self, info: zipfile.ZipInfo) -> bytes:
        if info.file_size > self.left:
            raise self.too_big
        with self.archive.open(info) as fh:
            data = fh.read(self.left + 1)  # the declared size can lie: the read is capped as well
        if len(data) > self.left:
            raise self.too_big
        self.left -= len(data)
        return data


def _weights_only(raw: bytes, member: str, path: Path, field: str) -> Any:
    """``torch.load`` restricted to tensors and plain containers: a pickled object of any other kind is refused."""
    try:
        with warnings.catch_warnings():  # torch warns about the pickle protocol of foreign files
            warnings.simplefilter("ignore")
            return torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
    except Exception as exc:
        asked = re.search(r"GLOBAL (\S+)", str(exc))
        what = f" (it asks for {asked.group(1)})" if asked else ""
        raise SpecError(field, f"{path}: {member} is not plain weights{what}. Reading it would mean unpickling, which "
                        "can run code from the file; gaintune reads agent files as weights only and refuses this "
                        "one") from None


def _read_plain_data(saved: SavedAgent, raw: bytes) -> None:
    """The spaces' shapes and the step count from ``data``, read as plain JSON; anything odd is left out."""
    try:
        data = json.loads(raw.decode("utf-8"))
    except (ValueError, RecursionError):
        return
    if not isinstance(data, dict):
        return
    action, observation = _shape(data.get("action_space")), _shape(data.get("observation_space"))
    if action is not None and observation is not None:
        saved.shapes = (action, observation)
    steps = data.get("num_timesteps")
    if type(steps) is int and 0 <= steps < 2**53:
        saved.num_timesteps = steps


def _shape(space: Any) -> tuple[int, ...] | None:
    """``_shape`` of a saved space: a plain JSON list that SB3 writes beside the pickled space."""
    shape = space.get("_shape") if isinstance(space, dict) else None
    if isinstance(shape, list) and all(type(n) is int and n >= 0 for n in shape):
        return tuple(shape)
    return None


def load_module_state(module: torch.nn.Module, state: Any) -> str | None:
    """Load ``state`` into ``module`` if it fits exactly: the same names, shapes and types, finite values.

    Returns None when loaded, else what does not fit (and ``module`` is unchanged)."""
    own = module.state_dict()  # every check compares shapes before touching values (see load_optimizer_state)
    if not isinstance(state, dict) or not all(isinstance(k, str) for k in state):
        return "no state dict of named tensors"
    missing = [k for k in own if k not in state]
    unexpected = [k for k in state if k not in own]
    other = [k for k in own if k in state and not _same_kind(state[k], own[k])]
    kinds = ((missing, "missing"), (unexpected, "unexpected"), (other, "of another shape or type"))
    problems = [f"{len(keys)} {what} (e.g. {keys[0]!r})" for keys, what in kinds if keys]
    if problems:
        return ", ".join(problems)
    if not all(bool(torch.isfinite(t).all()) for t in state.values()):
        return "non-finite weights"
    module.load_state_dict(state, strict=True)
    return None


#: The per-parameter state an optimizer's step reads; a state without it would fail mid-training.
_STATE_KEYS: tuple[tuple[type[torch.optim.Optimizer], frozenset[str]], ...] = (
    (torch.optim.Adam, frozenset({"step", "exp_avg", "exp_avg_sq"})),
    (torch.optim.RMSprop, frozenset({"step", "square_avg"})),
)


def load_optimizer_state(optimizer: torch.optim.Optimizer, state: Any) -> str | None:
    """Load the moments of ``state`` into ``optimizer`` if they fit its parameters; keep its hyper-parameters.

    torch's own ``load_state_dict`` checks only the number of parameters, so a moment of another
    shape would fail at the first step: every tensor is checked here against its parameter first.
    Returns None when loaded, else what does not fit (and ``optimizer`` is unchanged)."""
    own = optimizer.state_dict()
    if not (isinstance(state, dict) and isinstance(state.get("state"), dict)
            and isinstance(state.get("param_groups"), list)):
        return "is no optimizer state"
    theirs = [g.get("params") if isinstance(g, dict) else None for g in state["param_groups"]]
    if theirs != [g["params"] for g in own["param_groups"]]:
        return "holds other parameters"
    params = dict(zip((i for g in own["param_groups"] for i in g["params"]),
                      (p for g in optimizer.param_groups for p in g["params"]), strict=True))
    needed = next((keys for cls, keys in _STATE_KEYS if isinstance(optimizer, cls)), frozenset())
    for index, moments in state["state"].items():
        param = params.get(index) if type(index) is int else None
        if param is None or not isinstance(moments, dict) or not needed <= moments.keys():
            return "holds no moments of this optimizer"
        for key, value in moments.items():
            # the shape first: a forged tensor can be a huge zero-stride view of a few bytes
            if not (isinstance(value, torch.Tensor)
                    and (value.shape == param.shape or (key == "step" and value.numel() == 1))
                    and value.is_floating_point() and bool(torch.isfinite(value).all())):
                return f"has a {key!r} that is no finite tensor of its parameter's shape"
    # the file's moments, the spec's hyper-parameters (learning rate, betas, ...)
    optimizer.load_state_dict({"state": state["state"], "param_groups": own["param_groups"]})
    return None


def load_variables(agent: BaseAlgorithm, names: list[str], saved: Any) -> None:
    """Learned variables outside the modules (SAC's ``log_ent_coef``), when ``saved`` has them with the right shape.

    A variable that does not learn (a fixed entropy coefficient) is a hyper-parameter: it stays the spec's."""
    if not isinstance(saved, dict):
        return
    for name in names:
        current, value = recursive_getattr(agent, name, None), saved.get(name)
        if (isinstance(current, torch.Tensor) and current.requires_grad and _same_kind(value, current)
                and bool(torch.isfinite(value).all())):
            with torch.no_grad():
                current.copy_(value)


def _same_kind(value: Any, like: torch.Tensor) -> TypeGuard[torch.Tensor]:
    """``value`` is a tensor of the shape and type of ``like``."""
    return isinstance(value, torch.Tensor) and value.shape == like.shape and value.dtype == like.dtype


def save_agent(agent: BaseAlgorithm, path: str | Path) -> Path:
    """Save ``agent`` in SB3's zip format with :func:`gaintune.files.write_atomic`.

    The zip is built in memory and renamed into place, so a symlink planted at ``path`` is replaced,
    never written through, and a reader never sees half a file.
    """
    buf = io.BytesIO()
    agent.save(buf)
    return write_atomic(path, buf.getvalue())
