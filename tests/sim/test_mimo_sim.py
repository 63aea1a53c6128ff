"""The MIMO simulator (gaintune.sim.mimo): against python-control, and against the single-input kernel."""

from __future__ import annotations

import copy
from typing import Any

import control
import numpy as np
import pytest

from gaintune.evaluation.evaluator import DIVERGED_COST, DIVERGED_VIOLATION, Evaluator
from gaintune.plants.library import load_model
from gaintune.sim import Simulator
from gaintune.sim.mimo import MimoSimulator
from gaintune.spec import load_spec

#: Luyben's BLT tuning of Wood-Berry: Kc, Ti (min) per loop.
BLT = {"xD": (0.375, 8.29), "xB": (-0.075, 23.6)}


def wood_berry(dt: float = 0.5, horizon: float = 60.0, **extra: Any):
    data = load_model("wood_berry").example_spec()
    data["scenarios"] = [{**sc, "dt": dt, "horizon": horizon} for sc in data["scenarios"]]
    data.update(extra)
    return load_spec(data)


def blt_full(sim) -> np.ndarray:
    gains = {n: {"Kp": kc, "Ki": kc / ti} for n, (kc, ti) in BLT.items()}
    return sim.layout.from_dict(gains)[None]


def python_control_closed_loop(dt: float, n: int, ref: tuple[float, float]) -> np.ndarray:
    """y (2, n) of Wood-Berry with the BLT PI loops, built independently with python-control.

    Each entry is discretised with ZOH (control.c2d) and delayed by z^-d (delays are whole samples at
    this dt); each PI is the backward-Euler law u = Kp e + I, I[k] = I[k-1] + Ki dt e[k]:
    C(z) = ((Kp + Ki dt) z - Kp) / (z - 1).
    """
    G = {("1", "1"): (12.8, 16.7, 1.0), ("1", "2"): (-18.9, 21.0, 3.0),
         ("2", "1"): (6.6, 10.9, 7.0), ("2", "2"): (-19.4, 14.4, 3.0)}
    blocks = []
    for (i, j), (k, tau, delay) in G.items():
        d = int(round(delay / dt))
        gz = control.c2d(control.tf([k], [tau, 1.0]), dt, "zoh") * control.tf([1.0], [1.0] + [0.0] * d, dt)
        blocks.append(control.tf2io(gz, inputs=f"u{j}", outputs=f"y{i}{j}", name=f"G{i}{j}")
                      if hasattr(control, "tf2io") else control.ss(gz, inputs=f"u{j}", outputs=f"y{i}{j}",
                                                                  name=f"G{i}{j}"))
    for i, (kc, ti) in zip("12", BLT.values(), strict=True):
        ki = kc / ti
        c = control.tf([kc + ki * dt, -kc], [1.0, -1.0], dt)
        blocks.append(control.ss(c, inputs=f"e{i}", outputs=f"u{i}", name=f"C{i}"))
        blocks.append(control.summing_junction([f"r{i}", f"-y{i}"], f"e{i}", name=f"E{i}", dt=dt))
        blocks.append(control.summing_junction([f"y{i}1", f"y{i}2"], f"y{i}", name=f"Y{i}", dt=dt))
    cl = control.interconnect(blocks, inplist=["r1", "r2"], outlist=["y1", "y2"], dt=dt)
    t = np.arange(n) * dt
    r = np.vstack([np.full(n, ref[0]), np.full(n, ref[1])])
    return np.asarray(control.forced_response(cl, T=t, U=r).outputs)


@pytest.mark.parametrize("scenario, ref", [(0, (1.0, 0.0)), (1, (0.0, 1.0))])
def test_wood_berry_matches_python_control(scenario: int, ref: tuple[float, float]) -> None:
    spec = wood_berry(dt=0.5, horizon=60.0)
    sim = Simulator(spec)
    assert isinstance(sim, MimoSimulator)
    res = sim.run(blt_full(sim), scenario=scenario, traces=True)
    y_ref = python_control_closed_loop(0.5, spec.scenarios[scenario].n_steps, ref)
    y = np.vstack([res.traces["y.xD"][0], res.traces["y.xB"][0]])
    assert np.max(np.abs(y)) > 0.5  # a real response, not zeros on both sides
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-9 * np.max(np.abs(y_ref)))
    # the cost is the IAE of both errors: the sum of the chains' IAE
    m = res.metrics
    np.testing.assert_allclose(m["iae"], m["iae.xD"] + m["iae.xB"])
    e = np.vstack([np.full(y.shape[1], ref[0]), np.full(y.shape[1], ref[1])]) - y_ref
    np.testing.assert_allclose(m["iae"][0], np.abs(e).sum() * 0.5, rtol=1e-9)


def test_fractional_delays_converge_to_whole_sample_result() -> None:
    """Delays that are not whole samples (dt = 0.4 min: 1 min = 2.5 samples) are exact ZOH: halving dt
    changes the IAE by a discretisation-sized amount only."""
    coarse = Simulator(wood_berry(dt=0.4, horizon=80.0))
    fine = Simulator(wood_berry(dt=0.05, horizon=80.0))
    a = coarse.run(blt_full(coarse)).metrics["iae"][0]
    b = fine.run(blt_full(fine)).metrics["iae"][0]
    assert abs(a - b) / b < 0.05


SISO = {"plant": {"tf": {"num": [2.0], "den": "(s+1)^3"}, "delay": 0.37},
        "actuator": {"limits": [-1.5, 1.5], "rate_limit": 4.0},
        "scenario": {"dt": 0.05, "horizon": 25.0, "reference": {"kind": "step", "amplitude": 1.0},
                     "disturbance": {"kind": "step", "amplitude": -0.3, "time": 12.0}},
        "requirements": {"mks_max": None}}


@pytest.mark.parametrize("loop", [
    {"type": "pid", "anti_windup": "clamping", "b": 0.7, "c": 0.2},
    {"type": "pid", "anti_windup": "back_calculation", "filter": {"N": 5}},
    {"type": "pi", "anti_windup": "none"},
])
def test_single_input_graph_matches_the_siso_kernel(loop: dict) -> None:
    """A single loop that says what it drives runs on the MIMO simulator: the same law, the same numbers
    as the single-input kernel (saturation, rate limit, fractional delay, anti-windup, setpoint weights)."""
    siso = Simulator(load_spec({**SISO, "loops": [{"name": "a", **loop}]}))
    graph = Simulator(load_spec({**SISO, "loops": [{"name": "a", "drives": "u", **loop}]}))
    assert isinstance(graph, MimoSimulator) and not isinstance(siso, MimoSimulator)
    gains = {"a": {"Kp": 0.9, "Ki": 0.35, **({"Kd": 0.4} if loop["type"] == "pid" else {})}}
    full = np.vstack([siso.layout.from_dict(gains), siso.layout.from_dict({"a": {k: 2 * v for k, v in
                                                                               gains["a"].items()}})])
    a, b = siso.run(full).metrics, graph.run(full).metrics
    for name in ("iae", "ise", "itae", "effort", "tv", "overshoot", "settling_time", "load_iae", "peak_u",
                 "y_final", "sat_frac"):
        np.testing.assert_allclose(b[name], a[name], rtol=1e-9, atol=1e-12, err_msg=name)


def test_cascade_as_a_graph_matches_the_siso_cascade() -> None:
    """Two loops on a two-output plant: today's cascade (outer first) and the same loops wired with drives."""
    plant = {"ss": {"A": [[0, 1], [-2, -3]], "B": [[0], [1]], "C": [[1, 0], [0, 1]], "outputs": ["pos", "vel"]}}
    base = {"plant": plant, "scenario": {"dt": 0.01, "horizon": 10.0}, "requirements": {"mks_max": None}}
    outer = {"name": "p", "measure": "pos", "type": "pi", "direction": "direct"}
    inner = {"name": "v", "measure": "vel", "type": "pi", "direction": "direct"}
    siso = Simulator(load_spec({**base, "loops": [outer, inner]}))
    graph = Simulator(load_spec({**base, "loops": [{**inner, "drives": "u"}, {**outer, "drives": "loop:v"}]}))
    gains = {"p": {"Kp": 2.0, "Ki": 0.5}, "v": {"Kp": 3.0, "Ki": 1.0}}
    a = siso.run(siso.layout.from_dict(gains)[None]).metrics
    b = graph.run(graph.layout.from_dict(gains)[None]).metrics
    for name in ("iae", "ise", "effort", "overshoot", "y_final"):
        np.testing.assert_allclose(b[name], a[name], rtol=1e-9, err_msg=name)


def test_unstable_wood_berry_gains_diverge_and_are_infeasible() -> None:
    spec = wood_berry(dt=0.5, horizon=200.0)
    ev = Evaluator(spec)
    tuned = ev.layout.tuned_of(ev.layout.from_dict({"xD": {"Kp": 5.0, "Ki": 1.0}, "xB": {"Kp": -2.0, "Ki": -0.5}}))
    s = ev.evaluate(tuned[None])
    assert s.diverged[0] and s.cost[0] == DIVERGED_COST and s.violation[0] >= DIVERGED_VIOLATION
    ok = ev.evaluate(ev.layout.tuned_of(blt_full(ev.sim)))
    # BLT is stable; it misses only the example's MIMO Ms <= 2.1 at the inputs (2.47), by a finite grade
    assert not ok.diverged[0] and ok.cost[0] < 100 and ok.violation[0] < DIVERGED_VIOLATION


def test_disturbance_at_the_feed_input_passes_its_paths() -> None:
    """A feed step (input F, no loop drives it) reaches xB after its path's 3.4 min delay, xD no sooner than
    3.4 + 3 min (through loop xB and the S -> xD path), and the loops reject it."""
    spec = wood_berry(dt=0.1, horizon=200.0, scenarios=[
        {"name": "feed", "dt": 0.1, "horizon": 200.0, "reference": {"kind": "none"},
         "disturbance": {"kind": "step", "amplitude": 0.5, "time": 10.0, "input": "F"}}])
    sim = Simulator(spec)
    res = sim.run(blt_full(sim), traces=True)
    yb, yd = res.traces["y.xB"][0], res.traces["y.xD"][0]
    k = int(round((10.0 + 3.4) / 0.1))
    assert np.all(yb[:k + 1] == 0.0) and yb[k + 5] > 0
    assert np.all(yd[:int(round((10.0 + 3.4 + 3.0) / 0.1)) + 1] == 0.0)
    assert abs(yd[-1]) < 0.1 * np.max(np.abs(yd)) and abs(yb[-1]) < 0.1 * np.max(np.abs(yb))
    assert res.metrics["load_iae"][0] > 0


def test_actuators_entry_matches_the_single_input_actuator() -> None:
    """`actuators: {u: ...}` on a loop graph saturates and rate-limits as `actuator:` does on one loop."""
    loop = {"name": "a", "type": "pid", "anti_windup": "clamping"}
    siso = Simulator(load_spec({**SISO, "loops": [loop]}))
    act = {"u": {"limits": SISO["actuator"]["limits"], "rate_limit": SISO["actuator"]["rate_limit"]}}
    graph = Simulator(load_spec({**{k: v for k, v in SISO.items() if k != "actuator"}, "actuators": act,
                                 "loops": [{**loop, "drives": "u"}]}))
    full = siso.layout.from_dict({"a": {"Kp": 3.0, "Ki": 1.0, "Kd": 0.5}})[None]
    a, b = siso.run(full).metrics, graph.run(full).metrics
    assert a["sat_frac"][0] > 0  # the limits are active
    for name in ("iae", "effort", "tv", "peak_u", "sat_frac"):
        np.testing.assert_allclose(b[name], a[name], rtol=1e-9, err_msg=name)


def test_actuator_delay_adds_to_every_path_from_its_input() -> None:
    """An actuator delay of 0.35 min on R is the plant with 0.35 min more on G11 and G21 (no disturbance)."""
    spec = wood_berry(dt=0.1, horizon=80.0, actuators={"R": {"delay": 0.35}})
    data = load_model("wood_berry").example_spec()
    tfm = copy.deepcopy(load_model("wood_berry").plant.tf_matrix.model_dump(mode="json"))
    for row in tfm["entries"]:
        row[0]["delay"] += 0.35
    data.update(plant={"tf_matrix": tfm},
                scenarios=[{**sc, "dt": 0.1, "horizon": 80.0} for sc in data["scenarios"]])
    shifted = load_spec(data)
    a, b = Simulator(spec), Simulator(shifted)
    for i in (0, 1):
        ma, mb = a.run(blt_full(a), scenario=i).metrics, b.run(blt_full(b), scenario=i).metrics
        np.testing.assert_allclose(ma["iae"], mb["iae"], rtol=1e-9)


def test_static_decoupler_is_the_plant_times_its_matrix() -> None:
    """Loops through a decoupler W on plant B equal the same loops on plant B W without one."""
    A = [[-1.0, 0.2], [0.0, -0.5]]
    B = np.array([[1.0, 0.3], [0.4, 1.0]])
    W = np.array([[1.0, -0.3], [-0.4, 1.0]])
    base = {"loops": [{"name": "a", "measure": "y1", "drives": "u1", "type": "pi"},
                      {"name": "b", "measure": "y2", "drives": "u2", "type": "pi"}],
            "scenarios": [{"name": "s", "dt": 0.05, "horizon": 20.0, "reference": {"loop": "a"}}],
            "requirements": {"mks_max": None}}

    def ss(Bm):
        return {"ss": {"A": A, "B": Bm.tolist(), "C": [[1, 0], [0, 1]], "inputs": ["u1", "u2"],
                       "outputs": ["y1", "y2"]}}

    dec = Simulator(load_spec({**base, "plant": ss(B), "decoupler": {"inputs": ["u1", "u2"], "matrix": W.tolist()}}))
    folded = Simulator(load_spec({**base, "plant": ss(B @ W)}))
    gains = {"a": {"Kp": 1.5, "Ki": 1.0}, "b": {"Kp": 0.8, "Ki": 0.5}}
    a = dec.run(dec.layout.from_dict(gains)[None]).metrics
    b = folded.run(folded.layout.from_dict(gains)[None]).metrics
    for name in ("iae", "iae.a", "ise"):
        np.testing.assert_allclose(a[name], b[name], rtol=1e-9, err_msg=name)


def test_two_cascades_side_by_side_on_a_decoupled_plant_are_two_siso_cascades() -> None:
    """Two position/velocity cascades on a block-diagonal plant: each chain's IAE is its single-input
    cascade's, and the aggregate is their sum (the reference steps one chain; the other stays at rest)."""
    A1, B1 = [[0, 1], [-2, -3]], [[0], [1]]
    A2, B2 = [[0, 1], [-1, -0.5]], [[0], [2]]
    z = [[0, 0], [0, 0]]
    A = [r1 + r0 for r1, r0 in zip(A1, z, strict=True)] + [r0 + r2 for r0, r2 in zip(z, A2, strict=True)]
    B = [[b[0], 0] for b in B1] + [[0, b[0]] for b in B2]
    C = np.eye(4).tolist()
    plant = {"ss": {"A": A, "B": B, "C": C, "inputs": ["f1", "f2"], "outputs": ["p1", "v1", "p2", "v2"]}}
    pi = {"type": "pi", "direction": "direct"}
    loops = [{"name": "P1", "measure": "p1", "drives": "loop:V1", **pi},
             {"name": "V1", "measure": "v1", "drives": "f1", **pi},
             {"name": "V2", "measure": "v2", "drives": "f2", **pi},  # listed before the loop that drives it
             {"name": "P2", "measure": "p2", "drives": "loop:V2", **pi}]
    sc = {"dt": 0.01, "horizon": 8.0}
    graph = Simulator(load_spec({"plant": plant, "loops": loops, "requirements": {"mks_max": None},
                                 "scenarios": [{"name": "s1", **sc, "reference": {"loop": "P1"}},
                                               {"name": "s2", **sc, "reference": {"loop": "P2"}}]}))
    gains = {"P1": {"Kp": 2.0, "Ki": 0.5}, "V1": {"Kp": 3.0, "Ki": 1.0}, "P2": {"Kp": 1.5, "Ki": 0.3},
             "V2": {"Kp": 2.0, "Ki": 0.8}}
    full = graph.layout.from_dict(gains)[None]
    for k, (outer, inner, Ak, Bk) in enumerate((("P1", "V1", A1, B1), ("P2", "V2", A2, B2))):
        siso = Simulator(load_spec({
            "plant": {"ss": {"A": Ak, "B": Bk, "C": np.eye(2).tolist(), "outputs": ["p", "v"]}},
            "loops": [{"name": outer, "measure": "p", **pi}, {"name": inner, "measure": "v", **pi}],
            "scenario": sc, "requirements": {"mks_max": None}}))
        s = siso.run(siso.layout.from_dict({outer: gains[outer], inner: gains[inner]})[None]).metrics
        g = graph.run(full, scenario=k).metrics
        np.testing.assert_allclose(g[f"iae.{outer}"], s["iae"], rtol=1e-9)
        other = "P2" if outer == "P1" else "P1"
        assert g[f"iae.{other}"][0] == 0.0  # the other chain is not stepped and not coupled
        np.testing.assert_allclose(g["iae"], s["iae"], rtol=1e-9)
        np.testing.assert_allclose(g["overshoot"], s["overshoot"], rtol=1e-9)
