"""The fleet file: which problems a sweep runs (pydantic schema, loading, expansion into items).

A fleet is either a list of documents (``specs``: spec files relative to the fleet file, glob
patterns, or inline specs) or one ``base`` document with a ``grid`` (every combination of the
listed values) or a list of ``cases`` (one set of overrides each). Overrides name a field by its
dotted path (``plant.params.K``, ``loops.0.type``); ``overrides`` apply to every item.

For ``kind: tune`` a document is a tuning spec; for ``kind: query`` it is a trained-tuner query
``{params: {...}, refine: 0, seed: 0}`` answered by the fleet's ``tuner``.

:func:`load_fleet` reads and validates the file (a :class:`FleetError` naming the field for a bad
one); :func:`expand` turns it into :class:`Item` s, each keyed by the content hash of its resolved
document and kind. A bad document fails only its own item (:attr:`Item.error`).
"""

from __future__ import annotations

import copy
import glob
import hashlib
import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from gaintune.errors import GaintuneError, problem_details

__all__ = ["MAX_ITEMS", "Fleet", "FleetError", "Item", "load_fleet", "expand", "item_key", "set_path"]

#: Most items one fleet may expand to (a grid multiplies quickly).
MAX_ITEMS = 100_000


class FleetError(GaintuneError):
    """The fleet file itself is invalid (its field and the fix are named); nothing runs."""


class Fleet(BaseModel):
    """A fleet file: the problems of one sweep (see the module docstring)."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field("fleet", description="A name for the sweep (shown in the summary).")
    description: str = ""
    kind: Literal["tune", "query"] = Field("tune", description="tune: an RL search per item; query: a trained tuner.")
    tuner: str | None = Field(None, description="kind query: a ready-made tuner's name or a tuner folder.")
    specs: list[str | dict[str, Any]] | None = Field(
        None, description="Documents: file paths or glob patterns (relative to the fleet file), or inline mappings.")
    base: str | dict[str, Any] | None = Field(None, description="One document the grid or the cases vary.")
    grid: dict[str, list[Any]] | None = Field(None, description="Dotted path -> values; every combination is an item.")
    cases: list[dict[str, Any]] | None = Field(None, description="One mapping of dotted path -> value per item.")
    overrides: dict[str, Any] = Field(default_factory=dict, description="Dotted path -> value, for every item.")

    @field_validator("grid")
    @classmethod
    def _grid_values(cls, v: dict[str, list[Any]] | None) -> dict[str, list[Any]] | None:
        if v is not None:
            if not v:
                raise ValueError("give at least one dotted path with its values, e.g. plant.params.K: [0.5, 1, 2]")
            for path, values in v.items():
                if not values:
                    raise ValueError(f"{path}: give at least one value")
            if math.prod(len(x) for x in v.values()) > MAX_ITEMS:
                raise ValueError(f"the grid has more than {MAX_ITEMS:,} combinations; split the fleet")
        return v

    @model_validator(mode="after")
    def _one_source(self) -> Fleet:
        if (self.specs is None) == (self.base is None):
            raise ValueError("give either specs (a list of documents) or base (one document with a grid or cases)")
        if self.base is None and (self.grid is not None or self.cases is not None):
            raise ValueError("grid and cases vary a base document; add base, or list the documents under specs")
        if self.grid is not None and self.cases is not None:
            raise ValueError("give either grid or cases, not both")
        if (self.kind == "query") != (self.tuner is not None):
            raise ValueError("kind query needs tuner (a name or folder); kind tune takes none")
        if self.specs is not None and not self.specs:
            raise ValueError("specs is empty; list at least one document")
        return self


@dataclass(frozen=True)
class Item:
    """One problem of a sweep.

    Attributes
    ----------
    index
        Its position in the fleet.
    label
        What it is, for the summary: a file name, or the overrides that make it.
    kind
        ``tune`` or ``query``.
    doc
        The resolved document the worker runs (a validated spec's JSON form, or a query).
    key
        Content hash of ``kind`` and ``doc``: the same problem has the same key in every run.
    error
        Why the document is invalid, or None; such an item is recorded as failed without running.
    """

    index: int
    label: str
    kind: str
    doc: dict[str, Any]
    key: str
    error: str | None = None


def _fleet_error(exc: Exception, field: str = "fleet") -> FleetError:
    lines = [f"{d['loc']}: {d['msg']}" if d["loc"] else d["msg"] for d in problem_details(exc)]
    first = lines[0] if lines else str(exc)
    loc, sep, msg = first.partition(": ")
    return FleetError(f"{field}.{loc}" if sep else field, msg if sep else first)


def load_fleet(path: str | Path) -> tuple[Fleet, Path]:
    """Read and validate the fleet file at ``path``.

    Returns
    -------
    tuple[Fleet, Path]
        The fleet and the folder its relative paths start from.

    Raises
    ------
    FleetError
        When the file cannot be read or parsed, or a field is invalid (the error names it).
    """
    from gaintune.files import read_text_bounded
    from gaintune.spec import parse_json_or_yaml

    path = Path(path)
    if not path.is_file():
        raise FleetError("fleet", f"file not found: {path}" if not path.exists() else f"{path} is not a file")
    try:
        data = parse_json_or_yaml(read_text_bounded(path, "fleet"))
    except ValueError as exc:
        raise FleetError("fleet", f"{path} is not valid YAML/JSON: {exc}") from None
    if not isinstance(data, dict):
        raise FleetError("fleet", "must be a mapping with specs, or base with a grid or cases")
    try:
        return Fleet.model_validate(data), path.resolve().parent
    except ValidationError as exc:
        raise _fleet_error(exc) from None


# --------------------------------------------------------------------------------- expansion


def set_path(doc: dict[str, Any], path: str, value: Any) -> None:
    """Set ``doc``'s field at the dotted ``path`` (missing mappings are made; list entries by index).

    Raises
    ------
    GaintuneError
        When the path runs through a value that is neither a mapping nor a list, or past a list's end.
    """
    parts = path.split(".")
    node: Any = doc
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(node, list):
            if not (part.isdigit() and int(part) < len(node)):
                raise GaintuneError(path, f"{'.'.join(parts[:i]) or 'the document'} is a list of {len(node)}; "
                                          f"{part!r} is not an index into it")
            idx: Any = int(part)
        elif isinstance(node, dict):
            idx = part
            if not last and node.get(part) is None:  # a missing mapping is made; a value is never replaced
                node[part] = {}
        else:
            raise GaintuneError(path, f"{'.'.join(parts[:i])} is a value, not a mapping; cannot set {part!r} in it")
        if last:
            node[idx] = value
        else:
            node = node[idx]


def _read_doc(path: Path, field: str) -> dict[str, Any]:
    from gaintune.files import read_text_bounded
    from gaintune.spec import parse_json_or_yaml

    try:
        data = parse_json_or_yaml(read_text_bounded(path, field))
    except ValueError as exc:
        raise GaintuneError(field, f"{path} is not valid YAML/JSON: {exc}") from None
    if not isinstance(data, dict):
        raise GaintuneError(field, f"{path} must hold a mapping")
    return data


def _sources(fleet: Fleet, root: Path) -> list[tuple[str, dict[str, Any] | GaintuneError]]:
    """(label, document or the error reading it) of each entry of ``specs``; globs expanded."""
    out: list[tuple[str, dict[str, Any] | GaintuneError]] = []
    for i, entry in enumerate(fleet.specs or []):
        if isinstance(entry, dict):
            out.append((str(entry.get("name") or f"specs[{i}]"), entry))
            continue
        names = [entry]
        if glob.has_magic(entry):
            names = sorted(str(Path(p).relative_to(root)) for p in glob.glob(str(root / entry), recursive=True))
            if not names:
                raise FleetError(f"specs.{i}", f"the pattern {entry!r} matches no file under {root}")
        for name in names:
            path = root / name
            try:
                out.append((name, _read_doc(path, f"specs.{i}") if path.is_file() else
                            GaintuneError(f"specs.{i}", f"file not found: {path}")))
            except GaintuneError as exc:
                out.append((name, exc))
    return out


def _variations(fleet: Fleet) -> list[dict[str, Any]]:
    """The overrides of each item made from ``base``: the grid's combinations, the cases, or one empty set."""
    if fleet.grid is not None:
        paths = list(fleet.grid)
        return [dict(zip(paths, combo, strict=True)) for combo in itertools.product(*fleet.grid.values())]
    if fleet.cases is not None:
        return [dict(c) for c in fleet.cases]
    return [{}]


def _label(overrides: dict[str, Any]) -> str:
    """``K=0.5, T=2`` for the overrides ``plant.params.K: 0.5, plant.params.T: 2.0`` (full paths when the last
    names repeat)."""
    short = [k.rsplit(".", 1)[-1] for k in overrides]
    names = short if len(set(short)) == len(short) else list(overrides)
    return ", ".join(f"{n}={v:g}" if isinstance(v, float) else f"{n}={v}"
                     for n, v in zip(names, overrides.values(), strict=True)) or "base"


def _documents(fleet: Fleet, root: Path) -> list[tuple[str, dict[str, Any] | GaintuneError]]:
    """(label, document with every override applied, or its error), one per item."""
    if fleet.base is None:
        pairs = _sources(fleet, root)
        variations: list[dict[str, Any]] = [{}] * len(pairs)
    else:
        try:
            base = fleet.base if isinstance(fleet.base, dict) else _read_doc(root / fleet.base, "base")
        except GaintuneError as exc:
            raise FleetError("base", exc.message) from None
        variations = _variations(fleet)
        if len(variations) > MAX_ITEMS:
            raise FleetError("cases", f"more than {MAX_ITEMS:,} cases; split the fleet")
        pairs = [(_label(v), base) for v in variations]
    docs: list[tuple[str, dict[str, Any] | GaintuneError]] = []
    for (label, doc), extra in zip(pairs, variations, strict=True):
        if isinstance(doc, GaintuneError):
            docs.append((label, doc))
            continue
        doc = copy.deepcopy(doc)
        try:
            for path, value in {**fleet.overrides, **extra}.items():
                set_path(doc, path, value)
        except GaintuneError as exc:
            docs.append((label, exc))
            continue
        docs.append((label, doc))
    return docs


def item_key(kind: str, doc: dict[str, Any]) -> str:
    """The content hash of an item: SHA-256 of the canonical JSON of its kind and resolved document."""
    text = json.dumps({"kind": kind, "doc": doc}, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def _error_text(exc: Exception) -> str:
    if isinstance(exc, ValidationError) and exc.title == "TuningSpec":
        from gaintune.spec.hints import explain

        details = explain([dict(e) for e in exc.errors(include_url=False)])
    else:
        details = problem_details(exc)
    return "; ".join(f"{d['loc']}: {d['msg']}" if d["loc"] else d["msg"] for d in details)


def _resolve_tune(doc: dict[str, Any]) -> dict[str, Any]:
    """A spec document, validated, in its canonical JSON form."""
    from gaintune.spec import load_spec

    return load_spec(doc).model_dump(mode="json")


def _resolve_query(doc: dict[str, Any], tuner: str, root: Path) -> dict[str, Any]:
    """A query document checked: ``params`` (finite numbers), ``refine`` and ``seed`` (integers >= 0)."""
    unknown = sorted(set(doc) - {"params", "refine", "seed"})
    if unknown:
        raise GaintuneError(unknown[0], "a query takes params, refine and seed only")
    params = doc.get("params")
    if not isinstance(params, dict) or not params:
        raise GaintuneError("params", "give the plant's parameters, e.g. params: {K: 2, T: 60, L: 10}")
    for name, x in params.items():
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            raise GaintuneError(f"params.{name}", f"must be a finite number, got {x!r}")
    for name in ("refine", "seed"):
        x = doc.get(name, 0)
        if isinstance(x, bool) or not isinstance(x, int) or x < 0:
            raise GaintuneError(name, f"must be an integer >= 0, got {x!r}")
    folder = root / tuner
    ref = str(folder) if folder.is_dir() else tuner  # a folder beside the fleet file, else a shipped tuner's name
    return {"tuner": ref, "params": {k: float(v) for k, v in params.items()},
            "refine": int(doc.get("refine", 0)), "seed": int(doc.get("seed", 0))}


def expand(fleet: Fleet, root: Path) -> list[Item]:
    """The items of ``fleet`` (relative paths start at ``root``), each resolved, validated and keyed.

    An item whose document is invalid keeps its error (it fails alone); a problem with the fleet
    itself (a base file missing, a pattern matching nothing) raises :class:`FleetError`.
    """
    items = []
    for index, (label, doc) in enumerate(_documents(fleet, root)):
        error = None
        if isinstance(doc, GaintuneError):
            resolved: dict[str, Any] = {"unreadable": f"{doc.field}: {doc.message}"}
            error = _error_text(doc)
        else:
            try:
                resolved = (_resolve_tune(doc) if fleet.kind == "tune" else
                            _resolve_query(doc, str(fleet.tuner), root))
            except Exception as exc:  # whatever is wrong with one document fails that item only
                resolved, error = doc, _error_text(exc)
        items.append(Item(index=index, label=label, kind=fleet.kind, doc=resolved,
                          key=item_key(fleet.kind, resolved), error=error))
    return items
