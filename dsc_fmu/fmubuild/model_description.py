"""The model descriptions pythonfmu writes, completed: model exchange beside co-simulation, units, exact
start values, ranges, nominals, derivatives and ModelStructure with the dependencies the model code has
(FMI 2.0 and 3.0), and the documentation page made from them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from xml.etree import ElementTree as ET

from ..models.parameters import NONNEGATIVE
from ..registry import FmuSpec
from .documentation import documentation_html
from .structure import TIME, continuous_dependencies, initial_dependencies

__all__ = ["UNITS"]

# Exponents of the SI base units (kg, m, s, A, rad) of every unit the FMUs use.
UNITS = {
    "1": {},
    "m": {"m": 1},
    "rad": {"rad": 1},
    "s": {"s": 1},
    "kg": {"kg": 1},
    "kg.m2": {"kg": 1, "m": 2},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "rad/s": {"rad": 1, "s": -1},
    "rad/s2": {"rad": 1, "s": -2},
    "1/s": {"s": -1},
    "A/s": {"A": 1, "s": -1},
    "1/(m.s)": {"m": -1, "s": -1},
    "1/m": {"m": -1},
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1},
    "A": {"A": 1},
    "Ohm": {"kg": 1, "m": 2, "s": -3, "A": -2},
    "H": {"kg": 1, "m": 2, "s": -2, "A": -2},
    "V.s/rad": {"kg": 1, "m": 2, "s": -2, "A": -1, "rad": -1},
    "N.m/A": {"kg": 1, "m": 2, "s": -2, "A": -1},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "Hz": {"s": -1},
}

def _unit_definitions(used) -> ET.Element:
    units = ET.Element("UnitDefinitions")
    for name in sorted(used):
        ET.SubElement(ET.SubElement(units, "Unit", name=name), "BaseUnit", {k: str(e) for k, e in UNITS[name].items()})
    return units


def _complete_variable(typed: ET.Element, v, real: bool) -> None:
    """Unit and exact start value (Real, Float64), ``min`` and ``max`` of the table variable ``v``."""
    if real:
        typed.set("unit", v.unit)
        if typed.get("start") is not None:
            typed.set("start", repr(float(v.start)))
    if v.bound == NONNEGATIVE:
        typed.set("min", "0")
    if v.minimum is not None:
        typed.set("min", f"{v.minimum:g}")
    if v.maximum is not None:
        typed.set("max", f"{v.maximum:g}")


# The capabilities both interfaces share, copied from what the FMI library writes for co-simulation.
_SHARED_CAPABILITIES = ("needsExecutionTool", "canBeInstantiatedOnlyOncePerProcess",
                        "canNotUseMemoryManagementFunctions", "canGetAndSetFMUstate", "canSerializeFMUstate",
                        "canGetAndSetFMUState", "canSerializeFMUState", "providesDirectionalDerivative",
                        "providesDirectionalDerivatives", "providesAdjointDerivatives")

# The exact partial derivatives the binary provides (fmi2GetDirectionalDerivative; fmi3GetDirectionalDerivative
# and fmi3GetAdjointDerivative), under each version's names.
_PARTIALS = {2: {"providesDirectionalDerivative": "true"},
             3: {"providesDirectionalDerivatives": "true", "providesAdjointDerivatives": "true"}}


# That no step needs fmiCompletedIntegratorStep, under each version's name for it.
_NO_COMPLETED_STEP = {2: ("completedIntegratorStepNotNeeded", "true"), 3: ("needsCompletedIntegratorStep", "false")}


def _model_exchange(root: ET.Element, cosimulation: ET.Element, fmi_version: int) -> None:
    """Declare model exchange beside co-simulation: one binary, the same capabilities, no
    CompletedIntegratorStep needed (the switches change only at state events)."""
    shared = {name: cosimulation.get(name) for name in _SHARED_CAPABILITIES if cosimulation.get(name) is not None}
    flag, value = _NO_COMPLETED_STEP[fmi_version]
    element = ET.Element("ModelExchange", {"modelIdentifier": cosimulation.get("modelIdentifier"), flag: value,
                                           **shared})
    root.insert(list(root).index(cosimulation), element)


def _declare_states(variable: ET.Element, typed: ET.Element, name: str, spec: FmuSpec, reference: dict) -> None:
    """A state's nominal, a derivative's ``derivative`` attribute."""
    for state in spec.states:
        if name == state.variable.name:
            typed.set("nominal", repr(float(state.nominal)))
        elif name == state.derivative.name:
            typed.set("derivative", reference[state.variable.name])


def _structure(spec: FmuSpec, reference: dict, discrete: list) -> dict:
    """ModelStructure's parts as ``(name, dependencies)``, None where it states none (every known)."""
    continuous, initial = continuous_dependencies(spec), initial_dependencies(spec)

    def refs(names):
        return " ".join(sorted((reference[name] for name in names if name in reference), key=int))

    outputs = [(v.name, refs(continuous[v.name])) for v in spec.outputs]
    discrete = [(name, refs(spec.depends.get(name, ()))) for name in discrete]
    derivatives = [(s.derivative.name, refs(continuous[s.derivative.name])) for s in spec.states]
    unknowns = {v.name: refs(initial[v.name]) for v in spec.outputs}
    unknowns.update({s.variable.name: refs(initial[s.variable.name]) for s in spec.states})
    unknowns.update({s.derivative.name: refs(initial[s.derivative.name]) for s in spec.states})
    unknowns.update({name: None for name, _ in discrete})
    indicators = [(v.name, refs(continuous[v.name])) for v in spec.indicators]
    return {"outputs": outputs + discrete, "derivatives": derivatives, "initial": list(unknowns.items()),
            "indicators": indicators}


def _discrete_outputs(variables: ET.Element, spec: FmuSpec) -> list:
    continuous = {v.name for v in spec.outputs}
    return [v.get("name") for v in variables if v.get("causality") == "output" and v.get("name") not in continuous]


def _unknown(parent: ET.Element, tag: str, key: str, ref: str, dependencies: str | None) -> None:
    attributes = {key: ref} if dependencies is None else {key: ref, "dependencies": dependencies}
    ET.SubElement(parent, tag, attributes)


@dataclass(frozen=True)
class _Version:
    """What the FMI 2.0 and 3.0 model descriptions spell differently, for the one completer.

    ``scalar_wrapped``: a variable's type and attributes sit in a child element (FMI 2.0
    ``ScalarVariable``), not on the variable; ``real``: the tag of a real variable; ``key``: how
    ModelStructure refers to a variable, by position from 1 (``index``) or by ``valueReference``;
    ``structure``: ModelStructure's parts as ``(group element or None, element, part of _structure,
    sorted by reference)``; ``indicator_count``: the number of event indicators is a root attribute;
    ``cosimulation``: the CoSimulation attributes to set for a spec.
    """

    number: int
    scalar_wrapped: bool
    real: str
    key: str
    structure: tuple
    indicator_count: bool
    cosimulation: Callable[[FmuSpec], dict]


_VERSIONS = {
    2: _Version(2, True, "Real", "index", (("Outputs", "Unknown", "outputs", True),
                                           ("Derivatives", "Unknown", "derivatives", True),
                                           ("InitialUnknowns", "Unknown", "initial", True)), True,
                # The project's binary takes input derivatives.
                lambda spec: {**_PARTIALS[2], **({"canInterpolateInputs": "true"} if spec.inputs else {})}),
    3: _Version(3, False, "Float64", "valueReference", ((None, "Output", "outputs", True),
                                                         (None, "ContinuousStateDerivative", "derivatives", True),
                                                         (None, "InitialUnknown", "initial", True),
                                                         (None, "EventIndicator", "indicators", False)), False,
                # pythonfmu3 0.3.4 copies the last common option's value into this one.
                lambda spec: {"canHandleVariableCommunicationStepSize": "true", **_PARTIALS[3]}),
}


def _references(variables: ET.Element, version: _Version) -> dict:
    """How ModelStructure refers to each variable by name, ``structure.TIME`` included where declared."""
    if version.key == "index":
        references = {variable.get("name"): str(i) for i, variable in enumerate(variables, start=1)}
    else:
        references = {variable.get("name"): variable.get("valueReference") for variable in variables}
    for variable in variables:
        if variable.get("causality") == "independent":
            references[TIME] = references[variable.get("name")]
    return references


def _complete_variables(variables: ET.Element, spec: FmuSpec, version: _Version, references: dict) -> None:
    """Units, exact start values, ranges, nominals and derivatives of every variable."""
    for variable in variables:
        name = variable.get("name")
        typed = variable[0] if version.scalar_wrapped else variable
        if variable.get("causality") == "independent":
            typed.set("unit", "s")
        v = spec.variables.get(name)
        if v is not None:
            _complete_variable(typed, v, typed.tag == version.real)
        _declare_states(variable, typed, name, spec, references)


def _write_structure(root: ET.Element, spec: FmuSpec, version: _Version, references: dict) -> None:
    """ModelStructure with the dependencies the model code has, in the version's layout."""
    parts = _structure(spec, references, _discrete_outputs(root.find("ModelVariables"), spec))
    structure = root.find("ModelStructure")
    structure.clear()
    for group, tag, part, ordered in version.structure:
        parent = structure if group is None else ET.SubElement(structure, group)
        unknowns = parts[part]
        if ordered:
            unknowns = sorted(unknowns, key=lambda item: int(references[item[0]]))
        for name, dependencies in unknowns:
            _unknown(parent, tag, version.key, references[name], dependencies)


def complete_model_description(xml: bytes, spec: FmuSpec, fmi_version: int = 2) -> ET.Element:
    """The root element (not indented) of ``modelDescription.xml`` as pythonfmu (FMI 2.0) or pythonfmu3 (3.0) wrote it,
    completed: model exchange beside co-simulation, units, exact start values, ranges, nominals, derivatives and
    ModelStructure with its dependencies (``structure``: FMI 3.0 by value reference with the time and event
    indicators, FMI 2.0 by index), ``canInterpolateInputs`` for an FMI 2.0 FMU with inputs, and the exact partial
    derivatives the binary provides.
    """
    version = _VERSIONS[fmi_version]
    root = ET.fromstring(xml)
    cosimulation = root.find("CoSimulation")
    for attribute, value in version.cosimulation(spec).items():
        cosimulation.set(attribute, value)
    _model_exchange(root, cosimulation, version.number)
    if version.indicator_count:
        root.set("numberOfEventIndicators", str(len(spec.indicators)))
    for old in root.findall("UnitDefinitions"):
        root.remove(old)
    variables = root.find("ModelVariables")
    used = {v.unit for v in spec.variables.values() if not v.integer}
    if any(variable.get("causality") == "independent" for variable in variables):
        used.add("s")
    root.insert(list(root).index(cosimulation) + 1, _unit_definitions(used))
    references = _references(variables, version)
    _complete_variables(variables, spec, version, references)
    _write_structure(root, spec, version, references)
    return root


def documentation(root: ET.Element, spec: FmuSpec, requirements: str) -> bytes:
    """The FMU's ``documentation/index.html`` (UTF-8) from its completed model description and what the importing
    machine needs."""
    units = {"time": "s", "beta_guard_count": "1", "saturation_count": "1",
             **{name: v.unit for name, v in spec.variables.items()}}
    return documentation_html(root, spec.name, units, requirements).encode("utf-8")
