"""The tuning-problem schema: one pydantic model shared by the library, CLI and API.

A spec describes a plant, a cascade of control loops wrapped around it, the
actuator, the scenarios a gain set is scored on, the objective, the
requirements that verification enforces, domain randomisation, the safety
monitor and the search settings. Every field has a default, so a minimal spec
is a plant plus one loop::

    plant: {tf: {num: [1], den: "(s+1)^3"}}
    loops: [{type: pid}]

Numeric plant coefficients may be numbers or expressions over ``plant.params``
(parsed by :mod:`gaintune.plants.expr`, never ``eval``-ed), which is how
randomised LTI plants are expressed.

The schema is split by section; this package holds the top-level :class:`TuningSpec`
and :func:`load_spec` and re-exports every public name, so ``from gaintune.spec import ...``
is the one import path:

* :mod:`gaintune.spec.base`: the strict base model, finiteness checks and the limits
  (:data:`MAX_STEPS`, :data:`MAX_DELAY_STEPS`, :data:`MAX_ORDER`, :data:`MAX_LOOPS`, :data:`MAX_BUDGET`);
* :mod:`gaintune.spec.plant`: ``plant`` (transfer function, state space, ODE, built-in model);
* :mod:`gaintune.spec.loops`: ``loops`` (the cascade, gains, derivative filter) and ``actuator``;
* :mod:`gaintune.spec.scenarios`: ``scenarios``, ``objective`` and ``requirements``;
* :mod:`gaintune.spec.settings`: ``randomize``, ``safety``, ``search`` and ``verify``;
* :mod:`gaintune.spec.names`: what a spec or loop name may hold, and the identifier the exporters derive from it;
* :mod:`gaintune.spec.yamlload`: YAML loading with a bound on alias expansion (:data:`MAX_YAML_NODES`);
* :mod:`gaintune.spec.design`: the pidtune-style ``design`` shortcut, expanded into requirements and scenarios;
* :mod:`gaintune.spec.doc`: renders ``docs/spec.md`` from this schema (``python -m gaintune.spec.doc``).

Examples
--------
A :class:`TuningSpec` fills every default; a bad field is named in the error:

>>> spec = TuningSpec.model_validate({"plant": {"tf": {"num": [1], "den": "(s+1)^3"}}, "loops": [{"type": "pid"}]})
>>> spec.loops[0].name, spec.search.algo
('loop0', 'ppo')
>>> from pydantic import ValidationError
>>> try:
...     TuningSpec.model_validate({"plant": {"tf": {"num": [1], "den": [1, 1]}}, "loops": [{"type": "pq"}]})
... except ValidationError as exc:
...     print(exc.errors()[0]["loc"], exc.errors()[0]["msg"])
('loops', 0, 'type') Input should be 'p', 'pi', 'pd', 'pid', 'lqr' or 'lqi'
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pydantic import Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from gaintune.errors import SpecError
from gaintune.spec.base import (
    MAX_BUDGET,
    MAX_DELAY_STEPS,
    MAX_LOOPS,
    MAX_ORDER,
    MAX_STEPS,
    FiniteNumber,
    _error_at,
    _Model,
    check_delay_samples,
)
from gaintune.spec.blocks import BlockGainSpec, FeedforwardSpec
from gaintune.spec.design import DesignSpec, expand_design
from gaintune.spec.loops import GAIN_NAMES, ActuatorSpec, DerivativeFilterSpec, Gains, GainSpec, LoopSpec
from gaintune.spec.mimo import (
    MAX_GRAPH_LOOPS,
    ActuatorsEntrySpec,
    DecouplerSpec,
    SignalSpec,
    TfEntrySpec,
    TfMatrixSpec,
    check_architecture,
)
from gaintune.spec.names import ident_key, name_problem
from gaintune.spec.plant import (
    Coef,
    FiniteParams,
    ModelRefSpec,
    OdeSpec,
    PlantSpec,
    StateSpaceSpec,
    TransferFunctionSpec,
)
from gaintune.spec.scenarios import (
    DisturbanceSpec,
    ObjectiveSpec,
    ProfileSpec,
    ReferenceSpec,
    RequirementsSpec,
    ScenarioDefault,
    ScenarioSpec,
)
from gaintune.spec.settings import DistSpec, RandomizeSpec, RobustSpec, SafetySpec, SearchSpec, VerifySpec
from gaintune.spec.yamlload import MAX_YAML_NODES, load_yaml

__all__ = [
    "parse_json_or_yaml",
    "MAX_YAML_NODES",
    "MAX_STEPS",
    "MAX_DELAY_STEPS",
    "check_delay_samples",
    "MAX_ORDER",
    "MAX_BUDGET",
    "MAX_LOOPS",
    "MAX_GRAPH_LOOPS",
    "Coef",
    "TransferFunctionSpec",
    "StateSpaceSpec",
    "OdeSpec",
    "ModelRefSpec",
    "PlantSpec",
    "GainSpec",
    "DerivativeFilterSpec",
    "LoopSpec",
    "ActuatorSpec",
    "ProfileSpec",
    "ReferenceSpec",
    "SignalSpec",
    "TfEntrySpec",
    "TfMatrixSpec",
    "ActuatorsEntrySpec",
    "DecouplerSpec",
    "BlockGainSpec",
    "FeedforwardSpec",
    "ScenarioSpec",
    "ScenarioDefault",
    "ObjectiveSpec",
    "RequirementsSpec",
    "DistSpec",
    "RandomizeSpec",
    "SafetySpec",
    "RobustSpec",
    "SearchSpec",
    "VerifySpec",
    "TuningSpec",
    "load_spec",
    "GAIN_NAMES",
    "Gains",
    "DisturbanceSpec",
    "FiniteParams",
    "FiniteNumber",
]


#: Keys of a plant model file (models/*.yaml) that a tuning spec never has.
_MODEL_FILE_KEYS = ("title", "parameters", "input", "inputs", "outputs", "example")


class TuningSpec(_Model):
    """A complete gain-tuning problem."""

    name: str = Field(
        "untitled",
        description="Label of the spec, written into the exported files (gains.h, gains.m): printable text on one "
        "line, no control characters and no '/*' or '*/'.",
    )
    description: str = ""
    plant: PlantSpec
    # a single cascade holds at most MAX_LOOPS loops (checked with the graph); chains side by side more
    loops: list[LoopSpec] = Field(min_length=1, max_length=MAX_GRAPH_LOOPS)
    actuator: ActuatorSpec = Field(default_factory=ActuatorSpec)
    # the MIMO fields are left out of dumps while unset, so single-chain specs hash as before
    actuators: dict[str, ActuatorsEntrySpec] | None = Field(
        None, exclude_if=lambda v: v is None,
        description="Plants with several inputs: the actuator of each input, keyed by input name (an input left "
        "out is unlimited, without delay).")
    ties: list[list[str]] | None = Field(
        None, exclude_if=lambda v: v is None,
        description="Gains tuned as one value: each tie lists <loop>.<gain> of one kind and unit, e.g. "
        "[[j1.Kp, j2.Kp, j3.Kp]]; the first gain's settings (bounds, value) apply to all.")
    decoupler: DecouplerSpec | None = Field(
        None, exclude_if=lambda v: v is None,
        description="A static decoupler u = W v between the loops' outputs and the plant inputs; entries fixed "
        "or tuned.")
    feedforward: list[FeedforwardSpec] | None = Field(
        None, exclude_if=lambda v: v is None,
        description="Static reference feedforward: each item adds gain * (the reference of a chain's outer loop) "
        "to a plant input; gains fixed or tuned.")
    scenarios: list[ScenarioSpec] = Field(default_factory=lambda: [ScenarioSpec()], min_length=1)
    objective: ObjectiveSpec = Field(default_factory=ObjectiveSpec)
    requirements: RequirementsSpec = Field(default_factory=RequirementsSpec)
    randomize: RandomizeSpec = Field(default_factory=RandomizeSpec)
    safety: SafetySpec = Field(default_factory=SafetySpec)
    search: SearchSpec = Field(default_factory=SearchSpec)
    verify: VerifySpec = Field(default_factory=VerifySpec)
    design: DesignSpec | None = Field(
        None, description="pidtune-style shortcut: phase margin, focus; expanded into requirements and scenarios."
    )

    @model_validator(mode="before")
    @classmethod
    def _valid_unicode(cls, data: Any) -> Any:
        # JSON may carry a lone surrogate ("\ud800"): a valid Python str that no UTF-8 encoder
        # accepts, so the spec's hash and every dump of it would fail far from the input.
        bad = _lone_surrogate(data, "")
        if bad is not None:
            raise ValueError(f"{bad or 'spec'}: the text is not valid Unicode (a lone surrogate escape such as "
                             "\\ud800); use plain UTF-8 text")
        return data

    @field_validator("name")
    @classmethod
    def _printable_name(cls, v: str) -> str:
        # the name lands in comments of gains.h / gains.m: a newline or '*/' there would turn it into code
        problem = name_problem(v)
        if problem is not None:
            raise PydanticCustomError("spec_name", "{problem}", {"problem": f"spec name {v!r} {problem}"})
        return v

    @model_validator(mode="before")
    @classmethod
    def _not_a_model_file(cls, data: Any) -> Any:
        # Handing `tune` a file from models/ is a newcomer's first mistake; field by field it gave six
        # unknown-key errors (title, parameters, input, ...) and none said what the file is or what to run.
        if (isinstance(data, dict) and "loops" not in data and "plant" in data
                and any(k in data for k in _MODEL_FILE_KEYS)):
            name = data["name"] if isinstance(data.get("name"), str) else "NAME"
            raise ValueError(f"spec: this is a plant model file (a models/ entry), not a tuning spec: it has no "
                             f"'loops'. 'gaintune plants show {name} --spec > spec.yaml' writes a ready-to-run spec "
                             f"for it; a spec of your own uses it as plant: {{model: {name}}} (docs/models.md)")
        return data

    @model_validator(mode="before")
    @classmethod
    def _design_shortcut(cls, data: Any) -> Any:
        return expand_design(data) if isinstance(data, dict) else data

    @model_validator(mode="before")
    @classmethod
    def _single_scenario(cls, data: Any) -> Any:
        # Accept `scenario: {...}` as shorthand for a one-element `scenarios` list.
        if isinstance(data, dict) and "scenario" in data:
            data = dict(data)
            if "scenarios" in data:
                raise ValueError("give either 'scenario' or 'scenarios', not both")
            data["scenarios"] = [data.pop("scenario")]
        return data

    @model_validator(mode="after")
    def _loop_names(self) -> TuningSpec:
        for i, loop in enumerate(self.loops):
            if loop.name is None:
                loop.name = f"loop{i}"
        names = [lp.name for lp in self.loops]
        if len(set(names)) != len(names):
            raise ValueError(f"loop names must be unique, got {names}")
        self._check_identifiers()
        for i, loop in enumerate(self.loops):
            if loop.is_lq and i != len(self.loops) - 1 and loop.drives is None:
                raise ValueError(f"loops[{i}]: an {loop.type} loop must be the innermost (last) loop")
        self._check_delay_steps()
        check_architecture(self)
        mks = self.requirements.mks_max
        if isinstance(mks, dict) and set(mks) - set(names):
            raise _error_at(("requirements", "mks_max"), f"unknown loop(s) {sorted(set(mks) - set(names))}; the loops "
                            f"are {names}", mks)
        return self

    @property
    def loop_names(self) -> list[str]:
        """The loops' names, outer first (a validated spec names every loop: ``loop0``, ``loop1``, ... by default)."""
        return [lp.name or f"loop{i}" for i, lp in enumerate(self.loops)]

    def _check_identifiers(self) -> None:
        """Two loops whose names give one C/MATLAB identifier would redefine each other's gains in the exports."""
        seen: dict[str, int] = {}
        for i, loop in enumerate(self.loops):
            key = ident_key(loop.name or f"loop{i}")  # named by _loop_names already
            j = seen.setdefault(key, i)
            if j != i:
                msg = (f"loop name {loop.name!r} collides with loops[{j}].name {self.loops[j].name!r}: both become the "
                       f"identifier {key} in gains.h and gains.m; names must differ after every character other "
                       "than A-Z, a-z, 0-9 and _ becomes _ (and ignoring case), so rename one of them")
                raise _error_at(("loops", i, "name"), msg, loop.name)

    def _check_delay_steps(self) -> None:
        """A delay is held in a buffer of delay/dt samples per simulated lane: bound it like the horizon."""
        # a dt derived from the plant is checked where it is chosen (gaintune.classical.timescale)
        dt = min((sc.dt for sc in self.scenarios if sc.dt is not None), default=None)
        if dt is None:
            return
        delays = []
        try:  # a number, or an expression that is a plain number ("1e300"); parameter expressions are
            # bounded where the plant is built (gaintune.sim.simulator)
            if self.plant.delay is not None:
                delays.append(("plant.delay", float(self.plant.delay)))
        except ValueError:
            pass
        if self.randomize.delay is not None:
            delays.append(("randomize.delay", float(self.randomize.delay.box[1])))
        for where, d in delays:
            try:
                check_delay_samples(d, dt, where)
            except SpecError as exc:  # inside a validator pydantic wants a ValueError
                raise ValueError(str(exc)) from None

    def content_hash(self) -> str:
        """Stable SHA-256 of the canonical JSON of this spec (provenance)."""
        import hashlib

        return hashlib.sha256(self.model_dump_json().encode()).hexdigest()


def _lone_surrogate(data: Any, path: str) -> str | None:
    """The path of the first string (key or value) in ``data`` holding a lone surrogate, else None.

    Each container is visited once: one reached again through another reference (a YAML alias, a
    shared dict) was checked already, so shared and cyclic data cost their size, not the size of
    every copy. Paths are built only once a bad string is known to be there."""
    if not _has_bad_text(data):
        return None
    seen: set[int] = set()
    stack: list[tuple[Any, str]] = [(data, path)]
    while stack:
        node, at = stack.pop()
        if isinstance(node, str):
            if not _utf8(node):
                return at
            continue
        if not isinstance(node, (dict, list, tuple)) or id(node) in seen:
            continue
        seen.add(id(node))
        children = []
        for k, v in node.items() if isinstance(node, dict) else enumerate(node):
            sub = f"{at}.{k}" if at else str(k)
            if isinstance(k, str) and not _utf8(k):
                return sub
            children.append((v, sub))
        stack.extend(reversed(children))  # depth first, in document order
    return path


def _has_bad_text(data: Any) -> bool:
    """True when a string in ``data`` (a key or a value) is not valid UTF-8; each container once."""
    if isinstance(data, str):
        return not _utf8(data)
    seen: set[int] = set()
    stack = [data]
    while stack:
        node = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        if isinstance(node, dict):
            if not all(_utf8(k) for k in node if isinstance(k, str)):
                return True
            node = node.values()
        elif not isinstance(node, (list, tuple)):
            continue
        for x in node:
            if isinstance(x, str):
                if not _utf8(x):
                    return True
            elif isinstance(x, (dict, list, tuple)):
                stack.append(x)
    return False


def _utf8(text: str) -> bool:
    if text.isascii():
        return True
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def parse_json_or_yaml(text: str) -> Any:
    """Parse ``text`` as JSON when it starts with ``{`` or ``[``, else as YAML.

    YAML aliases may expand the document to at most :data:`MAX_YAML_NODES` nodes.

    Raises
    ------
    ValueError
        With the parser's message when the text is not valid (JSON's error is a ValueError; YAML's
        is re-raised as one), or when the YAML expands beyond :data:`MAX_YAML_NODES` nodes.
    """
    try:
        if text.lstrip().startswith(("{", "[")):
            return json.loads(text)
        return load_yaml(text)
    except RecursionError:
        raise ValueError("nested too deeply (thousands of levels of lists or mappings)") from None


def load_spec(source: str | Path | dict[str, Any]) -> TuningSpec:
    """Load and validate a spec from a YAML/JSON file path, a YAML/JSON string or a dict.

    Parameters
    ----------
    source
        A path ending in ``.yaml``, ``.yml`` or ``.json`` (a regular file of at most 10 MB), the
        YAML/JSON text itself, or the spec as a dict.

    Returns
    -------
    TuningSpec
        The validated spec.

    Raises
    ------
    SpecError
        When the file cannot be read or parsed, or the content is not a mapping.
    pydantic.ValidationError
        When a field is invalid (the message names the field).

    Examples
    --------
    >>> spec = load_spec("plant: {tf: {num: [1], den: '(s+1)^3'}}\\nloops: [{type: pi}]\\n")
    >>> spec.loops[0].type, spec.plant.tf.den
    ('pi', '(s+1)^3')
    >>> load_spec("- not\\n- a mapping\\n")
    Traceback (most recent call last):
        ...
    gaintune.errors.SpecError: spec: must be a mapping with at least 'plant' and 'loops'
    """
    if isinstance(source, dict):
        data = source
    elif not isinstance(source, (str, Path)):
        raise SpecError("spec", f"expected a file path, a YAML/JSON string or a dict, got {type(source).__name__}")
    else:
        text: str
        path = Path(source) if not (isinstance(source, str) and "\n" in source) else None
        if path is not None and path.suffix.lower() in (".yaml", ".yml", ".json") :
            from gaintune.files import read_text_bounded

            try:  # a regular file up to 10 MB only: /dev/zero or a FIFO is refused before anything is read
                text = read_text_bounded(path, "spec")
            except SpecError as exc:
                raise SpecError("spec", f"cannot read the spec file: {exc.message}") from None
        else:
            text = str(source)
        try:
            data = parse_json_or_yaml(text)
        except ValueError as exc:
            raise SpecError("spec", f"not valid YAML/JSON: {exc}") from None
    if not isinstance(data, dict):
        raise SpecError("spec", "must be a mapping with at least 'plant' and 'loops'")
    return TuningSpec.model_validate(data)

