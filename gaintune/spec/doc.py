"""Render the spec reference (docs/spec.md) from the pydantic schema itself, so docs never drift."""

from __future__ import annotations

import inspect
import re
import typing

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

from gaintune import spec as S
from gaintune.spec.backoff import BackoffSpec
from gaintune.spec.design import DesignSpec

__all__ = ["render_markdown"]

_SECTIONS: list[tuple[str, type[BaseModel]]] = [
    ("spec (top level)", S.TuningSpec),
    ("plant", S.PlantSpec),
    ("plant.tf", S.TransferFunctionSpec),
    ("plant.tf_matrix", S.TfMatrixSpec),
    ("plant.tf_matrix.entries[i][j]", S.TfEntrySpec),
    ("plant.tf_matrix.inputs[j], .outputs[i], plant.ss.inputs[j]", S.SignalSpec),
    ("plant.ss", S.StateSpaceSpec),
    ("plant.ode", S.OdeSpec),
    ("plant.model", S.ModelRefSpec),
    ("loops[i]", S.LoopSpec),
    ("loops[i].gains.<name>", S.GainSpec),
    ("loops[i].filter", S.DerivativeFilterSpec),
    ("actuator", S.ActuatorSpec),
    ("actuators.<input>", S.ActuatorsEntrySpec),
    ("decoupler", S.DecouplerSpec),
    ("feedforward[k]", S.FeedforwardSpec),
    ("decoupler.matrix[i][j], feedforward[k].gain (tuned entries)", S.BlockGainSpec),
    ("scenarios[i]", S.ScenarioSpec),
    ("scenarios[i].reference", S.ReferenceSpec),
    ("scenarios[i].disturbance", S.DisturbanceSpec),
    ("objective", S.ObjectiveSpec),
    ("requirements", S.RequirementsSpec),
    ("requirements.backoff", BackoffSpec),
    ("randomize", S.RandomizeSpec),
    ("randomize.* distributions", S.DistSpec),
    ("safety", S.SafetySpec),
    ("search", S.SearchSpec),
    ("search.robust", S.RobustSpec),
    ("verify", S.VerifySpec),
    ("design (pidtune-style shortcut)", DesignSpec),
]


def _type(t: object) -> str:
    text = str(t).replace("typing.", "").replace("NoneType", "None")
    # spec models print as gaintune.spec.<section>.<Class>; the reference names them by class only
    text = re.sub(r"gaintune\.spec\.(?:[a-z_]+\.)?", "", text)
    for cls in ("<class '", "'>"):
        text = text.replace(cls, "")
    return text.replace("|", "\\|")


def _default(field) -> str:
    if field.default is not PydanticUndefined:
        return f"`{field.default!r}`"
    if field.default_factory is not None:
        try:
            value = field.default_factory()
        except TypeError:
            return "(see type)"
        if isinstance(value, BaseModel):
            return "defaults"
        if isinstance(value, list) and value and isinstance(value[0], BaseModel):
            return "one item with defaults"
        return f"`{value!r}`"
    return "**required**"


#: The reference's opening paragraphs: the limits, the number and key rules, MIMO specs and tunable blocks.
_INTRO: list[str] = [
    "# Spec reference",
    "",
    "Generated from the schema in `gaintune/spec/` by `python -m gaintune.spec.doc > docs/spec.md` "
    "(a test checks it is current).",
    f"Limits: horizon/dt <= {S.MAX_STEPS} steps, delay/dt (plant.delay, the top of randomize.delay) <= "
    f"{S.MAX_DELAY_STEPS} samples, plant order <= {S.MAX_ORDER}, cascade depth <= {S.MAX_LOOPS}.",
    "",
    "Numbers: every numeric field takes finite numbers only (NaN and infinity, YAML's `.nan`/`.inf` included, "
    "are refused), and `true`/`false` are refused where a number belongs rather than read as 1/0. "
    f"YAML: aliases (`*name`) may expand a document to at most {S.MAX_YAML_NODES:,} nodes. "
    f"Polynomials in `s` (`plant.tf.num`/`den` as text): every part can reach a degree of at most {S.MAX_ORDER}, "
    "bounded from the expression before it is expanded (products add degrees, powers multiply them). "
    "Names: an ODE state may not be named like the input, a parameter not like a state, the ODE input or, "
    "in a `tf` plant, the Laplace variable `s`. "
    "Keys: every section takes only the keys listed below; an unknown key is refused, naming the keys that "
    "section takes and the closest match (`requirements.ms`: did you mean ms_max?).",
    "",
    "Several inputs and loop graphs: a plant with several inputs is a `plant.tf_matrix` (a delay per entry), "
    "a `plant.ss` with named `inputs` (and `input_delays`), a nonlinear `plant.ode` with named `inputs` "
    "(`u0` then maps each input to its operating value, or is solved by least squares for equilibrium at "
    "`x0`), or a built-in model of that form (`wood_berry`, `quadruple_tank_min`, `quadruple_tank_nmp`, "
    "`quadruple_tank`, `quadruple_tank_nmp_ode`). Each loop then says what it drives: a plant "
    "input (`drives: R`) or the setpoint of another loop (`drives: loop:<name>`); loops side by side form "
    f"chains (at most {S.MAX_GRAPH_LOOPS} loops in all), each chain's outer loop follows a reference when a "
    "scenario names it (`reference: {loop: <name>, ...}`; the other chains hold their operating point). "
    "Without `drives` anywhere the loops are one cascade, outer first, as before. `actuators` gives each "
    "input its saturation, rate limit, delay and safe value; `ties` makes several gains one tuned value; "
    "`decoupler` puts a static matrix between the loops and the inputs; `feedforward` adds a gain times a "
    "chain's reference to an input; `scenarios[i].disturbance.input` names "
    "the input a disturbance enters, `scenarios[i].disturbance.state` a named state whose derivative it is "
    "added to (a load torque; state space and ODE plants). Refused with the field named: a matrix whose "
    "rows or entries do not "
    "match the outputs and inputs, a loop that drives an unknown input or loop, a cycle of drives, two loops "
    "driving one input, a tie between gains of different kinds or units, an unknown output, an unknown "
    "disturbed state, an ODE `u0` without a value for every input. The cost sums "
    "every chain's outer error (`iae` = the sum of `iae.<outer loop>`). Not yet: state-feedback loops, "
    "output disturbances, measurement noise, fallback gains and randomisation other than `randomize.params` "
    "in a MIMO spec (each refused by name). See docs/simulation.md.",
    "",
    "Tunable static blocks: an entry of `decoupler.matrix` and the `gain` of a `feedforward` item is a "
    "number (fixed) or `{value, bounds, tune}`, written like a loop gain. A tuned entry needs `bounds` of "
    "one sign (`[0.2, 3]` or `[-3, -0.2]`): the search covers the magnitude on a log scale, as for every "
    "gain, and the entry keeps that sign; `value` (inside the bounds) is the initial guess, else the "
    "bounds' geometric centre. Tuned entries are gains of the pseudo-loops `decoupler` (`d_<row input>_"
    "<column input>`, e.g. `d_R_S` for `matrix[0][1]` of `inputs: [R, S]`) and `feedforward` "
    "(`ff_<loop>_<input>`), after every loop's gains; a gain set names them like loops "
    "(`{xD: {...}, decoupler: {d_R_S: 1.4}, feedforward: {ff_xD_S: 0.05}}`), and a loop may not be named "
    "`decoupler` or `feedforward` while that block has tuned entries. A spec without tuned entries has the "
    "same gains as without the blocks. Example, Wood-Berry with a decoupler whose off-diagonal entries "
    "are tuned around the inverse steady-state gains (18.9/12.8 and 6.6/19.4): `decoupler: {inputs: [R, "
    "S], matrix: [[1, {value: 1.48, bounds: [0.3, 5]}], [{value: 0.34, bounds: [0.05, 2]}, 1]]}`. Per "
    "step the simulator applies `u = sat(W v + F r)`: `W` the candidate's decoupler (identity wiring where "
    "there is none), `v` the loops' outputs, `F r` the feedforward of the chains' references, before the "
    "input's saturation and rate limit; a back-calculation loop driving an input directly tracks the "
    "applied value less the feedforward, and a clamping loop driving an input directly holds its "
    "integrator when that input saturates on the loop's output plus the feedforward (a loop behind a "
    "decoupler: its own output limits only). The "
    "verification puts the candidate's `W` in front of the controller; the feedforward is outside the "
    "loop, so it changes the responses (and the cost), never the stability, margins or peaks. The exports "
    "write the tuned `W`, the feedforward table `FF` (inputs x chain references) and the tuned entries "
    "(`GT_DECOUPLER_D_R_S`, `gt_decoupler`, the payload's `blocks`). Refused with the field named: bounds "
    "that contain 0, a value outside its bounds, a tuned entry without bounds, a fixed entry without a "
    "value, a feedforward from an unknown loop or from a loop that takes another loop's output, to an "
    "unknown input, or twice for one pair.",
    "",
]


def render_markdown() -> str:
    """The spec reference as Markdown."""
    lines = list(_INTRO)
    for title, model in _SECTIONS:
        doc = " ".join(inspect.cleandoc(model.__doc__ or "").split("\n\n")[0].split())
        lines += [f"## `{title}`", "", doc, "", "| field | type | default | description |", "|---|---|---|---|"]
        hints = typing.get_type_hints(model)
        for name, field in model.model_fields.items():
            desc = (field.description or "").replace("|", "\\|")
            lines.append(f"| `{name}` | {_type(hints.get(name, field.annotation))} | {_default(field)} | {desc} |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    print(render_markdown())
