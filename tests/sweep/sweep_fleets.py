"""Fleets for the sweep tests: tiny FOTD specs (a 100-simulation search each).

Imported by name (``from sweep_fleets import ...``): a ``from conftest import`` takes whichever conftest
module another test folder loaded first, and broke collection when tests/api ran before tests/sweep.
"""


from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

#: PI on K exp(-L s)/(T s + 1): a short horizon and a 100-simulation search (about 0.2 s warm).
TINY_SPEC: dict[str, Any] = {
    "name": "valve",
    "plant": {"tf": {"num": ["K"], "den": "T*s + 1"}, "delay": "L", "params": {"K": 1.0, "T": 2.0, "L": 0.5}},
    "loops": [{"name": "flow", "type": "pi", "gains": {"Kp": {"bounds": [0.01, 20]}, "Ki": {"bounds": [0.001, 20]}}}],
    "scenario": {"dt": 0.05, "horizon": 15.0},
    "requirements": {"gm_min_db": 6, "pm_min_deg": 45, "ms_max": 1.6},
    "search": {"budget": 100, "seed": 0, "n_envs": 8},
}


def write_fleet(folder: Path, fleet: dict[str, Any], name: str = "fleet.yaml") -> Path:
    """``fleet`` as a YAML file in ``folder``."""
    path = folder / name
    path.write_text(yaml.safe_dump(fleet, sort_keys=False))
    return path


def grid_fleet(folder: Path, gains: list[float], name: str = "fleet.yaml") -> Path:
    """A fleet of TINY_SPEC at each plant gain K of ``gains``."""
    return write_fleet(folder, {"name": "tiny", "base": TINY_SPEC, "grid": {"plant.params.K": gains}}, name)
