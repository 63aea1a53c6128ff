"""Clamping anti-windup sees the feedforward's saturation of the actuator (issue 28).

A PI loop on ``1/(s + 1)`` with a reference feedforward ``u += r`` (the plant's static inverse) and actuator
limits [-1.2, 1.2]: on a unit setpoint step the feedforward plus the loop's output saturates the
actuator, while the loop's output alone (limited to the actuator's limits) does not. The kernel's clamp
used to judge only the loop's output, so the integrator wound up during the rise and the step
overshot by about 18 %. A hand-written reference of the documented law pins the fixed kernel to 1e-9.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from gaintune.sim import Simulator
from gaintune.spec import load_spec

KP, KI, LIM, FF, DT = 1.0, 1.0, 1.2, 1.0, 0.01


def _spec(anti_windup: str = "clamping") -> dict[str, Any]:
    return {
        "plant": {"tf": {"num": [1], "den": [1, 1]}},
        "loops": [{"name": "main", "type": "pi", "direction": "direct", "anti_windup": anti_windup}],
        "actuator": {"limits": [-LIM, LIM]},
        "feedforward": [{"loop": "main", "input": "u", "gain": FF}],
        "scenarios": [{"name": "s", "dt": DT, "horizon": 20.0, "reference": {"kind": "step", "amplitude": 1.0}}],
        "requirements": {"mks_max": None, "gm_min_db": None, "pm_min_deg": None, "ms_max": None},
    }


def reference(sp: np.ndarray, judge_actuator: bool) -> tuple[np.ndarray, np.ndarray]:
    """(y, u) of the PI law with clamping on ``x' = -x + u``, exact ZOH; the clamp judges the loop's own
    limits, and with ``judge_actuator`` also the actuator's saturation of the output plus the feedforward."""
    a = math.exp(-DT)
    x = integ = 0.0
    ys, us = np.zeros(sp.size), np.zeros(sp.size)
    for k, r in enumerate(sp):
        y = x
        e = r - y
        it = integ + KI * DT * e
        vu = KP * (r - y) + it
        vs = min(max(vu, -LIM), LIM)
        hold = vs != vu and e * (vu - vs) * KI > 0
        tot = vs + FF * r
        ts = min(max(tot, -LIM), LIM)
        if judge_actuator and ts != tot and e * (tot - ts) * KI > 0:
            hold = True
        if hold:
            it = integ
            vs = min(max(KP * (r - y) + it, -LIM), LIM)
        integ = it
        u = min(max(vs + FF * r, -LIM), LIM)
        ys[k], us[k] = y, u
        x = a * x + (1.0 - a) * u
    return ys, us


def _overshoot(y: np.ndarray) -> float:
    return float(max(0.0, y.max() - 1.0) * 100.0)


def test_clamping_anti_windup_ignored_feedforward_saturation() -> None:
    sim = Simulator(load_spec(_spec()))
    res = sim.run(sim.layout.from_dict({"main": {"Kp": KP, "Ki": KI}})[None], traces=True)
    y, u, sp = res.traces["y.main"][0], res.traces["u.u"][0], res.traces["sp.main"][0]
    assert u.max() == LIM  # the actuator saturates (the loop's output alone stays inside its limits)
    fixed_y, fixed_u = reference(sp, judge_actuator=True)
    np.testing.assert_allclose(y, fixed_y, rtol=0, atol=1e-9)
    np.testing.assert_allclose(u, fixed_u, rtol=0, atol=1e-9)
    old_y, _ = reference(sp, judge_actuator=False)  # what the kernel did: the integrator winds up
    assert _overshoot(old_y) > 15.0
    assert _overshoot(y) < 4.0 and res.metrics["overshoot"][0] == pytest.approx(_overshoot(y), abs=1e-9)
    assert res.metrics["settling_time"][0] < 0.6 * _settling(old_y, sp)


def _settling(y: np.ndarray, sp: np.ndarray) -> float:
    """Time of the last sample outside 2 % of the final setpoint."""
    out = np.flatnonzero(np.abs(y - sp[-1]) >= 0.02 * abs(sp[-1]))
    return float((out[-1] + 1) * DT) if out.size else 0.0

