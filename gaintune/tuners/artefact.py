"""A tuner on disk: a folder with ``tuner.json`` and ``policy.npz``, versioned, written atomically.

``tuner.json`` holds the format name and version, the problem (family or spec) and the spec of its
central context, the context
variables and their ranges, the gain box, the policy's layer shapes and activation and the
SHA-256 of ``policy.npz``, the training record (algorithm, episodes, simulations, wall time,
the training curve) and the held-out validation table (cost / per-context optimum, verdicts).
``policy.npz`` holds plain float arrays, read with ``allow_pickle=False``: nothing in a tuner
folder is executed, and NumPy evaluates the policy without torch. A TD3 tuner also holds its critic
as arrays (``critic.npz``, :mod:`gaintune.tuners.critic`, its hash in ``tuner.json``), which only
``gaintune tuner update`` reads.

:func:`save` writes the folder next to its destination and renames it into place, so a reader
sees the old tuner or the new one, never half of one. :func:`load` checks the format, the
version, the hash and the shapes, and names what is wrong.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.errors import SpecError
from gaintune.files import read_bytes_bounded, write_atomic
from gaintune.tuners.mlp import NumpyPolicy
from gaintune.tuners.problems import GainBox, TunerProblem, problem_from_dict

__all__ = ["FORMAT", "VERSION", "Artefact", "check_out", "save", "load", "critic_sha256", "SHIPPED_DIR",
           "shipped_names", "resolve"]

FORMAT = "gaintune-tuner"
#: Bumped when the folder's meaning changes; :func:`load` refuses other versions.
VERSION = 1
#: Where the ready-made tuners live (inside the installed package).
SHIPPED_DIR = Path(__file__).resolve().parent / "shipped"


@dataclass
class Artefact:
    """A loaded tuner: its problem (with the gain box), its policy and the rest of ``tuner.json``."""

    name: str
    problem: TunerProblem
    policy: NumpyPolicy
    training: dict[str, Any] = field(default_factory=dict)
    validation: dict[str, Any] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)
    #: Other files written with the tuner (``agent.zip``: the torch agent ``gaintune tuner update`` continues).
    files: dict[str, bytes] = field(default_factory=dict, repr=False)


def _npz_bytes(policy: NumpyPolicy) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, *(), **policy.arrays())  # type: ignore[arg-type]  # numpy's stub takes **kwds as allow_pickle
    return buf.getvalue()


def check_out(out: str | Path) -> Path:
    """``out`` as a Path where a tuner may be written, else SpecError naming ``out``: a new folder, an empty one,
    or a tuner folder (replaced). A folder holding anything else is refused, never emptied: the atomic
    replace moves the old folder aside and deletes it, and a user's files there were lost."""
    if not str(out).strip():
        raise SpecError("out", "give a folder name for the tuner")
    out = Path(out)
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise SpecError("out", f"{out} exists and is not a folder; give a folder for the tuner")
    if out.is_dir() and not (out / "tuner.json").is_file() and any(out.iterdir()):
        raise SpecError("out", f"{out} holds files and is not a tuner folder; give a new or empty folder (a tuner "
                        "folder there is replaced, nothing else is)")
    if out.resolve() == Path.cwd().resolve():
        raise SpecError("out", "the tuner replaces its folder: give a folder below this one, not the current one")
    return out


def save(out: str | Path, art: Artefact) -> Path:
    """Write ``art`` as the folder ``out`` (atomically: built beside it, then renamed into place)."""
    out = check_out(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    assert art.problem.box is not None
    npz = _npz_bytes(art.policy)
    doc = {
        "format": FORMAT, "version": VERSION, "name": art.name, **art.meta,
        "problem": art.problem.as_dict(),
        # the tuning problem of the family's central context: what every context's spec looks like
        "spec": art.problem.spec_at(art.problem.centre()).model_dump(mode="json", exclude_defaults=True),
        "box": art.problem.box.as_dict(),
        "context": [{"name": v.name, "lo": v.lo, "hi": v.hi, "log": v.log} for v in art.problem.variables],
        "policy": {"file": "policy.npz", "sha256": hashlib.sha256(npz).hexdigest(), "activation": art.policy.activation,
                   "output": art.policy.output,
                   "layers": [list(w.shape) for w in art.policy.weights]},
        "training": art.training, "validation": art.validation,
    }
    if "critic.npz" in art.files:  # a TD3 tuner's critic: what 'tuner update' continues from (no torch agent)
        doc["critic"] = {"file": "critic.npz", "sha256": hashlib.sha256(art.files["critic.npz"]).hexdigest()}
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    tmp.chmod(0o755)  # mkdtemp makes it 0700: the folder it becomes is an ordinary one
    try:
        write_atomic(tmp / "policy.npz", npz)
        for fname, data in art.files.items():
            write_atomic(tmp / fname, data)
        write_atomic(tmp / "tuner.json", json.dumps(doc, indent=1, sort_keys=False) + "\n")
        old = None
        if out.exists():
            old = out.with_name(f".{out.name}.old-{os.getpid()}")
            os.replace(out, old)
        os.replace(tmp, out)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return out


def _doc(folder: Path) -> dict[str, Any]:
    try:
        doc = json.loads(read_bytes_bounded(folder / "tuner.json", "tuner", limit=2 * 1024 * 1024))
    except ValueError as exc:
        raise SpecError("tuner", f"{folder / 'tuner.json'} is not JSON ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise SpecError("tuner", f"{folder} holds no gaintune tuner (tuner.json has no format {FORMAT!r})")
    if doc.get("version") != VERSION:
        raise SpecError("version", f"{folder} is a tuner of format version {doc.get('version')!r}; this gaintune "
                        f"reads version {VERSION}. Retrain it with 'gaintune tuner train' (or 'update')")
    return doc


def load(folder: str | Path) -> Artefact:
    """Read and check a tuner folder (SpecError naming ``tuner``/``version`` with the fix otherwise)."""
    folder = Path(folder)
    doc = _doc(folder)
    raw = read_bytes_bounded(folder / "policy.npz", "tuner", limit=8 * 1024 * 1024)
    pol = doc.get("policy") or {}
    if hashlib.sha256(raw).hexdigest() != pol.get("sha256"):
        raise SpecError("tuner", f"{folder / 'policy.npz'} does not match the hash in tuner.json: the folder was "
                        "changed or damaged; retrain or restore it")
    try:
        with np.load(io.BytesIO(raw), allow_pickle=False) as arrays:
            policy = NumpyPolicy.from_arrays({k: arrays[k] for k in arrays.files}, str(pol.get("activation")),
                                             str(pol.get("output", "clip")))
        box = GainBox.from_dict(doc["box"])
        problem = problem_from_dict(doc["problem"], box)
        _check_slots(problem, box)
    except (ValueError, KeyError, TypeError, SpecError) as exc:
        if isinstance(exc, SpecError) and exc.field.startswith("models/"):
            raise  # a plant model file the tuner's spec names is bad, not the tuner: that file's error says so
        raise SpecError("tuner", f"{folder} is damaged ({_why(exc)}); retrain it") from None
    if policy.n_in != len(problem.variables) or policy.n_out != len(box.slots):
        raise SpecError("tuner", f"{folder}: the policy maps {policy.n_in} -> {policy.n_out} values but the tuner has "
                        f"{len(problem.variables)} context values and {len(box.slots)} gains; retrain it")
    meta = {k: v for k, v in doc.items()
            if k not in ("problem", "spec", "box", "context", "policy", "training", "validation", "critic")}
    return Artefact(str(doc.get("name") or folder.name), problem, policy, doc.get("training") or {},
                    doc.get("validation") or {}, meta)


def _why(exc: Exception) -> str:
    """What is wrong, in one line: a damaged spec's first field and message, not pydantic's whole report."""
    from pydantic import ValidationError

    from gaintune.errors import problem_details

    if isinstance(exc, (ValidationError, SpecError)):
        first = problem_details(exc)[0]
        return f"{first['loc']}: {first['msg']}" if first["loc"] else str(first["msg"])
    return str(exc)


def _check_slots(problem: TunerProblem, box: GainBox) -> None:
    """ValueError unless every slot of the box is a gain that the problem's spec tunes (a box naming a loop or a
    gain the spec does not have answered with a KeyError traceback); the layout's SpecError for a gain the
    loop's form does not have."""
    tuned = set(problem.tuned_slots())
    stray = [s for s in box.slots if s not in tuned]
    if stray:
        raise ValueError(f"its gain box names {stray[0][0]}.{stray[0][1]}, which its spec does not tune")


def critic_sha256(folder: str | Path) -> str | None:
    """The SHA-256 ``tuner.json`` records for the folder's ``critic.npz`` (None: the tuner has no critic)."""
    crit = _doc(Path(folder)).get("critic")
    return str(crit["sha256"]) if isinstance(crit, dict) and "sha256" in crit else None


def shipped_names() -> list[str]:
    """Names of the ready-made tuners shipped with gaintune."""
    if not SHIPPED_DIR.is_dir():
        return []
    return sorted(p.name for p in SHIPPED_DIR.iterdir() if (p / "tuner.json").is_file())


def resolve(name_or_dir: str | Path) -> Path:
    """A tuner folder from a path or a shipped tuner's name (SpecError naming ``tuner`` otherwise)."""
    p = Path(name_or_dir)
    if (p / "tuner.json").is_file():
        return p
    if str(name_or_dir) in shipped_names():
        return SHIPPED_DIR / str(name_or_dir)
    known = ", ".join(shipped_names()) or "none yet"
    raise SpecError("tuner", f"{name_or_dir!s} is neither a tuner folder (with tuner.json) nor a shipped tuner; "
                    f"shipped: {known} ('gaintune tuner list')")
