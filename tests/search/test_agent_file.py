"""Agent files are read as weights only (gaintune/search/agent_file.py, agents.load_weights): nothing in a file runs.

These tests build agents on a two-dimensional bandit env (no simulator), save them as a tune does,
and tamper with the zips the way a foreign party could: pickled code in ``data`` or in a ``.pth``
member, zip bombs, weights of another algorithm or shape.
"""

from __future__ import annotations

import io
import pickle
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from agent_forgery import RunsCode, pickled_code_in_data, rewrite, torch_saved
from stable_baselines3.common.save_util import recursive_getattr
from stable_baselines3.common.vec_env import DummyVecEnv

from gaintune.errors import SpecError
from gaintune.search.agent_file import read_agent_file, save_agent
from gaintune.search.agents import ALGOS, load_weights, make_agent


class _Bandit(gym.Env):
    """One-step episodes, constant context: the shape of gaintune's gain-search env, without a simulator."""

    observation_space = gym.spaces.Box(-5.0, 5.0, (2,), dtype=np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.full(2, 0.3, dtype=np.float32), {}

    def step(self, action):
        reward = -float(np.sum((np.asarray(action) - 0.5) ** 2))
        return np.full(2, 0.3, dtype=np.float32), reward, True, False, {}


def _agent(algo: str, seed: int = 0):
    return make_agent(algo, DummyVecEnv([_Bandit, _Bandit]), seed, budget_steps=64)


def _trained(algo: str, path: Path) -> Path:
    agent = _agent(algo)
    agent.learn(total_timesteps=24)  # past the off-policy warm-up: every optimizer has moments
    save_agent(agent, path)
    return path


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("agents")
    return {algo: _trained(algo, folder / f"{algo}.zip") for algo in ALGOS}


def test_agent_zip_with_pickled_code_in_any_member_is_refused_and_runs_nothing(saved, tmp_path) -> None:
    """Bug (issue 24): SB3's loader unpickled the zip, so a foreign agent.zip ran code at load time."""
    marker = tmp_path / "ran"
    good = saved["ppo"]
    forged = {
        "policy.pth": rewrite(good, tmp_path / "a.zip", **{"policy.pth": torch_saved({"w": RunsCode(marker)})}),
        "policy.pth as a plain pickle": rewrite(good, tmp_path / "b.zip", **{"policy.pth": pickle.dumps(RunsCode(marker))}),
        "policy.optimizer.pth": rewrite(good, tmp_path / "c.zip", **{"policy.optimizer.pth": torch_saved(RunsCode(marker))}),
        "extra.pth": rewrite(good, tmp_path / "d.zip", **{"extra.pth": torch_saved([RunsCode(marker)])}),
    }
    for member, path in forged.items():
        with pytest.raises(SpecError) as info:
            load_weights(_agent("ppo"), path)
        assert info.value.field == "warm_start" and "not plain weights" in str(info.value), member
        assert "posix.system" in str(info.value) or "unpickling" in str(info.value)
    # a data entry that holds only pickled code and no weights: refused, nothing run
    only_data = tmp_path / "e.zip"
    with zipfile.ZipFile(only_data, "w") as z:
        z.writestr("data", pickled_code_in_data(good, marker))
    with pytest.raises(SpecError, match="holds no policy weights"):
        load_weights(_agent("ppo"), only_data, field="agent")
    assert not marker.exists()


def test_pickled_code_in_the_data_entry_is_never_decoded(saved, tmp_path) -> None:
    """The data JSON's cloudpickled entries are ignored: the genuine weights load and the code does not run."""
    marker = tmp_path / "ran"
    path = rewrite(saved["sac"], tmp_path / "sac.zip", data=pickled_code_in_data(saved["sac"], marker))
    agent = load_weights(_agent("sac"), path)
    reference = load_weights(_agent("sac"), saved["sac"])
    obs = np.array([[0.3, 0.3]], dtype=np.float32)
    assert np.array_equal(agent.predict(obs, deterministic=True)[0], reference.predict(obs, deterministic=True)[0])
    assert not marker.exists()


@pytest.mark.parametrize("algo", list(ALGOS))
def test_saved_agent_round_trip_is_identical_to_the_sb3_loader(saved, algo: str) -> None:
    """gaintune's own saves load as before: the same weights, optimizer moments and answers as SB3's ``load``
    gives for the same (trusted, just written) file."""
    ours = load_weights(_agent(algo, seed=7), saved[algo])
    theirs = ALGOS[algo].load(saved[algo], device="cpu")  # our own file, written above: trusted
    for a, b in zip(ours.policy.state_dict().values(), theirs.policy.state_dict().values(), strict=True):
        assert torch.equal(a, b)
    for name in ours._get_torch_save_params()[0][1:]:
        mine, sb3 = recursive_getattr(ours, name), recursive_getattr(theirs, name)
        for sa, sb in zip(mine.state_dict()["state"].values(), sb3.state_dict()["state"].values(), strict=True):
            assert sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)
    obs = np.random.default_rng(0).uniform(-1, 1, (5, 2)).astype(np.float32)
    assert np.array_equal(ours.predict(obs, deterministic=True)[0], theirs.predict(obs, deterministic=True)[0])
    assert ours.num_timesteps == theirs.num_timesteps
    ours.learn(total_timesteps=8, reset_num_timesteps=False)  # learning on from the restored state


def test_weights_of_another_algorithm_or_shape_are_refused_naming_the_field(saved, tmp_path) -> None:
    with pytest.raises(SpecError, match=r"do not fit the SAC agent .*missing"):
        load_weights(_agent("sac"), saved["ppo"])
    with pytest.raises(SpecError, match="optimizer state policy.optimizer holds no moments"):
        load_weights(_agent("ppo"), saved["a2c"])  # the same policy network, RMSprop's moments
    wide = make_agent("ppo", DummyVecEnv([_Bandit]), 0, 64, {"policy_kwargs": {"net_arch": [8]}})
    with pytest.raises(SpecError, match="of another shape") as info:
        load_weights(wide, saved["ppo"], field="agent")
    assert info.value.field == "agent"


def test_non_finite_or_misshapen_state_is_refused(saved, tmp_path) -> None:
    with zipfile.ZipFile(saved["ppo"]) as z:
        policy = torch.load(io.BytesIO(z.read("policy.pth")), weights_only=True)
        optim = torch.load(io.BytesIO(z.read("policy.optimizer.pth")), weights_only=True)
    policy["log_std"] = torch.full_like(policy["log_std"], float("nan"))
    with pytest.raises(SpecError, match="non-finite"):
        load_weights(_agent("ppo"), rewrite(saved["ppo"], tmp_path / "nan.zip", **{"policy.pth": torch_saved(policy)}))
    for moment in (torch.zeros(7), torch.zeros(1).as_strided((10**12,), (0,))):  # a 10^12-element view of 4 bytes
        optim["state"][0]["exp_avg"] = moment
        path = rewrite(saved["ppo"], tmp_path / "moments.zip", **{"policy.optimizer.pth": torch_saved(optim)})
        with pytest.raises(SpecError, match="'exp_avg' that is no finite tensor of its parameter's shape"):
            load_weights(_agent("ppo"), path)
    policy["log_std"] = torch.zeros(1).as_strided((10**12,), (0,))  # refused by its shape, never scanned
    with pytest.raises(SpecError, match="1 of another shape or type"):
        load_weights(_agent("ppo"), rewrite(saved["ppo"], tmp_path / "huge.zip", **{"policy.pth": torch_saved(policy)}))


def test_agent_without_optimizer_state_loads_with_fresh_moments(saved, tmp_path) -> None:
    path = rewrite(saved["ppo"], tmp_path / "bare.zip", **{"policy.optimizer.pth": None, "data": None})
    agent = load_weights(_agent("ppo"), path)
    assert agent.policy.optimizer.state_dict()["state"] == {} and agent.num_timesteps == 0


def test_zip_bomb_and_oversized_or_foreign_files_are_refused(saved, tmp_path) -> None:
    bomb = tmp_path / "bomb.zip"
    with zipfile.ZipFile(bomb, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("policy.pth", b"\0" * (64 * 1024 * 1024))  # 64 MB of zeros in a 64 kB zip
    assert bomb.stat().st_size < 1024 * 1024
    with pytest.raises(SpecError, match="inflate to more than"):
        read_agent_file(bomb, "warm_start")
    with pytest.raises(SpecError, match="the limit is"):
        read_agent_file(saved["ppo"], "warm_start", limit=1000)
    text = tmp_path / "agent.zip"
    text.write_text("not a zip")
    with pytest.raises(SpecError, match="is not an agent saved by gaintune"):
        read_agent_file(text, "warm_start")
    with pytest.raises(SpecError, match="not a regular file"):
        read_agent_file("/dev/zero", "warm_start")
    with pytest.raises(SpecError, match="no saved agent at"):
        read_agent_file(tmp_path / "missing.zip", "agent")


def test_save_agent_replaces_a_planted_symlink_instead_of_writing_through_it(tmp_path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    link = tmp_path / "agent.zip"
    link.symlink_to(victim)
    save_agent(_agent("ppo"), link)
    assert victim.read_text() == "keep me"
    assert not link.is_symlink() and zipfile.is_zipfile(link)
    assert read_agent_file(link, "agent").shapes == ((2,), (2,))
