"""Gain exports: JSON, YAML, a C header, a MATLAB/Octave snippet and a Python dict.

Every format carries the verdict of the verification: gains that failed are
exported only on request and are marked ``FAILED`` in the file itself.

This package renders the JSON, YAML and Python payloads and writes the files
(:func:`export_gains`, :func:`export_result`, :func:`write_exports`). Its submodules
hold the rest:

* :mod:`gaintune.export.verdict`: the verdict at a sample time (:func:`verified_dt`,
  :func:`spec_at_dt`, :func:`verdict_at_dt`, :func:`result_verdict_at_dt`,
  :func:`first_reason`). A file only claims the verdict obtained *at the dt it is
  exported for*; every format records ``dt``, ``verified_dt`` and, for failed gains,
  why they failed;
* :mod:`gaintune.export.coefficients`: the resolved controller of every loop
  (:func:`loop_coefficients`) and its discrete law (:func:`discrete_pid_tf`);
* :mod:`gaintune.export.c`: the C header, which implements exactly the simulator's
  discrete-time law for one sample time ``dt``;
* :mod:`gaintune.export.matlab`: the MATLAB/Octave file;
* :mod:`gaintune.export.schedule`: a gain schedule's C header, MATLAB file and JSON, from plain tables;
* :mod:`gaintune.export.mimo`, :mod:`~gaintune.export.mimo_c`, :mod:`~gaintune.export.mimo_matlab`: a spec with
  several plant inputs or a loop graph: the whole architecture (every loop, the wiring, the decoupler,
  the actuators) in every format;
* :mod:`gaintune.export.common`: :class:`ExportError` and helpers the modules share.

Example
-------
>>> from gaintune.spec import load_spec
>>> spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}]})
>>> text = export_gains(spec, {"loop0": {"Kp": 1.0, "Ki": 0.5}}, "c")
>>> "static inline double gt_step" in text
True
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from gaintune.export.c import to_c
from gaintune.export.coefficients import discrete_pid_tf, loop_coefficients
from gaintune.export.common import ExportError, Gains, _check_dt, _one_line, _version
from gaintune.export.matlab import to_matlab
from gaintune.export.mimo import is_mimo, mimo_payload
from gaintune.export.mimo_c import to_c_mimo
from gaintune.export.mimo_matlab import to_matlab_mimo
from gaintune.export.verdict import (
    _spec_verified_dt,
    _Stamp,
    first_reason,
    result_verdict_at_dt,
    spec_at_dt,
    verdict_at_dt,
    verified_dt,
)
from gaintune.files import write_atomic
from gaintune.spec import TuningSpec

__all__ = [
    "FORMATS", "SUFFIX", "FIRMWARE_FORMATS", "ExportError", "ExportFiles", "loop_coefficients", "discrete_pid_tf",
    "verified_dt", "spec_at_dt", "verdict_at_dt", "result_verdict_at_dt", "first_reason", "export_gains",
    "export_result", "write_exports",
]

#: Export formats and the file each is written to by :func:`write_exports`.
FORMATS: tuple[str, ...] = ("json", "yaml", "c", "matlab", "python")
SUFFIX: dict[str, str] = {"json": "gains.json", "yaml": "gains.yaml", "c": "gains.h", "matlab": "gains.m",
                          "python": "gains.py"}
#: Formats that are pasted into controllers as they are: :func:`write_exports` writes them only for gains that passed.
FIRMWARE_FORMATS: tuple[str, ...] = ("c", "matlab", "python")


# --------------------------------------------------------------------- data


def _clean(x: Any) -> Any:
    """JSON/YAML-safe: inf -> "inf" strings, numpy scalars -> floats."""
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return "inf" if x > 0 else ("-inf" if x < 0 else "nan")
    return x


def _payload(spec: TuningSpec, gains: Gains, st: _Stamp) -> dict[str, Any]:
    if is_mimo(spec):
        return mimo_payload(spec, gains, st)
    coefs = loop_coefficients(spec, gains)
    return {
        "spec": spec.name,
        "spec_hash": spec.content_hash(),
        "verdict": st.label,
        "accepted": st.accepted,
        "dt": st.dt,
        "verified_dt": st.verified_dt,
        "reasons": st.reasons if st.verdict == "fail" else [],
        "gains": gains,
        "loops": _clean(coefs),
        "actuator": _clean({"limits": list(spec.actuator.limits) if spec.actuator.limits else None,
                            "rate_limit": spec.actuator.rate_limit}),
        "generator": f"gaintune {_version()}",
    }


def to_python(spec: TuningSpec, gains: Gains, st: _Stamp, dt: float) -> str:
    """A Python module defining ``GAINS`` (spec form) and ``LOOPS`` (resolved parallel form)."""
    p = _payload(spec, gains, st)
    # the docstring must not end early: no backslash escapes, no double quote (a name may hold '"""')
    doc = (f"Controller gains for spec '{_one_line(spec.name)}', generated by gaintune {_version()}. "
           f"{_one_line(st.banner())}.")
    doc = doc.replace("\\", "\\\\").replace('"', "'")
    return (
        f'"""{doc}"""\n\n'
        f"VERDICT = {p['verdict']!r}\n"
        f"ACCEPTED = {p['accepted']!r}\n"
        f"DT = {dt!r}\n"
        f"VERIFIED_DT = {st.verified_dt!r}\n"
        f"REASONS = {st.reasons if st.verdict == 'fail' else []!r}\n"
        f"GAINS = {json.dumps(gains, indent=4)}\n"
        f"LOOPS = {_pyrepr(p['loops'])}\n"
        + (f"ARCHITECTURE = {_pyrepr(_wiring(p))}\n" if "architecture" in p else "")
    )


def _wiring(p: dict[str, Any]) -> dict[str, Any]:
    """The wiring of a MIMO payload (the loops themselves are LOOPS)."""
    return {k: p[k] for k in ("evaluation_order", "chains", "inputs", "outputs", "W", "decoupler")}


def _pyrepr(x: Any) -> str:
    text = json.dumps(x, indent=4)
    return text.replace(": null", ": None").replace(": true", ": True").replace(": false", ": False")


def export_gains(
    spec: TuningSpec,
    gains: Gains,
    fmt: str,
    *,
    verdict: str | None = None,
    dt: float | None = None,
    prefix: str = "gt",
    verified_dt: float | None = None,
    reasons: list[str] | None = None,
) -> str:
    """Render ``gains`` of ``spec`` in format ``fmt`` (one of :data:`FORMATS`).

    ``verdict`` ("pass", "fail" or None for unverified) is the verdict obtained at sample
    time ``verified_dt`` (default: :func:`verified_dt` of ``spec``), with its ``reasons``.
    ``dt`` (default: ``verified_dt``) is the sample time the file is for. A verdict is only
    written as such when it was obtained at ``dt``; otherwise the file says the gains are
    NOT verified at ``dt`` (use :func:`export_result`, which re-verifies, to get one).
    """
    if fmt not in FORMATS:
        raise ExportError("format", f"unknown export format {fmt!r}; choose from {', '.join(FORMATS)}")
    from gaintune.classical.timescale import resolve_scenarios

    spec = resolve_scenarios(spec)  # a scenario without dt: the one derived from the plant, as tune and verify use
    vdt = None
    if verdict is not None:
        vdt = _check_dt(verified_dt) if verified_dt is not None else _spec_verified_dt(spec)
    dt = _check_dt(dt) if dt is not None else (vdt if vdt is not None else _spec_verified_dt(spec))
    st = _Stamp(verdict, dt, vdt, reasons)
    if fmt == "json":
        return json.dumps(_payload(spec, gains, st), indent=2) + "\n"
    if fmt == "yaml":
        return f"# {_one_line(st.banner())}\n" + yaml.safe_dump(_payload(spec, gains, st), sort_keys=False)
    if fmt == "c":
        return to_c_mimo(spec, gains, st, dt, prefix) if is_mimo(spec) else to_c(spec, gains, st, dt, prefix)
    if fmt == "matlab":
        return to_matlab_mimo(spec, gains, st, dt) if is_mimo(spec) else to_matlab(spec, gains, st, dt)
    return to_python(spec, gains, st, dt)


def export_result(
    result: Any,
    fmt: str,
    *,
    dt: float | None = None,
    prefix: str = "gt",
    checked: tuple[str | None, dict[str, Any] | None] | None = None,
    max_steps: int | None = None,
) -> str:
    """Export the gains of a :class:`~gaintune.search.result.TuneResult` with their verdict *at* ``dt``.

    ``dt`` defaults to the sample time the result was verified at (:func:`verified_dt`).
    At any other ``dt`` the gains are re-verified first (:func:`verdict_at_dt`); pass
    ``checked=(verdict, report)`` from an earlier :func:`result_verdict_at_dt` call with the
    same ``dt`` to skip that. Gains whose verdict at ``dt`` is not "pass" are still
    rendered (marked FAILED, with the first reason): refusing them is the caller's job.
    """
    if fmt not in FORMATS:
        raise ExportError("format", f"unknown export format {fmt!r}; choose from {', '.join(FORMATS)}")
    spec = TuningSpec.model_validate(result.spec)
    dt = verified_dt(spec) if dt is None else _check_dt(dt)
    verdict, report = checked if checked is not None else result_verdict_at_dt(result, dt, max_steps=max_steps)
    if isinstance(report, dict):
        reasons = list((report or {}).get("reasons") or [])
    else:
        reasons = list(getattr(report, "reasons", []) or [])
    return export_gains(spec, result.gains, fmt, verdict=verdict, dt=dt, prefix=prefix,
                        verified_dt=dt if verdict is not None else None, reasons=reasons)


class ExportFiles(list):
    """The paths :func:`write_exports` wrote (a list), with what it withheld and why."""

    def __init__(self, paths=(), *, verdict: str | None = None, dt: float | None = None, reason: str | None = None,
                 withheld: tuple[str, ...] = (), removed: tuple = ()) -> None:
        super().__init__(paths)
        self.verdict = verdict
        self.dt = dt
        self.reason = reason
        self.withheld = list(withheld)  # file names not written (gains.h, gains.m, ...)
        self.removed = list(removed)  # stale copies of those deleted from the folder


def write_exports(result: Any, out_dir: str | Path, formats: tuple[str, ...] = ("json", "yaml", "c", "matlab"),
                  dt: float | None = None) -> ExportFiles:
    """Write ``gains.json``, ``gains.yaml``, ``gains.h``, ``gains.m`` (and optionally ``gains.py``) into ``out_dir``.

    The verdict is the one at ``dt`` (default: the dt the result was verified at; see
    :func:`verdict_at_dt`). Unless it is "pass", only ``gains.json``/``gains.yaml`` are
    written (marked ``accepted: false``); the files that go into a controller as they are
    (:data:`FIRMWARE_FORMATS`: ``gains.h``, ``gains.m``, ``gains.py``) are withheld, and a
    stale copy of them from an earlier run in ``out_dir`` is deleted. Returns the paths
    written (an :class:`ExportFiles` list, which also names what was withheld and why).

    Each file is written atomically (:func:`gaintune.files.write_atomic`): a symlink planted
    in ``out_dir`` is replaced, never written through.
    """
    from pathlib import Path

    for fmt in formats:
        if fmt not in FORMATS:
            raise ExportError("format", f"unknown export format {fmt!r}; choose from {', '.join(FORMATS)}")
    spec = TuningSpec.model_validate(result.spec)
    dt = verified_dt(spec) if dt is None else _check_dt(dt)
    checked = result_verdict_at_dt(result, dt)
    verdict, report = checked
    ok = verdict == "pass"
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths, withheld, removed = [], [], []
    for fmt in formats:
        p = out / SUFFIX[fmt]
        if not ok and fmt in FIRMWARE_FORMATS:
            withheld.append(SUFFIX[fmt])
            if p.is_symlink() or p.is_file():  # unlink removes a link itself, never its target
                p.unlink()
                removed.append(p)
            continue
        write_atomic(p, export_result(result, fmt, dt=dt, checked=checked))
        paths.append(p)
    return ExportFiles(paths, verdict=verdict, dt=dt, reason=None if ok else (first_reason(report) or None),
                       withheld=tuple(withheld), removed=tuple(removed))
