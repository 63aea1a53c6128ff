"""``gaintune bench startup``: how fast the tool answers, end to end, side by side with ``python -c pass``.

Each command runs as a fresh process ``--repeat`` times, after a warm-up as a user's installation
has it: gaintune's bytecode is compiled (``compileall``, as ``pip install`` does; with
``PYTHONDONTWRITEBYTECODE=1``, set on this project's machine, Python would otherwise recompile
every gaintune module in every process, ~0.07 s per ``verify``) and one run of every command fills
numba's compile cache. The table gives the median and the minimum wall time, and the median minus
``python -c pass`` (the interpreter's own start-up on this machine, measured in the same run); the
machine's load average before and after is printed beside it (the machine is shared: compare
figures taken side by side). Targets (issue 13): ``gaintune --help`` <= 0.3 s,
``import gaintune.verification`` <= 0.4 s, ``gaintune verify`` of a PI loop <= 0.8 s, ``gaintune tune``
of a PI loop at 3,000 simulations <= 3 s. Four more rows show what that last figure is made of:
the same tune without ``--out`` (no report or exports written), a 100-simulation tune (the cost
every tune pays before its search: imports, rules, search box, verification, report),
``import stable_baselines3`` (the chosen learner and torch, on their own) and the learner's floor:
gaintune's PPO trained for the tune's 800 gradient steps on idle environments (:data:`LEARNER_FLOOR`),
which no change outside the learner's defaults can take below. Where the time goes:
docs/benchmarks.md, "Start-up".

``--before DIR`` measures an older checkout beside this one, interleaved in the same run (e.g.
``git worktree add /tmp/before <rev>``): both run as ``python -m gaintune`` with ``PYTHONPATH``
set to their own tree, and the table adds the before figures and the after/before ratio.

``--cold-cache`` measures the first run after an install instead (issue 25): ``gaintune demo``
on an empty numba cache (``NUMBA_CACHE_DIR`` a fresh folder for every run, so the simulator
compiles) and on a warm one (a folder filled by a warm-up run), interleaved. It reports wall
time and CPU seconds of the command and every process it started (the compile runs in child
processes): on a shared machine the CPU seconds are the steadier figure. Target: the cold demo
<= 25 s on 2 cores, the warm one unchanged.
"""

from __future__ import annotations

import compileall
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gaintune.bench.arguments import BenchParser, add_out_argument, positive_int, resolve_out
from gaintune.bench.compare import md_table, write_outputs

__all__ = ["commands", "main"]

SPEC: dict[str, Any] = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
        "scenario": {"dt": 0.05, "horizon": 20}, "search": {"budget": 3000, "seed": 0}}
GAINS = {"loop0": {"Kp": 1.14, "Ki": 0.454}}

#: The learner's share of the 3,000-sim tune on its own, in a fresh process: ``gaintune.search``
#: imported (torch, SB3, and the result and verification types every tune loads, ~0.25 s), gaintune's PPO
#: (default hyper-parameters, ``EagerAdam``) built on 32 do-nothing environments
#: shaped like the PI problem's (1 observation, 2 gains) and trained for the 80 updates of 10
#: gradient steps that the tune runs (its RL budget is 2,592 simulations: 81 batches of 32, and the
#: last batch ends the search before an update). No plant, simulation, repair or verification: any
#: 3,000-sim PPO tune with these defaults costs at least this plus numba's start (see the verify rows).
LEARNER_FLOOR = """
import numpy as np, gymnasium as gym
from stable_baselines3.common.vec_env import DummyVecEnv
from gaintune.search.agents import make_agent
class Idle(gym.Env):
    observation_space = gym.spaces.Box(-5.0, 5.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    def reset(self, seed=None, options=None):
        return np.zeros(1, np.float32), {}
    def step(self, action):
        return np.zeros(1, np.float32), -float(np.sum(np.square(action))), True, False, {}
agent = make_agent("ppo", DummyVecEnv([Idle] * 32), 0, 2560)
agent.learn(total_timesteps=2560)
assert agent._n_updates == 800, agent._n_updates
"""


#: The verification package's import; a ``--before`` checkout older than its rename has it as gaintune.verify
#: (asked of the tree's folder: an editable install would otherwise answer with this tree's package).
IMPORT_VERIFICATION = ("import os, gaintune\n"
                       "if os.path.isdir(os.path.join(os.path.dirname(gaintune.__file__), 'verification')):\n"
                       "    import gaintune.verification\n"
                       "else:\n"
                       "    import gaintune.verify")


def commands(folder: Path, module: bool = False) -> dict[str, list[str]]:
    """name -> argv of every measured command (files written into ``folder``).

    ``module``: run the CLI as ``python -m gaintune`` (the tree on ``PYTHONPATH`` answers) instead
    of the installed ``gaintune`` script."""
    spec, small, gains = folder / "pi.json", folder / "pi_100.json", folder / "gains.json"
    spec.write_text(json.dumps(SPEC))
    small.write_text(json.dumps({**SPEC, "search": {**SPEC["search"], "budget": 100}}))
    gains.write_text(json.dumps(GAINS))
    py = sys.executable
    script = shutil.which("gaintune") or str(Path(sys.executable).with_name("gaintune"))
    exe = [py, "-m", "gaintune"] if module else [script]
    return {
        "python -c pass": [py, "-c", "pass"],
        "gaintune --help": [*exe, "--help"],
        "import gaintune.verification": [py, "-c", IMPORT_VERIFICATION],
        "gaintune verify (PI loop)": [*exe, "verify", str(spec), "--gains", str(gains)],
        "gaintune tune (PI loop, 3,000 sims)": [*exe, "tune", str(spec), "--out", str(folder / "out")],
        # what the 3,000-sim figure is made of: the same tune without writing files (no report), a
        # 100-sim tune (imports, rules, search box, verification, report: the cost of any tune) and
        # the import of the chosen learner (torch + stable-baselines3) on its own
        "gaintune tune (PI loop, 3,000 sims, no --out)": [*exe, "tune", str(spec)],
        "gaintune tune (PI loop, 100 sims)": [*exe, "tune", str(small), "--out", str(folder / "out_100")],
        "import stable_baselines3": [py, "-c", "import stable_baselines3"],
        "PPO alone: 800 updates on idle envs": [py, "-c", LEARNER_FLOOR],
    }


def compile_bytecode(package: Path | None = None) -> None:
    """Compile gaintune's bytecode, as installing the package does (a no-op when it is up to date)."""
    compileall.compile_dir(str(package or Path(__file__).resolve().parents[1]), quiet=1)


def _wall(argv: list[str], env: dict[str, str] | None = None, cwd: Path | None = None) -> float:
    t0 = time.perf_counter()
    # cwd: a folder without a gaintune package, which `python -c`/`-m` would put ahead of PYTHONPATH
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False, env=env, cwd=cwd)
    return time.perf_counter() - t0


def _timed(argv: list[str], env: dict[str, str] | None, cwd: Path) -> tuple[float, float]:
    """Wall and CPU seconds of one run: the process and every process it started and waited for."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall = _wall(argv, env, cwd)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def demo_command(folder: Path, module: bool = False) -> list[str]:
    """argv of the ``--cold-cache`` command: ``gaintune demo`` writing into ``folder``."""
    script = shutil.which("gaintune") or str(Path(sys.executable).with_name("gaintune"))
    return [*([sys.executable, "-m", "gaintune"] if module else [script]), "demo", "--out", str(folder / "demo")]


def cold_cache_runs(trees: dict[str, Path | None], envs: dict[str, dict[str, str] | None], folder: Path,
                    repeat: int, module: bool) -> dict[tuple[str, str], list[tuple[float, float]]]:
    """(tree, "cold" | "warm") -> [(wall s, CPU s)] of ``gaintune demo``, ``repeat`` interleaved runs each.

    Cold: ``NUMBA_CACHE_DIR`` a new empty folder per run. Warm: one folder per tree, filled by a
    warm-up run first."""
    cmd = demo_command(folder, module)
    runs: dict[tuple[str, str], list[tuple[float, float]]] = {(k, c): [] for k in trees for c in ("cold", "warm")}
    base: dict[str, dict[str, str]] = {k: dict(envs[k] or os.environ) for k in trees}
    for k in trees:  # warm-up: fills the warm cache (and the OS file cache)
        _wall(cmd, {**base[k], "NUMBA_CACHE_DIR": str(folder / f"numba-warm-{k}")}, folder)
    for i in range(repeat):
        for k in trees:
            cold = {**base[k], "NUMBA_CACHE_DIR": str(folder / f"numba-cold-{k}-{i}")}
            runs[(k, "cold")].append(_timed(cmd, cold, folder))
            warm_env = {**base[k], "NUMBA_CACHE_DIR": str(folder / f"numba-warm-{k}")}
            runs[(k, "warm")].append(_timed(cmd, warm_env, folder))
    return runs


def cold_cache_table(runs: dict[tuple[str, str], list[tuple[float, float]]], before: bool) -> tuple[list[str], list]:
    """Header and rows of the ``--cold-cache`` table: median wall, min wall, median CPU (and after/before)."""
    def med(k: str, c: str, j: int) -> float:
        return float(np.median([r[j] for r in runs[(k, c)]]))

    rows, head = [], ["gaintune demo", "median wall s", "min wall s", "median CPU s"]
    if before:
        head += ["before median wall s", "before median CPU s", "after / before (CPU)"]
    for c in ("cold", "warm"):
        row = [f"{c} numba cache", med("after", c, 0), min(r[0] for r in runs[("after", c)]), med("after", c, 1)]
        if before:
            row += [med("before", c, 0), med("before", c, 1), med("after", c, 1) / med("before", c, 1)]
        rows.append(row)
    return head, rows


def _tree_env(tree: Path) -> dict[str, str]:
    """The environment that makes ``tree``'s gaintune the one imported (ahead of the installed one)."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(tree), os.environ.get("PYTHONPATH")]))}


def _load(avg: tuple[float, float, float]) -> str:
    return ", ".join(f"{x:.2f}" for x in avg)


def main(argv: Sequence[str] | None = None) -> int:
    ap = BenchParser(prog="gaintune bench startup", description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=positive_int, default=5, help="timed runs per command (default 5)")
    ap.add_argument("--before", type=Path, help="an older gaintune checkout to measure beside this one")
    ap.add_argument("--cold-cache", action="store_true",
                    help="time `gaintune demo` on an empty and on a warm numba cache (the first run after an install)")
    add_out_argument(ap)
    args = ap.parse_args(argv)
    if args.before is not None and not (args.before / "gaintune" / "__init__.py").is_file():
        print(f"error: --before: {args.before} holds no gaintune package (give the checkout's top folder)",
              file=sys.stderr)
        return 2
    out = resolve_out(args.out)
    here = Path(__file__).resolve().parents[2]
    trees = {"after": here, "before": args.before.resolve()} if args.before else {"after": None}
    load0 = os.getloadavg()
    envs = {k: (_tree_env(t) if t is not None else None) for k, t in trees.items()}
    if args.cold_cache:
        return _cold_cache_main(args, trees, envs, out, here, load0)
    with tempfile.TemporaryDirectory() as tmp:
        cmds = commands(Path(tmp), module=args.before is not None)
        times: dict[tuple[str, str], list[float]] = {(k, name): [] for k in trees for name in cmds}
        for t in trees.values():  # warm-up: bytecode, as an installed package has it
            compile_bytecode(t / "gaintune" if t is not None else None)
        for k in trees:
            for cmd in cmds.values():
                _wall(cmd, envs[k], Path(tmp))  # warm-up: OS file cache, numba's on-disk cache
        for _ in range(args.repeat):  # interleaved, so load changes hit every command and tree alike
            for name, cmd in cmds.items():
                for k in trees:
                    times[(k, name)].append(_wall(cmd, envs[k], Path(tmp)))
    load1 = os.getloadavg()
    med = {key: float(np.median(v)) for key, v in times.items()}
    base = med[("after", "python -c pass")]
    if args.before:
        rows = [[name, med[("before", name)], med[("after", name)], float(np.min(times[("after", name)])),
                 med[("after", name)] / med[("before", name)]] for name in cmds]
        head = ["command", "before median s", "after median s", "after min s", "after / before"]
    else:
        rows = [[name, med[("after", name)], float(np.min(times[("after", name)])), med[("after", name)] - base]
                for name in cmds]
        head = ["command", "median s", "min s", "median - python -c pass, s"]
    table = md_table(head, rows)
    load = (f"load average (1, 5, 15 min) before {_load(load0)}, after {_load(load1)}; "
            "gaintune bytecode compiled in the warm-up")
    return _publish(args, here, out, "startup", "", table, load,
                    {"rows": rows, "header": head, "repeat": args.repeat, "load_before": load0, "load_after": load1})


def _publish(args, here: Path, out: Path, stem: str, flag: str, table: str, note: str, data: dict) -> int:
    """Print the table and its note, write ``<stem>.md/.json`` with the command that made them."""
    if args.before:
        note += f"; before = {args.before}, after = {here}, both as python -m gaintune"
    print(table)
    print(note)
    before = f" --before {args.before}" if args.before else ""
    cmd = f"# gaintune bench startup{flag} --repeat {args.repeat}{before}"
    _, md = write_outputs(data, out, stem, f"{cmd}\n\n{table}\n\n{note}\n")
    print(f"wrote {md}")
    return 0


def _cold_cache_main(args, trees: dict, envs: dict, out: Path, here: Path, load0: tuple) -> int:
    """``--cold-cache``: run, print and write the cold/warm ``gaintune demo`` table."""
    for t in trees.values():  # bytecode, as an installed package has it
        compile_bytecode(t / "gaintune" if t is not None else None)
    with tempfile.TemporaryDirectory() as tmp:
        runs = cold_cache_runs(trees, envs, Path(tmp), args.repeat, module=args.before is not None)
    load1 = os.getloadavg()
    head, rows = cold_cache_table(runs, args.before is not None)
    table = md_table(head, rows)
    note = (f"load average (1, 5, 15 min) before {_load(load0)}, after {_load(load1)}; {os.cpu_count()} CPUs; "
            "CPU s = user + system of the command and the processes it started")
    return _publish(args, here, out, "startup_cold", " --cold-cache", table, note,
                    {"rows": rows, "header": head, "repeat": args.repeat, "load_before": load0, "load_after": load1,
                     "runs": {f"{k}/{c}": v for (k, c), v in runs.items()}})


if __name__ == "__main__":
    raise SystemExit(main())
