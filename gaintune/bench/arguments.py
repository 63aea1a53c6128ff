"""Argument checking shared by every ``gaintune bench`` module.

Bad input must never crash a benchmark or hang it: the project's rule is one line
``error: --option: what is wrong and the fix`` on stderr and exit code 2 (docs/cli.md).
Every bench module builds its parser with :class:`BenchParser` and the range-checked
types below, so out-of-range values (``--batch 0``, ``--min-time nan``,
``--concurrency 0``, an ``--out`` that is a file) are refused at parse time, before
any server, subprocess or long computation starts. Checks that need more than one
argument (``--problems`` of a ``--suite``) call :func:`fail`.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

from gaintune.spec.base import MAX_BUDGET

__all__ = [
    "EXIT_INPUT",
    "MAX_BATCH",
    "MAX_BUDGET",
    "MIN_BUDGET",
    "SEED_MAX",
    "BenchParser",
    "fail",
    "int_range",
    "positive_int",
    "non_negative_int",
    "seed_int",
    "budget_int",
    "float_range",
    "positive_float",
    "int_list",
    "output_dir",
    "add_out_argument",
    "resolve_out",
    "select_problems",
    "load_now",
    "load_span",
]

#: Exit code of invalid input (docs/cli.md; 1 means a component is missing).
EXIT_INPUT = 2
#: Largest batch of simulations in one call: far above any useful benchmark batch (4,096), and
#: small enough that a typo (1e11) is refused instead of asking NumPy for terabytes.
MAX_BATCH = 1_000_000
#: Smallest search budget, the spec's own limit (``search.budget``, ``ge=10``; the largest is MAX_BUDGET).
MIN_BUDGET = 10
#: Largest seed numpy accepts (the spec's ``search.seed`` range).
SEED_MAX = 2**32 - 1


def fail(option: str, message: str) -> NoReturn:
    """Print ``error: OPTION: MESSAGE`` on stderr and exit with :data:`EXIT_INPUT`."""
    print(f"error: {option}: {message}", file=sys.stderr, flush=True)
    raise SystemExit(EXIT_INPUT)


class BenchParser(argparse.ArgumentParser):
    """:class:`argparse.ArgumentParser` whose errors are the project's one line, exit 2.

    argparse prints the usage and ``prog: error: argument --x: ...``; this prints
    ``error: --x: ...`` (the option first, as every other ``gaintune`` command does).
    """

    def error(self, message: str) -> NoReturn:
        """Print ``error: --option: message`` (the option argparse blamed) and exit 2."""
        m = re.match(r"argument ([^:]+): (.*)", message, re.S)
        if m:
            option = m.group(1).split("/")[-1]  # "-n/--n" -> "--n": the long form
            fail(option, m.group(2))
        fail(self.prog, f"{message} (`{self.prog} --help` lists the options)")


# ------------------------------------------------------------------ value types
# Each factory returns a callable for ``add_argument(type=...)``; argparse turns its
# ArgumentTypeError into ``error: --option: <message>`` through BenchParser.


def _num(x: float) -> str:
    return f"{int(x):,}" if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def _range_text(lo: float | None, hi: float | None, lo_open: bool = False) -> str:
    if lo is not None and hi is not None:
        return f"from {_num(lo)} to {_num(hi)}" if not lo_open else f"> {_num(lo)} and <= {_num(hi)}"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {_num(lo)}"
    return f"<= {_num(hi)}" if hi is not None else "any value"


def int_range(lo: int | None = None, hi: int | None = None, what: str = "an integer") -> Callable[[str], int]:
    """Type: an integer in ``[lo, hi]`` (either bound may be None)."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {what} {_range_text(lo, hi)}, got {text!r}") from None
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"must be {what} {_range_text(lo, hi)}, got {v}")
        return v

    return parse


def float_range(lo: float | None = None, hi: float | None = None, *, lo_open: bool = True,
                what: str = "a finite number") -> Callable[[str], float]:
    """Type: a finite float above ``lo`` (``lo_open``: strictly) and at most ``hi``.

    NaN and infinities are refused: a NaN time limit never ends a ``while t < limit`` loop.
    """

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            v = math.nan
        below = lo is not None and (v <= lo if lo_open else v < lo)
        if not math.isfinite(v) or below or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"must be {what} {_range_text(lo, hi, lo_open)}, got {text!r}")
        return v

    return parse


#: A count of at least one (repetitions, requests, candidates, batch sizes without their cap ...).
positive_int = int_range(1)
#: A count that may be zero (kills, rounds, threads ...).
non_negative_int = int_range(0)
#: A random seed (numpy's range, as ``search.seed``).
seed_int = int_range(0, SEED_MAX, what="a seed")
#: A simulation budget (the spec's ``search.budget`` range).
budget_int = int_range(MIN_BUDGET, MAX_BUDGET, what="a simulation budget")
#: A finite duration or quantity > 0.
positive_float = float_range(0.0)


def int_list(lo: int = 1, hi: int | None = None) -> Callable[[str], list[int]]:
    """Type: comma-separated integers, each in ``[lo, hi]`` (e.g. ``--sweep 1,2,4``)."""
    one = int_range(lo, hi)

    def parse(text: str) -> list[int]:
        try:
            return [one(x) for x in text.split(",") if x.strip()]
        except argparse.ArgumentTypeError as exc:
            raise argparse.ArgumentTypeError(f"comma-separated values: each {exc}") from None

    return parse


def _check_folder(path: Path) -> str | None:
    """Why ``path`` cannot be used as the output folder (it is created if missing), or None."""
    if path.exists() and not path.is_dir():
        return f"{path} exists and is not a folder; give a folder"
    try:
        path.mkdir(parents=True, exist_ok=True)
        # an existing folder may still refuse files (read-only mount, permissions): try one
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        return f"cannot use {path} as the output folder ({exc.strerror or exc}); give a writable folder"
    return None


def output_dir(text: str) -> Path:
    """Type of ``--out``: an existing or creatable, writable folder (created here, before any work)."""
    path = Path(text)
    why = _check_folder(path)
    if why:
        raise argparse.ArgumentTypeError(why)
    return path


def add_out_argument(ap: argparse.ArgumentParser) -> None:
    """The ``--out`` option every writing benchmark has (checked by :func:`output_dir`)."""
    ap.add_argument("--out", type=output_dir, help="output folder, created if missing (default: bench/results)")


def resolve_out(out: Path | None) -> Path:
    """``--out`` or the default folder, checked like ``--out`` before the benchmark runs."""
    if out is not None:
        return out
    from gaintune.bench.references import default_out_dir

    path = default_out_dir()
    why = _check_folder(path)
    if why:
        fail("--out", f"default folder: {why} (or pass --out)")
    return path


def select_problems(suite: str, names: list[str] | None) -> list:
    """The ``--problems`` of ``--suite`` (all of them when None); an unknown name exits 2 naming ``--problems``.

    Checked after parsing: which names exist depends on ``--suite``.
    """
    from gaintune.bench.suite import get_suite, select

    try:
        return select(get_suite(suite), list(names) if names else None)
    except ValueError as exc:
        fail("--problems", str(exc))


def load_now() -> list[float]:
    """This machine's 1, 5 and 15-minute load averages, to two decimals (a benchmark records them)."""
    return [round(x, 2) for x in os.getloadavg()]


def load_span(start: list[float]) -> str:
    """``start`` (:func:`load_now` when the benchmark began) and the load averages now, as the results say them."""
    return f"{start} at the start, {load_now()} at the end"
