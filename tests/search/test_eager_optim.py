"""EagerAdam (gaintune/search/eager_optim.py): the RL agent trains without importing torch._dynamo,
and its weights and the tuned gains are bit-identical to torch's stock Adam path."""

from __future__ import annotations

import os

#: A short PPO tune, then training continued from its saved agent (loading restores the optimizer
#: state); prints both answers, a digest of each saved policy and whether torch._dynamo was imported.
PROBE = """
import hashlib, json, sys, tempfile
from pathlib import Path
from gaintune import load_spec, tune
from gaintune.search.agents import load_agent

def digest(path):
    agent = load_agent(path, load_spec(spec))
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


def test_eager_adam_trains_bit_identically_without_loading_dynamo(fresh_python) -> None:
    fast, stock = (fresh_python(PROBE, env=dict(os.environ, GAINTUNE_TORCH_DYNAMO=flag), timeout=600) for flag in "01")
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


def _policy_like_params(seed: int):
    """The parameter shapes of a PPO MlpPolicy on a 3-dim observation and a 2-dim action."""
    import torch

    g = torch.Generator().manual_seed(seed)
    shapes = [(64, 3), (64,), (64, 64), (64,), (64, 3), (64,), (64, 64), (64,), (2, 64), (2,), (1, 64), (1,), (2,)]
    return [torch.nn.Parameter(torch.randn(s, generator=g)) for s in shapes]


def _train(opt, params, steps: int, seed: int) -> None:
    import torch

    g = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        opt.zero_grad()
        for p in params:
            p.grad = torch.randn(p.shape, generator=g) * 0.1
        opt.step()


def test_flat_step_matches_torch_adam_bit_for_bit_and_survives_a_state_dict_round_trip() -> None:
    """The flat update (one op per moment for all parameters) against torch's per-tensor Adam: the
    weights and the optimizer state agree exactly, also after saving and loading the state."""
    import io

    import torch

    from gaintune.search.eager_optim import EagerAdam

    runs = {}
    for cls in (EagerAdam, torch.optim.Adam):
        params = _policy_like_params(0)
        opt = cls(params, lr=3e-3, eps=1e-5)
        _train(opt, params, 300, seed=1)
        buf = io.BytesIO()
        torch.save(opt.state_dict(), buf)
        if cls is EagerAdam:
            assert opt._flat is not None  # the flat path ran
        params2 = [torch.nn.Parameter(p.detach().clone()) for p in params]
        opt2 = cls(params2, lr=3e-3, eps=1e-5)
        buf.seek(0)
        opt2.load_state_dict(torch.load(buf))
        _train(opt2, params2, 50, seed=2)
        state = opt2.state_dict()["state"]
        runs[cls.__name__] = (params, params2, state)
    (p1, q1, s1), (p2, q2, s2) = runs["EagerAdam"], runs["Adam"]
    assert all(torch.equal(a, b) for a, b in zip(p1 + q1, p2 + q2))
    assert s1.keys() == s2.keys()
    for k in s1:
        assert all(torch.equal(s1[k][name], s2[k][name]) for name in ("step", "exp_avg", "exp_avg_sq"))


def test_flat_step_leaves_other_cases_to_torch() -> None:
    """Weight decay (or amsgrad, several groups...) is not the plain case: torch's own step runs."""
    import torch

    from gaintune.search.eager_optim import EagerAdam

    a, b = _policy_like_params(0), _policy_like_params(0)
    fast, stock = EagerAdam(a, lr=1e-2, weight_decay=1e-3), torch.optim.Adam(b, lr=1e-2, weight_decay=1e-3)
    _train(fast, a, 20, seed=1)
    _train(stock, b, 20, seed=1)
    assert fast._flat is None
    assert all(torch.equal(x, y) for x, y in zip(a, b))
