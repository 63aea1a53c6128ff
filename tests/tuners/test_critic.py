"""A tuner folder without its torch agent (the shipped ones) keeps the TD3 critic as arrays, and
``tuner update`` starts from both the actor and the critic, with no critic-only warm-up."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gaintune.errors import SpecError
from gaintune.tuners import artefact
from gaintune.tuners.critic import FILE, critic_arrays, read_critic
from gaintune.tuners.env import ContextBanditVecEnv
from gaintune.tuners.problems import FamilyProblem
from gaintune.tuners.train import CRITIC_WARMUP, TrainSettings, _make_agent, _warm_agent, _warm_box, train

TINY = TrainSettings(episodes=256, n_envs=32, contexts_per_step=4, chunk=256, batch_size=64, validation=2,
                     curve_contexts=2)


@pytest.fixture(scope="module")
def shipped_like(tmp_path_factory):
    """A tuner trained as the shipped ones are: no agent.zip."""
    out = tmp_path_factory.mktemp("critic") / "fotd_small"
    return train(FamilyProblem("fotd", "pi", 1.4), out, TINY, keep_agent=False)


def _fresh_agent(folder):
    p = FamilyProblem("fotd", "pi", 1.4)
    _warm_box(p, folder)
    return _make_agent(ContextBanditVecEnv(p, TINY.n_envs, TINY.contexts_per_step, seed=1),
                       TrainSettings(**{**TINY.__dict__, "seed": 1}))


def test_folder_without_agent_keeps_the_critic_arrays_with_their_hash(shipped_like):
    assert not (shipped_like / "agent.zip").exists() and (shipped_like / FILE).is_file()
    doc = json.loads((shipped_like / "tuner.json").read_text())
    assert doc["critic"]["file"] == FILE and artefact.critic_sha256(shipped_like) == doc["critic"]["sha256"]


def test_update_from_a_shipped_folder_starts_the_trained_critic_without_a_critic_only_warm_up(shipped_like):
    agent = _fresh_agent(shipped_like)
    before = critic_arrays(agent)
    saved = read_critic(shipped_like, artefact.critic_sha256(shipped_like))
    assert before is not None and saved is not None
    assert any(not np.array_equal(before[k].astype(np.float32), saved[k]) for k in saved)  # a fresh critic differs
    assert _warm_agent(agent, shipped_like) == 0
    for q in list(agent.policy.critic.q_networks) + list(agent.policy.critic_target.q_networks):
        w = [m.weight.detach().numpy() for m in q if hasattr(m, "weight")]
        for i, wi in enumerate(w):
            np.testing.assert_array_equal(wi, saved[f"w{i}"])


def test_update_from_a_folder_without_critic_arrays_warms_a_fresh_critic_up_first(shipped_like, tmp_path):
    old = tmp_path / "old_style"
    old.mkdir()
    doc = json.loads((shipped_like / "tuner.json").read_text())
    doc.pop("critic")
    (old / "tuner.json").write_text(json.dumps(doc))
    (old / "policy.npz").write_bytes((shipped_like / "policy.npz").read_bytes())
    assert _warm_agent(_fresh_agent(old), old) == CRITIC_WARMUP


def test_tampered_critic_arrays_are_refused_by_their_hash(shipped_like, tmp_path):
    bad = tmp_path / "tampered"
    bad.mkdir()
    for f in ("tuner.json", "policy.npz"):
        (bad / f).write_bytes((shipped_like / f).read_bytes())
    raw = bytearray((shipped_like / FILE).read_bytes())
    raw[-40] ^= 0xFF
    (bad / FILE).write_bytes(bytes(raw))
    with pytest.raises(SpecError, match="critic.npz does not match the hash"):
        _warm_agent(_fresh_agent(bad), bad)


def test_an_update_takes_more_gradient_steps_per_simulation_than_a_cold_start(shipped_like, tmp_path):
    """Before, an update learned as slowly per simulation as a cold start (2.5x fewer simulations, not 5x)."""
    from gaintune.tuners.train import UPDATE_GRADIENT_STEPS

    small = TrainSettings(**{**TINY.__dict__, "episodes": 64, "chunk": 64})
    out = train(FamilyProblem("fotd", "pi", 1.4), tmp_path / "upd", small, warm_start=shipped_like, resume=False)
    settings = artefact.load(out).training["settings"]
    assert UPDATE_GRADIENT_STEPS > TINY.gradient_steps
    assert settings["gradient_steps"] == UPDATE_GRADIENT_STEPS and settings["noise_start"] <= 0.05
    assert artefact.load(shipped_like).training["settings"]["gradient_steps"] == TINY.gradient_steps
