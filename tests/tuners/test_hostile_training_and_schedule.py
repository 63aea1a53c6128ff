"""Hostile input to tuner training and gain schedules: a damaged resume checkpoint, a comparison on an LTI family.

The checkpoint is a real one (a tiny run stopped after its first chunk), then damaged; the tuner is a tiny one
(its figures mean nothing, every code path is the real one). Every case must be a SpecError (exit 2 in the CLI)
that names the fix, never a traceback.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml
from typer.testing import CliRunner

from gaintune import cli
from gaintune.cli import tuner as tuner_cli
from gaintune.errors import SpecError
from gaintune.spec import load_spec
from gaintune.tuners.problems import SpecProblem
from gaintune.tuners.train import TrainSettings, train

runner = CliRunner()
#: A small LTI family: PI on K/(s+1)^2, K from 0.5 to 2 (fast to simulate).
LAG2 = {"name": "lag2_family", "plant": {"tf": {"num": ["K"], "den": "(s+1)^2"}, "params": {"K": 1.0}},
        "loops": [{"type": "pi"}], "scenario": {"dt": 0.05, "horizon": 10.0},
        "randomize": {"params": {"K": [0.5, 2.0]}}}
#: Episodes of the checkpointed run: its first checkpoint (the tiny settings' chunk, 512) comes before the end.
EPISODES = 1024


def _settings(tiny: dict[str, Any], **changes: Any) -> TrainSettings:
    """The tests' tiny training sizes (the session fixture ``tiny_training``), ``EPISODES`` long."""
    return TrainSettings(**{**tiny, "episodes": EPISODES, **changes})


class _Started(Exception):
    """The training got past its start (the checkpoint was read, or was not asked for)."""


def _stop_at_start(done: int, total: int, info: dict[str, Any]) -> None:
    raise _Started


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory, tiny_training: dict) -> Path:
    """A run's checkpoint folder, left by a run stopped after its first checkpoint (a kill, for the code)."""
    out = tmp_path_factory.mktemp("ckpt") / "lag2"
    seen: list[int] = []

    def killed(done: int, total: int, info: dict[str, Any]) -> None:
        if seen:  # the first report after a checkpoint was saved
            raise KeyboardInterrupt
        if "ratio" in info:
            seen.append(done)

    with pytest.raises(KeyboardInterrupt):
        train(SpecProblem(load_spec(LAG2)), out, _settings(tiny_training), on_progress=killed)
    folder = out.with_name(f".{out.name}.training")
    assert seen and (folder / "state.json").is_file() and (folder / "agent.zip").is_file()
    return folder


@pytest.fixture
def damaged(checkpoint: Path, tmp_path: Path) -> Callable[[Callable[[Path], None]], Path]:
    """``damaged(harm)``: a copy of the checkpoint for the output folder ``tmp_path/lag2``, ``harm(copy)`` done."""

    def make(harm: Callable[[Path], None]) -> Path:
        copy = tmp_path / checkpoint.name
        shutil.copytree(checkpoint, copy)
        harm(copy)
        return tmp_path / "lag2"

    return make


def _edit_state(change: Callable[[dict[str, Any]], Any]) -> Callable[[Path], None]:
    def harm(folder: Path) -> None:
        state = json.loads((folder / "state.json").read_text())
        (folder / "state.json").write_text(json.dumps(change(state)))

    return harm


def _write_state(text: str) -> Callable[[Path], None]:
    return lambda folder: (folder / "state.json").write_text(text)


def _assert_damaged_advice(exc: SpecError, folder: Path) -> None:
    assert exc.field == "resume" and str(folder) in exc.message and "damaged" in exc.message, exc.message
    assert "delete that folder" in exc.message and "--no-resume" in exc.message, exc.message


@pytest.mark.parametrize("harm", [
    _edit_state(lambda s: {**s, "episodes": "abc"}),
    _edit_state(lambda s: {k: v for k, v in s.items() if k != "episodes"}),
    _edit_state(lambda s: {**s, "curve": [{"episodes": "x"}]}),
    _write_state("{not json"),
    _write_state("[1, 2, 3]"),
    _write_state("[" * 100_000),
], ids=["episodes-abc", "episodes-missing", "curve-point-bad", "not-json", "json-list", "nested-too-deep"])
def test_damaged_checkpoint_state_crashed_the_resumed_run_in_start_state(damaged, harm, tiny_training: dict) -> None:
    """Before: 'episodes' as "abc" or missing crashed _start_state (ValueError, KeyError); a state.json that was
    no JSON or a JSON list was ignored, and the run silently started afresh over the checkpoint."""
    out = damaged(harm)
    problem = SpecProblem(load_spec(LAG2))
    with pytest.raises(SpecError) as e:
        train(problem, out, _settings(tiny_training), on_progress=_stop_at_start)
    _assert_damaged_advice(e.value, out.with_name(".lag2.training"))
    with pytest.raises(_Started):  # the advice works: without resuming, the run starts
        train(problem, out, _settings(tiny_training), on_progress=_stop_at_start, resume=False)


def test_corrupt_checkpoint_agent_zip_advised_giving_the_agent_zip_a_tune_wrote(damaged, tiny_training: dict) -> None:
    """Before: random bytes as the checkpoint's agent.zip said "give the agent.zip a tune wrote with --out", advice
    about another command's file, instead of saying the checkpoint is damaged and how to start afresh."""
    out = damaged(lambda folder: (folder / "agent.zip").write_bytes(os.urandom(4096)))
    with pytest.raises(SpecError) as e:
        train(SpecProblem(load_spec(LAG2)), out, _settings(tiny_training), on_progress=_stop_at_start)
    _assert_damaged_advice(e.value, out.with_name(".lag2.training"))
    assert "a tune wrote" not in e.value.message and "agent.zip" in e.value.message


def test_damaged_checkpoint_crashed_tuner_train_with_a_traceback(damaged, monkeypatch, tiny_training: dict,
                                                                  tmp_path: Path) -> None:
    """Before: 'gaintune tuner train' over a checkpoint whose state.json had "episodes": "abc" ended in a
    ValueError traceback from _start_state instead of exit 2 naming the checkpoint."""
    monkeypatch.setattr(tuner_cli, "TRAIN_DEFAULTS", tiny_training)
    out = damaged(_edit_state(lambda s: {**s, "episodes": "abc"}))
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump(LAG2, sort_keys=False))
    res = runner.invoke(cli.app, ["tuner", "train", str(spec), "--out", str(out), "--episodes", str(EPISODES)])
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    assert f"error: resume: the checkpoint {out.with_name('.lag2.training')} is damaged" in res.stderr, res.stderr
    assert "--no-resume" in res.stderr and not out.exists()


# ------------------------------------------------------------------------------- schedule --compare, LTI


@pytest.fixture(scope="module")
def lti_tuner(tmp_path_factory, tiny_training: dict) -> Path:
    """A spec tuner of the LTI family LAG2 over K, trained for one rollout (32 episodes)."""
    out = tmp_path_factory.mktemp("lti") / "lag2"
    return train(SpecProblem(load_spec(LAG2)), out, _settings(tiny_training, episodes=32))


def test_schedule_compare_on_an_lti_tuner_crashed_in_rk4(lti_tuner: Path, tmp_path: Path) -> None:
    """Before: 'tuner schedule DIR --var K --grid ... --compare' on an LTI spec tuner crashed in sweep.py's rk4
    (ValueError: the scheduled simulation steps ODE plants only), after writing the schedule's files."""
    out = tmp_path / "sched"
    res = runner.invoke(cli.app, ["tuner", "schedule", str(lti_tuner), "--var", "K", "--grid", "0.5:2:3",
                                  "--compare", "--out", str(out)])
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    assert "error: compare: the comparison with a fixed PI sweeps a nonlinear plant's operating range" in res.stderr
    assert "without --compare" in res.stderr and not out.exists()  # refused before anything was written


def test_best_fixed_pi_and_compare_fixed_on_an_lti_schedule_crashed_in_rk4() -> None:
    """Before: best_fixed_pi searched an LTI schedule's fixed PI, then compare_fixed crashed in sweep.py's rk4
    with a ValueError instead of a SpecError naming compare."""
    from gaintune.tuners.schedule import best_fixed_pi, build_schedule, compare_fixed

    gains = {"Kp": 0.5, "Ki": 0.3}
    schedule = build_schedule(load_spec(LAG2), "K", [0.5, 1.0, 2.0], lambda spec: {spec.loop_names[0]: gains})
    for call in (lambda: best_fixed_pi(schedule, budget=8), lambda: compare_fixed(schedule, gains)):
        with pytest.raises(SpecError) as e:
            call()
        assert e.value.field == "compare" and "LTI" in e.value.message, e.value.message
