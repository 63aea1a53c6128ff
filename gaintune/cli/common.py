"""What every ``gaintune`` command shares: consoles, exit codes, error handling, input loading and formatting.

* exit codes (:data:`EXIT_OK`, :data:`EXIT_INPUT`, :data:`EXIT_VERIFY`) and the
  :data:`EPILOG` every help page ends with;
* the consoles: :data:`out` (stdout) and :data:`err` (stderr);
* :class:`InputError` and :func:`handle_errors`, which turns bad input into
  ``error: <field>: <message>`` lines on stderr and exit 2, never a traceback;
* the inputs: :func:`load_spec_file`, :func:`load_gains`, :func:`load_result`,
  :func:`reverify_result` and :func:`apply_overrides`; files are read bounded
  (:func:`gaintune.files.read_text_bounded`: regular files up to 10 MB);
* formatting helpers: ``_f`` (the one number formatter, :func:`gaintune.fmt.fmt`),
  ``_json_num``, ``_close`` and ``_command_line``.

Names with a leading underscore are internal to :mod:`gaintune.cli`: its modules
import them from here.
"""

from __future__ import annotations

import contextlib
import functools
import json
import math
import os
import shlex
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from gaintune.fmt import fmt

if TYPE_CHECKING:  # pragma: no cover
    from rich.console import Console

    from gaintune.search.result import TuneResult
    from gaintune.spec import Gains, TuningSpec

__all__ = [
    "EXIT_OK", "EXIT_INPUT", "EXIT_VERIFY", "EPILOG", "out", "err", "InputError", "handle_errors",
    "load_spec_file", "load_gains", "load_result", "reverify_result", "apply_overrides",
    "_f", "_json_num", "_close", "_command_line",
]

EXIT_OK, EXIT_INPUT, EXIT_VERIFY = 0, 2, 3

EPILOG = (
    "Exit codes: 0 success; 2 invalid input (spec, gains or file: the message names the field); "
    "3 verification failed (the gains are not accepted). Docs: docs/cli.md"
)


class _Console:
    """A :class:`rich.console.Console` made with these arguments on first use, standing in for it.

    Deferred on purpose: importing rich.console costs ~17 ms that ``gaintune verify`` (plain text
    on stdout) and ``gaintune --help`` never use. A console reads ``sys.stdout``/``sys.stderr``
    when it writes, so making it later changes nothing."""

    def __init__(self, **kwargs: Any) -> None:
        self._kwargs = kwargs
        self._console: Any = None

    def real(self) -> Console:
        """The console itself, made now if not yet (for APIs that want a real Console, e.g. a progress bar)."""
        return self._real()

    def _real(self) -> Any:
        if self._console is None:
            from rich.console import Console

            self._console = Console(**self._kwargs)
        return self._console

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real(), name)

    def __enter__(self) -> Any:
        return self._real().__enter__()

    def __exit__(self, *exc: Any) -> Any:
        return self._real().__exit__(*exc)


# emoji off: rich turns ':b:' in echoed input ('a:b:c', a path, a spec name) into an emoji
out = _Console(emoji=False)
err = _Console(stderr=True, soft_wrap=True, emoji=False)


class InputError(Exception):
    """Bad user input found by the CLI itself (file missing, unreadable gains, ...)."""

    def __init__(self, field: str, message: str) -> None:
        super().__init__(f"{field}: {message}")
        self.field, self.message = field, message


def _problem_lines(exc: Exception) -> list[str]:
    from gaintune.errors import problem_details

    if isinstance(exc, InputError):
        return [f"{exc.field}: {exc.message}"]
    if isinstance(exc, OSError) and not isinstance(exc, (FileNotFoundError, IsADirectoryError)):
        # a file the command reads or writes: full disk, no permission, a file where a folder goes
        return [f"{exc.filename or 'file'}: {exc.strerror or exc}"]
    details = problem_details(exc)
    if type(exc).__name__ == "ValidationError" and getattr(exc, "title", "") == "TuningSpec":
        from gaintune.spec.hints import explain

        details = explain(exc.errors(include_url=False))  # type: ignore[attr-defined]  # pydantic's ValidationError
    return [f"{d['loc']}: {d['msg']}" if d["loc"] else d["msg"] for d in details]


def _input_errors() -> tuple[type[Exception], ...]:
    import yaml
    from pydantic import ValidationError

    from gaintune.errors import GaintuneError

    return (InputError, GaintuneError, ValidationError, yaml.YAMLError, json.JSONDecodeError, OSError)


def handle_errors(fn: Callable) -> Callable:
    """Bad input -> ``error: <field>: <message>`` lines on stderr and exit 2, never a traceback."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except typer.Exit:
            raise
        except _input_errors() as exc:
            for line in _problem_lines(exc):
                err.print(f"error: {line}", markup=False, highlight=False)
            raise typer.Exit(EXIT_INPUT) from None
        except KeyboardInterrupt:
            err.print("interrupted", markup=False)
            raise typer.Exit(130) from None

    return wrapper


# ----------------------------------------------------------------- inputs


@contextlib.contextmanager
def output_errors(path: Path, field: str = "output") -> Iterator[None]:
    """``with output_errors(path):`` an OSError while writing ``path`` becomes an :class:`InputError`
    naming the ``--output`` option and the file (full disk, no permission, a file where a folder goes)."""
    try:
        yield
    except OSError as exc:
        raise InputError(field, f"cannot write {path}: {exc.strerror or exc}") from None


def check_out_dir(path: Path, field: str = "out") -> None:
    """Fail before any work when ``path`` cannot become an output folder (a file in the way, or read-only).

    A tune writes its folder only at the end; without this check a file named like ``--out`` cost
    the whole search before the command failed."""
    import tempfile

    for p in (path, *path.parents):
        if p.exists():
            if not p.is_dir():
                raise InputError(field, f"{p} is a file, not a folder; give --out a folder path")
            try:  # a real write: os.access says yes to root, and /proc is a folder nobody can write in
                os.rmdir(tempfile.mkdtemp(prefix=".gaintune-probe-", dir=p))
            except OSError as exc:
                raise InputError(field, f"{p} is not writable ({exc.strerror}); give --out a folder you can write "
                                 "to") from None
            return


def _read_file(path: Path, field: str) -> str:
    """The text of a regular file of at most :data:`gaintune.files.MAX_INPUT_BYTES` (``/dev/zero``, a FIFO: exit 2)."""
    from gaintune.errors import SpecError
    from gaintune.files import read_text_bounded

    if not path.exists():
        raise InputError(field, f"file not found: {path}")
    if path.is_dir():
        raise InputError(field, f"{path} is a directory, expected a file")
    try:
        return read_text_bounded(path, field)
    except SpecError as exc:
        raise InputError(field, exc.message) from None


def _parse_mapping(text: str, field: str) -> Any:
    from gaintune.spec import parse_json_or_yaml

    try:
        return parse_json_or_yaml(text)
    except ValueError as exc:
        raise InputError(field, f"not valid JSON/YAML: {exc}") from None


def load_spec_file(path: Path) -> TuningSpec:
    """The spec at ``path``, validated (bad input: an error naming the field, exit 2)."""
    from gaintune.spec import load_spec

    data = _parse_mapping(_read_file(path, "spec"), "spec")
    if not isinstance(data, dict):
        raise InputError("spec", "must be a mapping with at least 'plant' and 'loops'")
    return load_spec(data)


def load_gains(value: str) -> Gains:
    """``--gains``: a JSON/YAML file (a result.json's ``gains`` is taken) or inline JSON."""
    text = value
    if not value.lstrip().startswith("{"):
        text = _read_file(Path(value), "gains")
    data = _parse_mapping(text, "gains")
    if isinstance(data, dict) and "gains" in data and isinstance(data["gains"], dict):
        data = data["gains"]
    if not isinstance(data, dict):
        raise InputError("gains", "must be a mapping {loop: {gain: value}} (JSON or YAML)")
    return data


def load_result(path: Path) -> TuneResult:
    """The result.json at ``path`` as a :class:`~gaintune.search.result.TuneResult` (bad input: exit 2)."""
    from pydantic import ValidationError

    from gaintune.search.result import TuneResult

    text = _read_file(path, "result")
    try:
        result = TuneResult.model_validate_json(text)
    except ValidationError as exc:
        if any(e["type"] == "json_invalid" for e in exc.errors()):
            raise InputError("result", f"{path} is not valid JSON") from None
        raise
    if result.verification_set_aside:
        err.print(f"note: {path}: {result.verification_set_aside}; the gains are verified again here", markup=False)
    return result


def reverify_result(result, path: Path) -> None:
    """Replace the verification ``result`` (read from ``path``) carries by a fresh one, in place.

    A stored verdict is never the authority for a file that claims one: a file whose ``gains``
    and ``verification.gains`` were both edited, verdict left at pass, passes every consistency
    check (:attr:`~gaintune.search.result.TuneResult.verification_set_aside`); only verifying the
    gains again tells (about half a second). The diagnosis, written from the stored verdict, is
    dropped when it disagrees with the fresh one. ``verification_set_aside`` keeps why a stored
    verification was set aside on reading, or says that the file's verdict was not taken.
    """
    from gaintune.export.verdict import verify_if_possible
    from gaintune.spec import TuningSpec

    claimed = result.verdict
    result.verification, why = verify_if_possible(TuningSpec.model_validate(result.spec), result.gains)
    if why is not None:  # a MIMO architecture the verification does not cover: no verdict
        result.verification_set_aside = why
    elif result.verification_set_aside is None:
        result.verification_set_aside = "a verdict stored in a result file is not taken as it is"
    if result.diagnosis is not None and result.diagnosis.status != result.verdict:
        result.diagnosis = None
    if claimed is not None and claimed != result.verdict:
        err.print(f"note: {path} claims verdict {claimed!r}, but its gains verified again here give "
                  f"{result.verdict!r}; the stored verdict is not used", markup=False, highlight=False)


def apply_overrides(spec, *, algo: str | None = None, budget: int | None = None, seed: int | None = None,
                    workers: int | None = None):
    """Override ``search`` settings and re-validate the whole spec."""
    from gaintune.spec import TuningSpec

    upd: dict[str, Any] = {}
    if algo is not None:
        upd["algo"] = algo
    if budget is not None:
        upd["budget"] = budget
    if seed is not None:
        upd["seed"] = seed
    if workers is not None:
        upd["n_envs"] = workers
    if not upd:
        return spec
    data = spec.model_dump()
    data["search"] = {**data["search"], **upd}
    return TuningSpec.model_validate(data)


# ------------------------------------------------------------- formatting


_f = fmt  # one formatter for every table (gaintune.fmt)


def _command_line(*parts: Any, **options: Any) -> str:
    """The command that re-runs this result: positional parts, then the options that were given."""
    words = ["gaintune", *[str(p) for p in parts]]
    for k, v in options.items():
        if v is None or v is False:
            continue
        words.append(f"--{k.replace('_', '-')}")
        if v is not True:
            words.append(str(v))
    return shlex.join(words)


def _json_num(x: Any) -> Any:
    """``x`` for JSON: a numpy scalar as a Python number, a non-finite float as None."""
    x = x.item() if hasattr(x, "item") else x
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _close(a: float, b: float) -> bool:
    """Whether two floats agree to 1e-9 relative."""
    return math.isclose(a, b, rel_tol=1e-9, abs_tol=0.0)
