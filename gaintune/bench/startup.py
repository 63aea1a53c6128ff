"""``gaintune bench startup``: how fast the tool answers, end to end, side by side with ``python -c pass``.

Each command runs as a fresh process ``--repeat`` times (after one warm-up run that also fills
numba's compile cache); the table gives the median and the minimum wall time, and the median
minus ``python -c pass`` (the interpreter's own start-up on this machine, measured in the same
run). Targets (issue 13): ``gaintune --help`` <= 0.3 s, ``import gaintune.verify`` <= 0.4 s,
``gaintune verify`` of a PI loop <= 0.8 s, ``gaintune tune`` of a PI loop at 3,000 simulations
<= 3 s.
"""

from __future__ import annotations

import argparse
import json
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


def _wall(argv: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
    return time.perf_counter() - t0


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="gaintune bench startup", description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="timed runs per command (default 5)")
    ap.add_argument("--out", type=Path, help="output folder (default: bench/results)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        cmds = commands(Path(tmp))
        times = {name: [] for name in cmds}
        for name, cmd in cmds.items():
            _wall(cmd)  # warm-up: OS file cache, numba's on-disk cache
        for _ in range(args.repeat):  # interleaved, so load changes hit every command alike
            for name, cmd in cmds.items():
                times[name].append(_wall(cmd))
    base = float(np.median(times["python -c pass"]))
    rows = [[name, float(np.median(t)), float(np.min(t)), float(np.median(t)) - base] for name, t in times.items()]
    table = md_table(["command", "median s", "min s", "median - python -c pass, s"], rows)
    print(table)
    _, md = write_outputs({"rows": rows, "repeat": args.repeat}, args.out or default_out_dir(), "startup",
                          f"# gaintune bench startup --repeat {args.repeat}\n\n{table}\n")
    print(f"wrote {md}")
    return 0
