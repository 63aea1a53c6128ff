"""``direction: auto`` behind a static decoupler reads the path through the decoupler's column (issue 28).

The plant ``G(s) = B/(s + 1)`` with ``B = [[1, 2], [1, 1]]`` has positive diagonal gains, but its
steady-state decoupler ``W = [[1, -2], [-1, 1]]`` (``G W`` diagonal) makes both loops' paths
``G W = -I/(s + 1)``: a negative pairing's decoupler flips both signs. The old rule read ``G11`` and
``G22`` (direct) and gave loops whose closed loops are unstable.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest

from gaintune.controllers.direction import resolve_directions
from gaintune.errors import SpecError
from gaintune.sim import Simulator
from gaintune.spec import load_spec

DECOUPLER = {"inputs": ["u1", "u2"], "matrix": [[1.0, -2.0], [-1.0, 1.0]]}
TUNED = {"inputs": ["u1", "u2"], "matrix": [[1.0, {"bounds": [-4.0, -1.0]}], [{"value": -1.0, "bounds": [-2.0, -0.5]},
                                                                              1.0]]}
MAGS = {"Kp": 1.0, "Ki": 1.0}


def negative_pairing(decoupler: dict | None, direction: str = "auto") -> dict[str, Any]:
    """Two PI loops (a: y1 by u1, b: y2 by u2) on ``B/(s + 1)``, a steps, over 40 s."""
    d: dict[str, Any] = {
        "plant": {"ss": {"A": [[-1.0, 0.0], [0.0, -1.0]], "B": [[1.0, 2.0], [1.0, 1.0]], "C": [[1, 0], [0, 1]],
                         "inputs": ["u1", "u2"], "outputs": ["y1", "y2"]}},
        "loops": [{"name": "a", "measure": "y1", "drives": "u1", "type": "pi", "direction": direction},
                  {"name": "b", "measure": "y2", "drives": "u2", "type": "pi", "direction": direction}],
        "scenarios": [{"name": "s", "dt": 0.05, "horizon": 40.0, "reference": {"loop": "a"}}],
        "requirements": {"mks_max": None, "gm_min_db": None, "pm_min_deg": None, "ms_max": None},
    }
    if decoupler is not None:
        d["decoupler"] = copy.deepcopy(decoupler)
    return d


def _run(d: dict[str, Any]) -> dict[str, np.ndarray]:
    sim = Simulator(load_spec(d))
    signs = sim.layout.directions
    gains = {n: {k: s * v for k, v in MAGS.items()} for n, s in zip(("a", "b"), signs, strict=True)}
    return sim.run(sim.layout.from_dict(gains)[None]).metrics


def test_auto_direction_ignoring_the_decoupler_picked_an_unstable_sign() -> None:
    # without the decoupler the loops are direct (G11 = G22 = 1 > 0): the sign the old rule kept with it
    assert [d.sign for d in resolve_directions(load_spec(negative_pairing(None)))] == [1, 1]
    dirs = resolve_directions(load_spec(negative_pairing(DECOUPLER)))
    assert [d.sign for d in dirs] == [-1, -1]
    assert dirs[0].gain == pytest.approx(-1.0) and "decoupler's column (u1 - u2)" in dirs[0].reason
    assert "(-2 u1 + u2)" in dirs[1].reason
    # the old sign on the decoupled plant: -1/(s + 1) under a direct PI, s^2 + (1 - Kp) s - Ki, unstable
    old = _run(negative_pairing(DECOUPLER, "direct"))
    assert old["diverged"][0] == 1.0
    new = _run(negative_pairing(DECOUPLER))
    assert new["diverged"][0] == 0.0 and new["sse"][0] < 1e-3


def test_tuned_decoupler_entries_are_read_at_the_search_start_value() -> None:
    # matrix[0][1] starts at its bounds' geometric centre (-2), matrix[1][0] at its value (-1): the fixed W above
    spec = load_spec(negative_pairing(TUNED))
    dirs = resolve_directions(spec)
    assert [d.sign for d in dirs] == [-1, -1]
    assert "tuned decoupler.matrix[1][0] at the search's start value" in dirs[0].reason
    assert "tuned decoupler.matrix[0][1]" in dirs[1].reason


def test_a_decoupler_column_with_zero_static_gain_asks_for_direction() -> None:
    # column b = (-1, 1): y2 sees u2 - u1, static gain 0, so the sign cannot be read
    dec = {"inputs": ["u1", "u2"], "matrix": [[1.0, -1.0], [0.0, 1.0]]}
    with pytest.raises(SpecError) as exc:
        resolve_directions(load_spec(negative_pairing(dec)))
    assert exc.value.field == "loops[1].direction" and "decoupler's column (-u1 + u2)" in str(exc.value)


def test_a_single_input_plant_reads_its_one_by_one_decoupler() -> None:
    d = {"plant": {"tf": {"num": [1], "den": [1, 1]}}, "loops": [{"type": "pi"}],
         "decoupler": {"inputs": ["u"], "matrix": [[-1.0]]},
         "scenarios": [{"name": "s", "dt": 0.05, "horizon": 10.0}]}
    (only,) = resolve_directions(load_spec(d))
    assert only.sign == -1 and "decoupler's gain -1" in only.reason
