"""EagerAdam (gaintune/search/eager_optim.py): the RL agent trains without importing torch._dynamo,
and its weights and the tuned gains are bit-identical to torch's stock Adam path."""

from __future__ import annotations

import json
import os
import subprocess
import sys

#: A short PPO tune, then training continued from its saved agent (loading restores the optimizer
#: state); prints both answers, a digest of each saved policy and whether torch._dynamo was imported.
PROBE = """
import hashlib, json, sys, tempfile
from pathlib import Path
from gaintune import load_spec, tune
from gaintune.search.agents import load_agent

def digest(path):
    agent = load_agent(path)
    h = hashlib.sha256()
    for p in agent.policy.parameters():
        h.update(p.detach().numpy().tobytes())
    return h.hexdigest(), type(agent.policy.optimizer).__name__

spec = {"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
        "scenario": {"dt": 0.05, "horizon": 20}, "search": {"budget": 600, "seed": 3, "n_envs": 16, "refine": False}}
with tempfile.TemporaryDirectory() as tmp:
    first = tune(load_spec(spec), out_dir=Path(tmp) / "a", verify=False)
    spec["search"]["budget"] = 300  # learning on: continue from the saved agent and its optimizer state
    again = tune(load_spec(spec), out_dir=Path(tmp) / "b", verify=False, warm_start=Path(tmp) / "a" / "agent.zip")
    out = {"gains": [first.gains, again.gains], "agents": [digest(Path(tmp) / d / "agent.zip") for d in "ab"],
           "dynamo": "torch._dynamo" in sys.modules}
print(json.dumps(out))
"""


def _run(stock: bool) -> dict:
    env = dict(os.environ, GAINTUNE_TORCH_DYNAMO="1" if stock else "0")
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, check=True,
                         timeout=600).stdout
    return json.loads(out.strip().splitlines()[-1])


def test_eager_adam_trains_bit_identically_without_loading_dynamo() -> None:
    fast, stock = _run(stock=False), _run(stock=True)
    assert not fast["dynamo"] and stock["dynamo"]
    assert [opt for _, opt in fast["agents"]] == ["EagerAdam", "EagerAdam"]
    assert [opt for _, opt in stock["agents"]] == ["Adam", "Adam"]
    assert [w for w, _ in fast["agents"]] == [w for w, _ in stock["agents"]]  # bit-identical weights
    assert fast["gains"] == stock["gains"]


def test_eager_adam_falls_back_to_torchs_step_when_torch_is_laid_out_differently(monkeypatch) -> None:
    """An agent saved with EagerAdam and loaded under a torch whose Adam.step has no plain inner step
    must still train: EagerAdam then runs torch's own step (same update)."""
    import torch

    from gaintune.search import eager_optim

    def one_step(cls):
        torch.manual_seed(0)
        w = torch.nn.Parameter(torch.randn(4))
        opt = cls([w], lr=0.1, eps=1e-5)
        (w ** 2).sum().backward()
        opt.step()
        return w.detach().clone()

    fast = one_step(eager_optim.EagerAdam)
    monkeypatch.setattr(eager_optim, "_ADAM_STEP", None)
    assert torch.equal(one_step(eager_optim.EagerAdam), fast)
    assert torch.equal(one_step(torch.optim.Adam), fast)
