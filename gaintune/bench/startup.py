"""``gaintune bench startup``: how fast the tool answers, end to end, side by side with ``python -c pass``.

Each command runs as a fresh process ``--repeat`` times, after a warm-up as a user's installation
has it: gaintune's bytecode is compiled (``compileall``, as ``pip install`` does; with
``PYTHONDONTWRITEBYTECODE=1``, set on this project's machine, Python would otherwise recompile
every gaintune module in every process, ~0.07 s per ``verify``) and one run of every command fills
numba's compile cache. The table gives the median and the minimum wall time, and the median minus
``python -c pass`` (the interpreter's own start-up on this machine, measured in the same run); the
machine's load average before and after is printed beside it (the machine is shared: compare
figures taken side by side). Targets (issue 13): ``gaintune --help`` <= 0.3 s,
``import gaintune.verify`` <= 0.4 s, ``gaintune verify`` of a PI loop <= 0.8 s, ``gaintune tune``
of a PI loop at 3,000 simulations <= 3 s. Where the time goes: docs/benchmarks.md, "Start-up".
"""

from __future__ import annotations

import argparse
import compileall
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gaintune.bench.compare import md_table, write_outputs
from gaintune.bench.references import default_out_dir

__all__ = ["commands", "main"]

SPEC = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
        "scenario": {"dt": 0.05, "horizon": 20}, "search": {"budget": 3000, "seed": 0}}
GAINS = {"loop0": {"Kp": 1.14, "Ki": 0.454}}


def commands(folder: Path) -> dict[str, list[str]]:
    """name -> argv of every measured command (files written into ``folder``)."""
    spec, gains = folder / "pi.json", folder / "gains.json"
    spec.write_text(json.dumps(SPEC))
    gains.write_text(json.dumps(GAINS))
    exe = shutil.which("gaintune") or str(Path(sys.executable).with_name("gaintune"))
    py = sys.executable
    return {
        "python -c pass": [py, "-c", "pass"],
        "gaintune --help": [exe, "--help"],
        "import gaintune.verify": [py, "-c", "import gaintune.verify"],
        "gaintune verify (PI loop)": [exe, "verify", str(spec), "--gains", str(gains)],
        "gaintune tune (PI loop, 3,000 sims)": [exe, "tune", str(spec), "--out", str(folder / "out")],
    }


def compile_bytecode() -> None:
    """Compile gaintune's bytecode, as installing the package does (a no-op when it is up to date)."""
    compileall.compile_dir(str(Path(__file__).resolve().parents[1]), quiet=1)  # the gaintune package


def _wall(argv: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
    return time.perf_counter() - t0


def _load(avg: tuple[float, float, float]) -> str:
    return ", ".join(f"{x:.2f}" for x in avg)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="gaintune bench startup", description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="timed runs per command (default 5)")
    ap.add_argument("--out", type=Path, help="output folder (default: bench/results)")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        cmds = commands(Path(tmp))
        times = {name: [] for name in cmds}
        compile_bytecode()  # warm-up: gaintune's bytecode, as an installed package has it
        for name, cmd in cmds.items():
            _wall(cmd)  # warm-up: OS file cache, numba's on-disk cache
        for _ in range(args.repeat):  # interleaved, so load changes hit every command alike
            for name, cmd in cmds.items():
                times[name].append(_wall(cmd))
    load1 = os.getloadavg()
    base = float(np.median(times["python -c pass"]))
    rows = [[name, float(np.median(t)), float(np.min(t)), float(np.median(t)) - base] for name, t in times.items()]
    table = md_table(["command", "median s", "min s", "median - python -c pass, s"], rows)
    load = f"load average (1, 5, 15 min) before {_load(load0)}, after {_load(load1)}; gaintune bytecode compiled in the warm-up"
    print(table)
    print(load)
    _, md = write_outputs({"rows": rows, "repeat": args.repeat, "load_before": load0, "load_after": load1},
                          args.out or default_out_dir(), "startup",
                          f"# gaintune bench startup --repeat {args.repeat}\n\n{table}\n\n{load}\n")
    print(f"wrote {md}")
    return 0
