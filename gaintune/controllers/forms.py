"""The two PID forms engineers use, and the conversion between them.

* parallel: ``u = Kp e + Ki ∫e + Kd de/dt``
* ideal (standard, ISA): ``u = Kp (e + (1/Ti) ∫e + Td de/dt)``, so ``Ki = Kp/Ti`` and ``Kd = Kp Td``.

A loop has one form in the spec (``loops[i].form``); :func:`equivalent` gives the gains of the
other form, for tables and reports, and :func:`to_form` reads gains written in either form.
"""

from __future__ import annotations

import math
from collections.abc import Callable

__all__ = ["IDEAL", "PARALLEL", "equivalent", "form_of", "other_form_text", "to_form", "gain_unit"]

PARALLEL = ("Kp", "Ki", "Kd")
IDEAL = ("Kp", "Ti", "Td")


def _ideal(g: dict[str, float]) -> dict[str, float]:
    kp = g.get("Kp", 0.0)
    out = {"Kp": kp}
    if "Ki" in g:
        out["Ti"] = kp / g["Ki"] if g["Ki"] != 0 else math.inf  # no integral action: Ti = inf
    if "Kd" in g:
        out["Td"] = g["Kd"] / kp if kp != 0 else math.nan
    return out


def _parallel(g: dict[str, float]) -> dict[str, float]:
    kp = g.get("Kp", 0.0)
    out = {"Kp": kp}
    if "Ti" in g:
        out["Ki"] = kp / g["Ti"] if g["Ti"] != 0 else math.nan
    if "Td" in g:
        out["Kd"] = kp * g["Td"]
    return out


def equivalent(form: str, gains: dict[str, float]) -> dict[str, float]:
    """The gains of a PID loop in the *other* form (ideal for a parallel loop and vice versa).

    Examples
    --------
    >>> equivalent("parallel", {"Kp": 2.0, "Ki": 0.5, "Kd": 1.0})
    {'Kp': 2.0, 'Ti': 4.0, 'Td': 0.5}
    >>> equivalent("ideal", {"Kp": 2.0, "Ti": 4.0})
    {'Kp': 2.0, 'Ki': 0.5}
    """
    return _ideal(gains) if form == "parallel" else _parallel(gains)


def form_of(gains: dict[str, float]) -> str | None:
    """The PID form ``gains`` are written in, when their names tell (None for a P loop or other gains).

    Examples
    --------
    >>> form_of({"Kp": 1.0, "Ti": 2.0}), form_of({"Kp": 1.0, "Ki": 0.5}), form_of({"Kp": 1.0})
    ('ideal', 'parallel', None)
    """
    names = set(gains)
    if names <= set(PARALLEL) and names & {"Ki", "Kd"}:
        return "parallel"
    if names <= set(IDEAL) and names & {"Ti", "Td"}:
        return "ideal"
    return None


def other_form_text(form: str | None, gains: dict[str, float], number: Callable[[float], str]) -> str:
    """The gains the other PID form adds, as text: ``"Ti 2.5 s, Td 0.5 s"`` for a parallel loop ("" for none).

    ``number`` formats each value (the caller's table style).

    Examples
    --------
    >>> other_form_text("parallel", {"Kp": 2.0, "Ki": 0.5, "Kd": 1.0}, "{:g}".format)
    'Ti 4 s, Td 0.5 s'
    """
    if form is None:
        return ""
    alt = {k: v for k, v in equivalent(form, gains).items() if k not in gains}
    return ", ".join(f"{k} {number(v)}" + (" s" if k in ("Ti", "Td") else "") for k, v in alt.items())


def to_form(form: str, gains: dict[str, float]) -> dict[str, float]:
    """``gains`` of one loop in ``form``, converted when they are written in the other form.

    ``K`` is read as ``Kp``. Gains that are already in ``form`` (or mix in names of neither form)
    are returned as they are, so the caller's own check names what is unknown.

    Examples
    --------
    >>> to_form("parallel", {"K": 2.0, "Ti": 4.0, "Td": 0.5})
    {'Kp': 2.0, 'Ki': 0.5, 'Kd': 1.0}
    >>> to_form("ideal", {"Kp": 2.0, "Ki": 0.5})
    {'Kp': 2.0, 'Ti': 4.0}
    """
    g = dict(gains)
    if "K" in g and "Kp" not in g:
        g["Kp"] = g.pop("K")
    mine, other = (PARALLEL, IDEAL) if form == "parallel" else (IDEAL, PARALLEL)
    names = set(g)
    if names <= set(mine) or not names <= set(other):
        return g
    if "Kp" not in g:  # Ti/Td without a gain cannot be converted; leave the names to be reported
        return g
    return equivalent("ideal" if form == "parallel" else "parallel", g)


def gain_unit(name: str, out_unit: str, in_unit: str) -> str:
    """The unit of a PID gain for a loop driving ``out_unit`` from a measurement in ``in_unit`` ("" if unknown).

    Examples
    --------
    >>> gain_unit("Ki", "V", "rad/s")
    'V/((rad/s)·s)'
    >>> gain_unit("Ti", "", "")
    's'
    """
    if name in ("Ti", "Td"):
        return "s"
    if not out_unit or not in_unit or "-" in (out_unit, in_unit):
        return ""
    den = f"({in_unit})" if "/" in in_unit or " " in in_unit else in_unit
    if name == "Kp":
        return f"{out_unit}/{den}"
    if name == "Ki":
        return f"{out_unit}/({den}·s)"
    if name == "Kd":
        return f"{out_unit}·s/{den}"
    return ""
