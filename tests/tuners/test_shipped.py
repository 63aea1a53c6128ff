"""The shipped tuners match the code that reads them: every folder loads (format, version, hash, shapes),
its gain box is the one the box code builds, it keeps its critic's arrays for ``tuner update``, and it answers
a plant of its family with a passing verdict."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gaintune.tuners import artefact
from gaintune.tuners.box import fit_box
from gaintune.tuners.build_shipped import SHIPPED
from gaintune.tuners.critic import read_critic
from gaintune.tuners.problems import problem_from_dict
from gaintune.tuners.tuner import Tuner

#: One plant of each family (physical parameters) the shipped tuner must answer with a pass.
PLANTS = {
    "fotd": {"K": 2.0, "T": 60.0, "L": 10.0},
    "sotd": {"K": 1.5, "T1": 20.0, "T2": 5.0, "L": 4.0},
    "ipd": {"K": 0.2, "T": 3.0, "L": 2.0},
    "spec": {"H0": 7.0},
}


def test_every_shipped_tuner_is_in_the_build_list_and_back():
    assert sorted(artefact.shipped_names()) == sorted(SHIPPED)


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_tuner_loads_and_matches_the_box_code(name):
    t = Tuner.load(name)
    assert t.name == name
    box = t.problem.box
    assert box is not None
    doc = json.loads((artefact.SHIPPED_DIR / name / "tuner.json").read_text())
    fresh = problem_from_dict(doc["problem"])
    fit_box(fresh)
    assert fresh.box is not None and fresh.box.slots == box.slots
    np.testing.assert_allclose(fresh.box.log_lo, box.log_lo, rtol=1e-9)
    np.testing.assert_allclose(fresh.box.log_hi, box.log_hi, rtol=1e-9)


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_tuner_answers_a_plant_of_its_family_with_a_pass(name):
    t = Tuner.load(name)
    a = t.query(PLANTS[SHIPPED[name][0]])
    assert a.verdict == "pass" and a.accepted_gains == a.gains
    v = t.artefact.validation
    assert v["passed"] == v["n"] and v["median_ratio"] < 1.1  # what the tuner was shipped with


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_tuner_keeps_its_critic_for_update(name):
    """Every shipped tuner holds its TD3 critic as arrays (what ``tuner update`` continues from instead of a fresh
    critic): the file matches the hash in tuner.json and maps (context, gains) to one value."""
    folder = artefact.SHIPPED_DIR / name
    arrays = read_critic(folder, artefact.critic_sha256(folder))
    assert arrays is not None, f"{name} has no critic.npz: rebuild it with python -m gaintune.tuners.build_shipped"
    t = Tuner.load(name)
    assert t.problem.box is not None
    n_layers = len(arrays) // 2
    assert arrays["w0"].shape[1] == t.policy.n_in + len(t.problem.box.slots)
    assert arrays[f"w{n_layers - 1}"].shape[0] == 1 and arrays[f"b{n_layers - 1}"].shape == (1,)
