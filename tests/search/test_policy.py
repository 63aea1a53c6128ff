"""Trained tuners (gaintune.search.policy): the saved policy's gains for other plants of its family, each verified."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from agent_forgery import RunsCode, pickled_code_in_data, rewrite, torch_saved

from gaintune import cli
from gaintune.bench import policy as P
from gaintune.errors import SpecError
from gaintune.search import tune
from gaintune.search.policy import PolicyTuner
from gaintune.spec import load_spec

# the benchmark's plant family (PI on K/(T s + 1)^2, K and T randomised), with a shorter horizon and search
FAMILY = {**P.FAMILY, "scenario": {"dt": 0.05, "horizon": 15}, "search": {"budget": 600, "n_envs": 16, "seed": 3}}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    result = tune(load_spec(FAMILY), out_dir=out)
    (out / "result.json").write_text(result.model_dump_json())
    return out


@pytest.fixture(scope="module")
def tuner(run) -> PolicyTuner:
    return PolicyTuner.from_run(run)


def test_answer_is_verified_on_the_plant_at_those_parameters(tuner: PolicyTuner) -> None:
    a = tuner.answer({"K": 1.7})
    assert a.params == {"K": 1.7, "T": 1.0} and a.outside == []
    assert a.verification.spec_hash != tuner.spec.content_hash()  # verified on the K = 1.7 plant, not the nominal one
    assert a.accepted_gains == (a.gains if a.verdict == "pass" else None)
    assert a.elapsed_ms > 0 and set(a.gains["loop0"]) == {"Kp", "Ki"}
    # the verdict is the one gaintune.verification gives those gains on that plant
    from gaintune.verification import verify

    plant_spec = load_spec({**FAMILY, "plant": {**FAMILY["plant"], "params": {"K": 1.7, "T": 1.0}}, "randomize": {}})
    assert verify(plant_spec, a.gains).verdict == a.verdict


def test_parameters_change_the_answer_and_the_grid_is_a_schedule(tuner: PolicyTuner) -> None:
    answers = tuner.schedule({"K": [0.6, 1.9], "T": [0.7, 1.5]})
    assert [a.params for a in answers] == [{"K": 0.6, "T": 0.7}, {"K": 0.6, "T": 1.5}, {"K": 1.9, "T": 0.7}, {"K": 1.9, "T": 1.5}]
    kp = [a.gains["loop0"]["Kp"] for a in answers]
    assert len(set(np.round(kp, 9))) > 1  # the context reaches the policy


def test_outside_the_training_range_is_flagged_and_still_verified(tuner: PolicyTuner) -> None:
    a = tuner.answer({"K": 3.0})
    assert a.outside == ["K"] and a.verdict in ("pass", "fail")


@pytest.mark.parametrize("params, field", [({"Z": 1.0}, "params.Z"), ({"K": float("nan")}, "params.K"), ({"K": "x"}, "params.K"),
                                           ({"T": 0.0}, "params")])
def test_unknown_or_bad_parameter_is_a_spec_error_naming_it(tuner: PolicyTuner, params, field: str) -> None:
    with pytest.raises(SpecError) as info:
        tuner.answer(params)
    assert info.value.field == field


def test_agent_of_another_spec_is_refused(run) -> None:
    other = load_spec({**FAMILY, "randomize": {"params": {"K": [0.5, 2.0]}}})  # one context value, not two
    with pytest.raises(SpecError, match="was trained on 2 tuned gains and 2 context value"):
        PolicyTuner(run / "agent.zip", other)


def test_cli_policy_table_json_and_bad_input(run) -> None:
    runner = CliRunner()
    res = runner.invoke(cli.app, ["policy", str(run), "-p", "K=0.8,1.6", "-p", "T=1"])
    assert res.exit_code in (0, 3), res.output
    assert "only PASS rows are accepted" in res.output and res.output.count("PASS") + res.output.count("FAIL") >= 2
    res = runner.invoke(cli.app, ["policy", str(run), "--json", "-p", "K=1.2"])
    docs = json.loads(res.stdout)
    assert docs[0]["params"]["K"] == 1.2 and docs[0]["verdict"] in ("pass", "fail")
    assert docs[0]["accepted_gains"] == (docs[0]["gains"] if docs[0]["verdict"] == "pass" else None)
    for args, needle in [(["-p", "Z=1"], "error: params.Z:"), (["-p", "K=abc"], "error: --param:"), (["-p", "K"], "error: --param:")]:
        res = runner.invoke(cli.app, ["policy", str(run), *args])
        assert res.exit_code == 2 and needle in res.stderr, res.output
    res = runner.invoke(cli.app, ["policy", str(run / "nope")])
    assert res.exit_code == 2 and "error: run:" in res.stderr


def _forged_run(run: Path, folder: Path, **members: bytes | None) -> Path:
    """A copy of the run folder whose agent.zip has ``members`` replaced (see agent_forgery)."""
    folder.mkdir()
    shutil.copy(run / "result.json", folder / "result.json")
    rewrite(run / "agent.zip", folder / "agent.zip", **members)
    return folder


def test_agent_zip_with_pickled_code_is_refused_and_runs_nothing(run, tmp_path) -> None:
    """Bug (issue 24): `gaintune policy` and `tune --warm-start` loaded agent.zip with SB3's loader, which
    unpickles the zip's data entry, so a foreign file ran its code."""
    marker = tmp_path / "ran"
    runner = CliRunner()
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps(FAMILY))
    code_in_data = pickled_code_in_data(run / "agent.zip", marker)
    forged = {  # member replaced -> what the refusal says
        "data": ({"data": code_in_data, "policy.pth": None}, "holds no policy weights (policy.pth)"),
        "policy.pth": ({"data": code_in_data, "policy.pth": torch_saved({"w": RunsCode(marker)})},
                       "policy.pth is not plain weights (it asks for posix.system)"),
    }
    for name, (members, needle) in forged.items():
        evil = _forged_run(run, tmp_path / name, **members)
        for args, field in [(["policy", str(evil), "-p", "K=1"], "agent"),
                            (["tune", str(spec), "--warm-start", str(evil / "agent.zip"), "--budget", "100"], "warm_start")]:
            res = runner.invoke(cli.app, args)
            assert not marker.exists(), f"{args[0]} ran code from {name}"  # code run from a loaded file: 0
            assert res.exit_code == 2 and f"error: {field}:" in res.stderr and needle in res.stderr, res.output
            assert "Traceback" not in res.output


def test_pickled_code_in_agent_data_never_runs_and_the_weights_still_answer(run, tuner: PolicyTuner, tmp_path) -> None:
    """The data entry's cloudpickled objects are never decoded: the run answers from its weights as before."""
    marker = tmp_path / "ran"
    forged = _forged_run(run, tmp_path / "forged", data=pickled_code_in_data(run / "agent.zip", marker))
    res = CliRunner().invoke(cli.app, ["policy", str(forged), "--json", "-p", "K=1.2"])
    assert not marker.exists()
    assert res.exit_code in (0, 3), res.output
    assert json.loads(res.stdout)[0]["gains"] == tuner.answer({"K": 1.2}).gains


def test_saved_agent_answers_as_sb3_loaded_it_and_still_warm_starts(run, tuner: PolicyTuner) -> None:
    """gaintune's own agent.zip: the weights-only loader gives the policy SB3's load gave (round trip), and a
    warm start on it learns on."""
    from stable_baselines3 import PPO

    reference = PPO.load(run / "agent.zip", device="cpu")  # written by the fixture's tune: trusted
    obs = np.random.default_rng(1).uniform(-1, 1, (6, 2)).astype(np.float32)
    assert np.array_equal(tuner.agent.predict(obs, deterministic=True)[0], reference.predict(obs, deterministic=True)[0])
    spec = load_spec({**FAMILY, "search": {**FAMILY["search"], "budget": 200}})
    warm = tune(spec, warm_start=run / "agent.zip", verify=False)
    assert warm.rl_sims > 0 and warm.warm_start == str(run / "agent.zip")
