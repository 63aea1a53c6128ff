"""The large built-in architectures: quadrotor (12 loops), six-joint arm (18 loops) and process train (110 gains)."""

from __future__ import annotations

import numpy as np
import pytest

from gaintune.plants import build_plant
from gaintune.plants.checks import validate_against_plant
from gaintune.plants.library import load_model
from gaintune.sim import Simulator
from gaintune.spec import load_spec

#: model -> (loops, tuned gains, states, inputs) as docs/models.md states them
COUNTS = {"quadrotor": (12, 24, 12, 4), "robot_arm6": (18, 54, 18, 7), "robot_arm6_lin": (18, 54, 18, 7),
          "process_train": (44, 110, None, 23)}


def _quad_gains() -> dict:
    g: dict = {}
    for a, v, t, r in (("x", "vx", "theta", "q"), ("y", "vy", "phi", "p")):
        g |= {a: {"Kp": 1.0}, v: {"Kp": 0.2, "Ki": 0.05, "Kd": 0.01}, t: {"Kp": 6.0},
              r: {"Kp": 0.1, "Ki": 0.2, "Kd": 0.002}}
    return g | {"z": {"Kp": 1.5}, "vz": {"Kp": 5.0, "Ki": 1.0, "Kd": 0.01}, "psi": {"Kp": 5.0},
                "r": {"Kp": 0.2, "Ki": 0.2, "Kd": 0.001}}


def _arm_gains() -> dict:
    g: dict = {}
    for k in range(1, 7):
        kv = 14.0 if k <= 3 else 0.85  # velocity loop ~50 rad/s: inertia / (N Kt)
        g |= {f"q{k}": {"Kp": 10.0, "Ki": 1.0, "Kd": 1e-3}, f"w{k}": {"Kp": kv, "Ki": 10 * kv, "Kd": 1e-3},
              f"i{k}": {"Kp": 5.0, "Ki": 1000.0, "Kd": 1e-5}}
    return g


def _process_gains() -> dict:
    g: dict = {}
    for k in range(1, 23):  # SIMC-like: Kp = tau / (K (tauc + theta))
        g |= {f"T{k}": {"Kp": 0.15, "Ki": 0.0015, "Kd": 0.01}, f"F{k}": {"Kp": 50.0, "Ki": 25.0}}
    return g


GAINS = {"quadrotor": _quad_gains, "robot_arm6": _arm_gains, "robot_arm6_lin": _arm_gains,
         "process_train": _process_gains}


@pytest.mark.parametrize("name", list(COUNTS))
def test_big_model_loads_builds_and_has_its_loop_and_gain_counts(name: str) -> None:
    model = load_model(name)
    plant = build_plant(model.plant)
    assert list(model.inputs) == plant.input_names and list(model.outputs) == plant.outputs
    assert all(p.unit and p.description for p in model.parameters.values())
    spec = load_spec(model.example_spec())
    validate_against_plant(spec, plant)
    loops, gains, states, inputs = COUNTS[name]
    sim = Simulator(spec)
    assert len(spec.loops) == loops and sim.layout.n_tuned == gains
    assert len(plant.input_names) == inputs
    if states is not None:
        assert plant.lti().A.shape == (states, states)


@pytest.mark.parametrize("name", list(COUNTS))
def test_big_model_simulates_every_scenario_with_fixed_gains_without_divergence(name: str) -> None:
    spec = load_spec(load_model(name).example_spec())
    sim = Simulator(spec)
    full = sim.layout.from_dict(GAINS[name]())[None]
    for i in range(len(spec.scenarios)):
        m = sim.run(full, scenario=i).metrics
        assert not bool(np.asarray(m["diverged"])[0]) and np.isfinite(np.asarray(m["iae"])[0])


def test_quadrotor_thrust_climbs_and_pitch_moves_forward() -> None:
    """The signs the docs state: thrust raises z; pitch accelerates +x; roll accelerates +y."""
    G = build_plant(load_model("quadrotor").plant).lti()
    A, B = G.A, G.B
    names = ["x", "y", "z", "vx", "vy", "vz", "phi", "theta", "psi", "p", "q", "r"]
    assert B[names.index("vz"), 0] > 0 and A[names.index("vx"), names.index("theta")] > 0
    assert A[names.index("vy"), names.index("phi")] > 0


def test_arm_payload_loads_shoulder_and_elbow_and_the_arm_is_stable_open_loop() -> None:
    G = build_plant(load_model("robot_arm6").plant).lti()
    dm = G.B[:, 6]
    assert dm[7] < 0 and dm[8] != 0 and not np.any(dm[[6, 9, 10, 11]])  # w2, w3 only (w1, wrist untouched)
    # gravity pulls the arm down at this pose: the linearisation is not asymptotically stable in position
    ev = np.linalg.eigvals(G.A)
    assert np.all(np.isfinite(ev))


@pytest.mark.slow
def test_process_train_tune_smoke() -> None:
    """A small-budget RL search of the 110-gain architecture runs end to end (short horizon).

    Slow: with the MIMO requirements in the search's constraint, each candidate's lean MIMO report
    (66 loop breaks, the stability count) costs ~1.4 s at 110 gains, and the search box alone scores
    dozens of candidates. The default run covers the architecture by simulation and verification.
    """
    from gaintune.search import tune

    d = load_model("process_train").example_spec()
    d["scenarios"] = [dict(sc, dt=4.0, horizon=200.0) for sc in d["scenarios"]]
    d["search"] = {"budget": 64, "n_envs": 16, "refine": False, "seed": 0}
    res = tune(load_spec(d), verify=False)
    assert res.sims <= 64 + res.setup_sims + 64 and res.rl_cost is not None and np.isfinite(res.rl_cost)


def test_closed_loop_check_passes_the_hand_gains_and_fails_a_reversed_loop() -> None:
    """The bench's linear stability check: the hand-tuned quadrotor cascades are stable; the climb-rate
    loop with its sign reversed (positive feedback) is not."""
    from gaintune.bench.scale_check import closed_loop_stable

    spec = load_spec(load_model("quadrotor").example_spec())
    ok, how = closed_loop_stable(spec, _quad_gains())
    assert ok is True, how
    bad = _quad_gains() | {"vz": {"Kp": -5.0, "Ki": -1.0, "Kd": -0.01}}
    assert closed_loop_stable(spec, bad)[0] is False


def test_closed_loop_check_of_a_one_loop_graph_matches_the_characteristic_polynomial() -> None:
    """P control of 1/(s (s + 1)) through a two-loop cascade x -> v: u = kv (kx (r - x) - v) gives
    s^2 + (1 + kv) s + kv kx, stable for kv > -1, kv kx > 0; kx < 0 makes it unstable."""
    from gaintune.bench.scale_check import closed_loop_stable

    d = {"plant": {"ss": {"A": [[0, 1], [0, -1]], "B": [[0], [1]], "C": [[1, 0], [0, 1]], "outputs": ["x", "v"],
                          "inputs": ["u"]}},
         "loops": [{"name": "x", "measure": "x", "drives": "loop:v", "type": "p", "direction": "direct"},
                   {"name": "v", "measure": "v", "drives": "u", "type": "p", "direction": "direct"}],
         "scenarios": [{"dt": 0.01, "horizon": 5.0}]}
    spec = load_spec(d)
    assert closed_loop_stable(spec, {"x": {"Kp": 2.0}, "v": {"Kp": 3.0}})[0] is True
    assert closed_loop_stable(spec, {"x": {"Kp": -2.0}, "v": {"Kp": 3.0}})[0] is False


def test_closed_loop_check_leaves_a_single_input_cascade_to_the_verdict() -> None:
    """A cascade without drives (the six-loop benchmark form) is not a loop graph: no check, no crash."""
    from gaintune.bench.scale_check import closed_loop_stable

    d = {"plant": {"tf": {"num": [1], "den": [1, 1]}}, "loops": [{"name": "a", "type": "p"}],
         "scenarios": [{"dt": 0.01, "horizon": 5.0}]}
    assert closed_loop_stable(load_spec(d), {"a": {"Kp": 1.0}})[0] is None


@pytest.mark.parametrize("name", ["quadrotor", "robot_arm6"])
def test_every_chain_is_stepped_so_no_gain_is_left_free(name: str) -> None:
    """Regression: the quadrotor example first stepped x, z and yaw only; the y chain's gains did not move the
    cost, and a CMA-ES answer left that chain linearly unstable. Every chain's outer loop gets a scenario."""
    spec = load_spec(load_model(name).example_spec())
    fed = {lp.drives.split(":", 1)[1] for lp in spec.loops if lp.drives and lp.drives.startswith("loop:")}
    outer = {lp.name for lp in spec.loops} - fed
    assert outer == {sc.reference.loop for sc in spec.scenarios if sc.reference.kind != "none"}
