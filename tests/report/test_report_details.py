"""Report details an engineer asked for: units, both PID forms, the |CS| plot with the Mks limit,
a setpoint step for a load-only spec."""

from __future__ import annotations

import re

import pytest

from gaintune.plants.library import load_model
from gaintune.report import render_html, result_from_gains
from gaintune.spec import load_spec

TANK = {"level": {"Kp": 0.5, "Ki": 0.01}}


def _section(html: str, sid: str) -> str:
    m = re.search(rf'<section id="{sid}">(.*?)</section>', html, re.S)
    assert m, f"section {sid} missing"
    return m.group(1)


@pytest.fixture(scope="module")
def tank_html() -> str:
    spec = load_spec(load_model("water_tank").example_spec())
    return render_html(result_from_gains(spec, TANK))


def test_report_gains_carry_units_and_the_ideal_form(tank_html):
    table = tank_html.split('id="gains"', 1)[1].split("</table>", 1)[0]
    assert "<td>V/m</td>" in table and "<td>V/(m·s)</td>" in table
    assert "Ti 50 s" in table  # Kp/Ki = 0.5/0.01


def test_report_u_axis_has_the_input_unit(tank_html):
    assert "u [V]" in _section(tank_html, "time")


def test_report_draws_cs_with_the_mks_limit_when_mks_binds(tank_html):
    freq = _section(tank_html, "frequency")
    assert 'id="noise-sensitivity"' in freq and "Mks limit" in freq


def test_report_without_mks_requirement_has_no_cs_plot():
    spec = load_spec({**load_model("water_tank").example_spec(), "requirements": {"mks_max": None}})
    html = render_html(result_from_gains(spec, TANK))
    assert 'id="noise-sensitivity"' not in html


def test_report_of_load_only_spec_shows_a_setpoint_step_for_information():
    spec = load_spec({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pi"}],
                      "scenario": {"dt": 0.05, "horizon": 30.0, "reference": {"kind": "none"},
                                   "disturbance": {"kind": "step", "time": 1.0, "amplitude": 1.0, "entry": "input"}}})
    html = render_html(result_from_gains(spec, {"loop0": {"Kp": 1.0, "Ki": 0.4}}))
    assert "Setpoint step of 1, for information" in _section(html, "time")


def test_report_of_parallel_pid_shows_ideal_equivalent():
    spec = load_spec(load_model("lag_n").example_spec())
    html = render_html(result_from_gains(spec, {"main": {"Kp": 2.0, "Ki": 0.5, "Kd": 1.0}}))
    table = html.split('id="gains"', 1)[1].split("</table>", 1)[0]
    assert "Ti 4 s" in table and "Td 0.5 s" in table
