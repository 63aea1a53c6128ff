"""Write models/robot_arm6_lin.yaml and models/process_train.yaml (large built-in architectures).

Both are written out by this script rather than by hand: their matrices are long and regular.
Run from the repository root: ``python bench/tools/gen_big_models.py``. The YAML keeps every physical
figure as a named parameter; the matrices are expressions in those parameters.
"""

from __future__ import annotations

from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
J = 6


def _arm_inertia() -> dict[tuple[int, int], str]:
    """Joint-space inertia M(q0) (link part plus reflected rotor inertia N^2 Jm), as expressions."""
    reach = "(l2*cos(q2_0) + l3c*cos(q2_0 + q3_0))"
    m = {
        (0, 0): f"(I1 + m2*(l2c*cos(q2_0))^2 + m3*{reach}^2 + N1^2*Jm)",
        (1, 1): "(I2 + I3 + m2*l2c^2 + m3*(l2^2 + l3c^2 + 2*l2*l3c*cos(q3_0)) + N2^2*Jm)",
        (2, 2): "(I3 + m3*l3c^2 + N3^2*Jm)",
        (1, 2): "(I3 + m3*(l3c^2 + l2*l3c*cos(q3_0)))",
        (3, 3): "(I4 + N4^2*Jm)", (4, 4): "(I5 + N5^2*Jm)", (5, 5): "(I6 + N6^2*Jm)",
    }
    m[(2, 1)] = m[(1, 2)]
    return m


def _arm_minv() -> dict[tuple[int, int], str]:
    """M(q0)^-1: the base and the wrist are decoupled at q0; shoulder and elbow form a 2 x 2 block."""
    m = _arm_inertia()
    det = f"({m[(1, 1)]}*{m[(2, 2)]} - {m[(1, 2)]}^2)"
    inv = {(0, 0): f"1/{m[(0, 0)]}", (1, 1): f"{m[(2, 2)]}/{det}", (2, 2): f"{m[(1, 1)]}/{det}",
           (1, 2): f"-{m[(1, 2)]}/{det}", (2, 1): f"-{m[(1, 2)]}/{det}"}
    for k in (3, 4, 5):
        inv[(k, k)] = f"1/{m[(k, k)]}"
    return inv


def _arm_gravity_stiffness() -> dict[tuple[int, int], str]:
    """d(gravity torque)/dq at q0 (shoulder and elbow), joint torque = -K dq."""
    s23 = "sin(q2_0 + q3_0)"
    return {(1, 1): f"(-g*((m2*l2c + m3*l2)*sin(q2_0) + m3*l3c*{s23}))", (1, 2): f"(-g*m3*l3c*{s23})",
            (2, 1): f"(-g*m3*l3c*{s23})", (2, 2): f"(-g*m3*l3c*{s23})"}


def _mul(a: str, b: str) -> str:
    return f"{a}*{b}"


def arm_plant() -> dict:
    """States q1..q6, w1..w6, i1..i6; inputs v1..v6 and the payload change dm at the tool."""
    n = 3 * J
    A = [[0 for _ in range(n)] for _ in range(n)]
    B = [[0 for _ in range(J + 1)] for _ in range(n)]
    minv, kg = _arm_minv(), _arm_gravity_stiffness()
    for k in range(J):
        A[k][J + k] = 1  # dq/dt = w
        A[2 * J + k][2 * J + k] = "-R/L"
        A[2 * J + k][J + k] = f"-Kb*N{k + 1}/L"
        B[2 * J + k][k] = "1/L"
    # payload torque at shoulder and elbow: -g dm (reach), as a load torque entering the rigid body
    pay = {1: "(-g*(l2*cos(q2_0) + l3*cos(q2_0 + q3_0)))", 2: "(-g*l3*cos(q2_0 + q3_0))"}
    for r in range(J):
        for c in range(J):
            if (r, c) not in minv:
                continue
            mi = minv[(r, c)]
            # dw_r/dt = sum_c Minv[r, c] (N_c Kt i_c - b w_c - sum_k K[c, k] q_k + tau_load_c)
            A[J + r][2 * J + c] = _mul(mi, f"N{c + 1}*Kt")
            A[J + r][J + c] = _mul(mi, "(-b)")
            for k in range(J):
                if (c, k) in kg:
                    prev = A[J + r][k]
                    term = _mul(mi, f"(-{kg[(c, k)]})")
                    A[J + r][k] = term if prev == 0 else f"{prev} + {term}"
            if c in pay:
                prev = B[J + r][J]
                term = _mul(mi, pay[c])
                B[J + r][J] = term if prev == 0 else f"{prev} + {term}"
    C = [[1 if c == r else 0 for c in range(n)] for r in range(n)]
    states = [f"q{k}" for k in range(1, J + 1)] + [f"w{k}" for k in range(1, J + 1)] + \
        [f"i{k}" for k in range(1, J + 1)]
    inputs = [{"name": f"v{k}", "unit": "V"} for k in range(1, J + 1)] + [{"name": "dm", "unit": "kg"}]
    units = ["rad"] * J + ["rad/s"] * J + ["A"] * J
    return {"ss": {"inputs": inputs, "states": states, "outputs": states, "output_units": units,
                   "A": A, "B": B, "C": C}}


def _pid(kp: list[float], ki: list[float], kd: list[float]) -> dict:
    return {"Kp": {"bounds": kp}, "Ki": {"bounds": ki}, "Kd": {"bounds": kd}}


def arm_example() -> dict:
    loops = []
    for k in range(1, J + 1):
        loops += [
            {"name": f"q{k}", "measure": f"q{k}", "drives": f"loop:w{k}", "type": "pid", "direction": "direct",
             "output_limits": [-3, 3], "gains": _pid([0.5, 200], [0.01, 100], [1e-5, 1])},
            {"name": f"w{k}", "measure": f"w{k}", "drives": f"loop:i{k}", "type": "pid", "direction": "direct",
             "output_limits": [-10, 10], "gains": _pid([0.1, 100], [0.1, 1000], [1e-5, 1])},
            {"name": f"i{k}", "measure": f"i{k}", "drives": f"v{k}", "type": "pid", "direction": "direct",
             "gains": _pid([0.1, 50], [1, 10000], [1e-6, 0.01])},
        ]
    acts = {f"v{k}": {"limits": [-48, 48]} for k in range(1, J + 1)}
    scen = [{"name": f"step_q{k}", "dt": 0.001, "horizon": 0.5, "reference": {"loop": f"q{k}", "kind": "step",
                                                                              "amplitude": 0.1}}
            for k in range(1, J + 1)]
    scen.append({"name": "payload", "dt": 0.001, "horizon": 0.5, "reference": {"kind": "none"},
                 "disturbance": {"kind": "step", "amplitude": 2.0, "time": 0.1, "input": "dm"}})
    return {"description": "Position -> velocity -> current PID cascade on every joint (18 loops, 54 gains); "
                           "a 0.1 rad step on each joint in turn and a 2 kg payload picked up at t = 0.1 s; "
                           "the IAE of every joint's position error.",
            "loops": loops, "actuators": acts, "scenarios": scen,
            "objective": {"measure": "iae", "effort_weight": 0.0}}


ARM_PARAMS = {
    "m2": (8.0, "kg", "Upper-arm mass"), "m3": (4.0, "kg", "Forearm mass (with wrist and tool)"),
    "l2": (0.5, "m", "Upper-arm length"), "l3": (0.4, "m", "Forearm length to the tool"),
    "l2c": (0.25, "m", "Shoulder to the upper arm's centre of mass"),
    "l3c": (0.2, "m", "Elbow to the forearm's centre of mass"),
    "I1": (0.3, "kg m^2", "Base link inertia about joint 1"),
    "I2": (0.17, "kg m^2", "Upper-arm inertia about its centre"),
    "I3": (0.06, "kg m^2", "Forearm inertia about its centre"), "I4": (0.01, "kg m^2", "Wrist link 4 inertia"),
    "I5": (0.005, "kg m^2", "Wrist link 5 inertia"), "I6": (0.002, "kg m^2", "Tool flange inertia"),
    "g": (9.81, "m/s^2", "Gravity"),
    "q2_0": (0.5, "rad", "Shoulder angle of the operating point (from horizontal)"),
    "q3_0": (-1.0, "rad", "Elbow angle of the operating point"),
    "N1": (100, "-", "Gear ratio joint 1"), "N2": (100, "-", "Gear ratio joint 2"),
    "N3": (100, "-", "Gear ratio joint 3"),
    "N4": (50, "-", "Gear ratio joint 4"), "N5": (50, "-", "Gear ratio joint 5"), "N6": (50, "-", "Gear ratio joint 6"),
    "Jm": (3e-5, "kg m^2", "Rotor inertia (every motor)"), "Kt": (0.1, "N m/A", "Motor torque constant"),
    "Kb": (0.1, "V s/rad", "Motor back-EMF constant"), "R": (1.0, "ohm", "Winding resistance"),
    "L": (0.005, "H", "Winding inductance"), "b": (0.5, "N m s/rad", "Joint viscous friction"),
}

ARM_DESC = (
    "A six-joint articulated arm (base yaw, shoulder and elbow pitch, three-axis wrist), each joint "
    "driven by a DC motor through a gear of ratio N: L di/dt = v - R i - Kb N w, joint torque N Kt i. "
    "Rigid-body dynamics M(q) dw/dt + G(q) = N Kt i - b w + tau_load, linearised about the pose "
    "q0 = (0, q2_0, q3_0, 0, 0, 0) at rest: M(q0) holds the configuration-dependent link inertia "
    "(base: I1 + m2 (l2c cos q2)^2 + m3 (l2 cos q2 + l3c cos(q2 + q3))^2; shoulder-elbow block with the "
    "coupling I3 + m3 (l3c^2 + l2 l3c cos q3)) plus the reflected rotor inertia N^2 Jm; the gravity "
    "torque's slope dG/dq couples shoulder and elbow. Velocity-dependent (Coriolis) terms vanish at rest. "
    "The input dm is a payload mass change at the tool (kg): a load torque -g dm (l2 cos q2 + l3 cos(q2 + q3)) "
    "on the shoulder and -g dm l3 cos(q2 + q3) on the elbow. States q (rad, deviations from q0), "
    "w (rad/s), i (A); every state is measured. Time in seconds.")


def process_train(units: int = 22) -> tuple[dict, dict, dict]:
    """A train of heat-exchange units: unit k's valve u_k sets its flow F_k, which heats T_k; T_k is
    also moved by the neighbouring valves and by the common feed temperature Tf."""
    ins = [{"name": f"u{k}", "unit": "%"} for k in range(1, units + 1)] + [{"name": "Tf", "unit": "K"}]
    outs = []
    for k in range(1, units + 1):
        outs += [{"name": f"F{k}", "unit": "kg/s"}, {"name": f"T{k}", "unit": "K"}]
    rows = []
    params = {"Kf": (0.02, "kg/s/%", "Valve gain (flow per % opening)"),
              "tf": (4.0, "s", "Flow loop lag (valve and line)"),
              "Kh": (25.0, "K/(kg/s)", "Temperature gain of the unit's own flow"),
              "Kc": (0.1, "-", "Share of a neighbour's effect (coupling through the shared header)"),
              "Kd": (0.8, "-", "Feed temperature gain"), "td": (30.0, "s", "Feed disturbance lag")}
    for k in range(units):
        tau, theta = 60.0 + 40.0 * (k % 4), 8.0 + 4.0 * (k % 3)
        params[f"tau{k + 1}"] = (tau, "s", f"Thermal time constant of unit {k + 1}")
        params[f"theta{k + 1}"] = (theta, "s", f"Transport delay of unit {k + 1}")
        f_row: list = [0] * (units + 1)
        f_row[k] = {"num": ["Kf"], "den": ["tf", 1]}
        t_row: list = [0] * (units + 1)
        own = "Kf*Kh"
        t_row[k] = {"num": [own], "den": f"(tf*s + 1)*(tau{k + 1}*s + 1)", "delay": f"theta{k + 1}"}
        for j in (k - 1, k + 1):
            if 0 <= j < units:
                t_row[j] = {"num": [f"-Kc*{own}"], "den": f"(tf*s + 1)*(tau{k + 1}*s + 1)",
                            "delay": f"2*theta{k + 1}"}
        t_row[units] = {"num": ["Kd"], "den": f"(td*s + 1)*(tau{k + 1}*s + 1)", "delay": f"theta{k + 1}"}
        rows += [f_row, t_row]
    plant = {"tf_matrix": {"inputs": ins, "outputs": outs, "entries": rows}}
    loops = []
    for k in range(1, units + 1):
        loops += [
            {"name": f"T{k}", "measure": f"T{k}", "drives": f"loop:F{k}", "type": "pid", "direction": "direct",
             "output_limits": [-2, 2], "gains": _pid([0.001, 1], [1e-5, 0.1], [1e-4, 5])},
            {"name": f"F{k}", "measure": f"F{k}", "drives": f"u{k}", "type": "pi", "direction": "direct",
             "gains": {"Kp": {"bounds": [1, 1000]}, "Ki": {"bounds": [1, 1000]}}},
        ]
    acts = {f"u{k}": {"limits": [-50, 50]} for k in range(1, units + 1)}
    scen = [{"name": "feed", "dt": 1.0, "horizon": 900.0, "reference": {"kind": "none"},
             "disturbance": {"kind": "step", "amplitude": 5.0, "time": 10.0, "input": "Tf"}},
            {"name": "step_T1", "dt": 1.0, "horizon": 900.0, "reference": {"loop": "T1", "kind": "step",
                                                                          "amplitude": 1.0}}]
    example = {"description": f"A temperature PID -> flow PI cascade on every unit ({2 * units} loops, "
                              f"{5 * units} gains); a 5 K feed-temperature step (every unit) and a 1 K setpoint "
                              "step on unit 1; the IAE of every temperature error.",
               "loops": loops, "actuators": acts, "scenarios": scen,
               "objective": {"measure": "iae", "effort_weight": 0.0}}
    return plant, example, params


PROCESS_DESC = (
    "A train of {n} heat-exchange units sharing a heating-medium header (a process plant of many "
    "interacting units). Unit k has a valve u_k (% opening, deviation), a measured medium flow "
    "F_k = Kf/(tf s + 1) u_k and an outlet temperature T_k = Kh e^(-theta_k s)/(tau_k s + 1) F_k, minus "
    "a share Kc of each neighbour's flow effect with twice the delay (opening a valve robs the neighbours "
    "through the header), plus the common feed temperature Tf through Kd/((td s + 1)(tau_k s + 1)) "
    "e^(-theta_k s). The units differ: tau_k = 60, 100, 140, 180 s and theta_k = 8, 12, 16 s in turn. "
    "Tf is an input no loop drives (disturbance). Signals are deviations; time in seconds.")


def _model(name: str, title: str, desc: str, params: dict, inputs: list[dict], outputs: list[tuple[str, str]],
           plant: dict, example: dict) -> dict:
    return {"name": name, "title": title, "description": desc,
            "parameters": {k: {"value": v, "unit": u, "description": d} for k, (v, u, d) in params.items()},
            "inputs": {i["name"]: {"unit": i["unit"], "description": i.get("description", i["name"])}
                       for i in inputs},
            "outputs": {o: {"unit": u, "description": o} for o, u in outputs},
            "plant": plant, "example": example}


def main() -> None:
    arm = arm_plant()
    outs = list(zip(arm["ss"]["outputs"], arm["ss"]["output_units"], strict=True))
    ins = [dict(i, description=f"Motor {i['name'][1:]} voltage") for i in arm["ss"]["inputs"][:J]]
    ins.append({"name": "dm", "unit": "kg", "description": "Payload mass change at the tool (disturbance input)"})
    doc = _model("robot_arm6_lin", "Six-joint robot arm with DC joint motors, linearised about a pose (18 states)",
                 ARM_DESC, ARM_PARAMS, ins, outs, arm, arm_example())
    (ROOT / "models" / "robot_arm6_lin.yaml").write_text(yaml.safe_dump(doc, sort_keys=False, width=110))
    plant, example, params = process_train()
    tm = plant["tf_matrix"]
    outs = [(o["name"], o["unit"]) for o in tm["outputs"]]
    doc = _model("process_train", "Process train: 22 interacting heat-exchange units (44 loops, 110 gains)",
                 PROCESS_DESC.format(n=22), params, tm["inputs"], outs, plant, example)
    (ROOT / "models" / "process_train.yaml").write_text(yaml.safe_dump(doc, sort_keys=False, width=110))


if __name__ == "__main__":
    main()
