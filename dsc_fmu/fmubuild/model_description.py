"""The model descriptions pythonfmu writes, completed: model exchange beside co-simulation, units, exact
start values, ranges, nominals, derivatives and ModelStructure with the dependencies the model code has
(FMI 2.0 and 3.0), and the documentation page made from them."""

from __future__ import annotations

from xml.etree import ElementTree as ET

from ..models.parameters import NONNEGATIVE
from ..registry import FmuSpec
from .documentation import documentation_html
from .structure import TIME, continuous_dependencies, initial_dependencies

__all__ = ["UNITS", "complete_model_description", "complete_model_description3", "documentation"]

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
}

def _unit_definitions(used) -> ET.Element:
    units = ET.Element("UnitDefinitions")
    for name in sorted(used):
        ET.SubElement(ET.SubElement(units, "Unit", name=name), "BaseUnit", {k: str(e) for k, e in UNITS[name].items()})
    return units


def _complete_variable(typed: ET.Element, v, real: bool) -> None:
    """Unit and exact start value (Real / Float64), ``min`` and ``max`` of the table variable ``v``."""
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
                        "canGetAndSetFMUState", "canSerializeFMUState")


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
    """A state's nominal, a derivative's ``derivative`` attribute (``reference``: name -> how the
    model description refers to a variable)."""
    for state in spec.states:
        if name == state.variable.name:
            typed.set("nominal", repr(float(state.nominal)))
        elif name == state.derivative.name:
            typed.set("derivative", reference[state.variable.name])


def _structure(spec: FmuSpec, reference: dict, discrete: list) -> dict:
    """The outputs, derivatives, initial unknowns and event indicators of ModelStructure as
    ``(name, dependencies)``; dependencies None where the model description states none (every known).
    ``discrete``: the discrete outputs, which depend on ``spec.depends``."""
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
    return {"outputs": outputs + discrete, "derivatives": derivatives, "initial": unknowns, "indicators": indicators}


def _discrete_outputs(variables: ET.Element, spec: FmuSpec) -> list:
    continuous = {v.name for v in spec.outputs}
    return [v.get("name") for v in variables if v.get("causality") == "output" and v.get("name") not in continuous]


def _unknown(parent: ET.Element, tag: str, key: str, ref: str, dependencies: str | None) -> None:
    attributes = {key: ref} if dependencies is None else {key: ref, "dependencies": dependencies}
    ET.SubElement(parent, tag, attributes)


def complete_model_description(xml: bytes, spec: FmuSpec) -> ET.Element:
    """Complete the FMI 2.0 model description that pythonfmu writes.

    Adds what pythonfmu does not write: model exchange beside co-simulation, units, exact start
    values, ranges, nominals, derivatives, the number of event indicators and ModelStructure with its
    dependencies (``structure``). An FMU with inputs declares ``canInterpolateInputs`` (the project's
    binary takes input derivatives).

    Parameters
    ----------
    xml : bytes
        ``modelDescription.xml`` as pythonfmu wrote it.
    spec : registry.FmuSpec
        The FMU it describes.

    Returns
    -------
    xml.etree.ElementTree.Element
        The completed root element, not indented.
    """
    root = ET.fromstring(xml)
    tables = spec.variables
    cosimulation = root.find("CoSimulation")
    if spec.inputs:
        cosimulation.set("canInterpolateInputs", "true")
    _model_exchange(root, cosimulation, 2)
    root.set("numberOfEventIndicators", str(len(spec.indicators)))
    position = list(root).index(cosimulation) + 1
    root.insert(position, _unit_definitions({v.unit for v in tables.values() if not v.integer}))

    variables = root.find("ModelVariables")
    index = {scalar.get("name"): str(i) for i, scalar in enumerate(variables, start=1)}
    for scalar in variables:
        name = scalar.get("name")
        v = tables.get(name)
        if v is not None:
            _complete_variable(scalar[0], v, scalar[0].tag == "Real")
        _declare_states(scalar, scalar[0], name, spec, index)

    parts = _structure(spec, index, _discrete_outputs(variables, spec))
    structure = root.find("ModelStructure")
    structure.clear()
    for tag, key in (("Outputs", "outputs"), ("Derivatives", "derivatives")):
        element = ET.SubElement(structure, tag)
        for name, dependencies in sorted(parts[key], key=lambda item: int(index[item[0]])):
            _unknown(element, "Unknown", "index", index[name], dependencies)
    initial = ET.SubElement(structure, "InitialUnknowns")
    for name, dependencies in sorted(parts["initial"].items(), key=lambda item: int(index[item[0]])):
        _unknown(initial, "Unknown", "index", index[name], dependencies)
    return root


def complete_model_description3(xml: bytes, spec: FmuSpec) -> ET.Element:
    """Complete the FMI 3.0 model description that pythonfmu3 writes.

    Adds model exchange, units (pythonfmu3 writes them only if registered), exact start values,
    ranges, nominals, derivatives and ModelStructure with its dependencies (by value reference, the
    time included; pythonfmu3 writes none) and event indicators.

    Parameters
    ----------
    xml : bytes
        ``modelDescription.xml`` as pythonfmu3 wrote it.
    spec : registry.FmuSpec
        The FMU it describes.

    Returns
    -------
    xml.etree.ElementTree.Element
        The completed root element, not indented.
    """
    root = ET.fromstring(xml)
    tables = spec.variables
    cosimulation = root.find("CoSimulation")
    # pythonfmu3 0.3.4 copies the last common option's value into canHandleVariableCommunicationStepSize.
    cosimulation.set("canHandleVariableCommunicationStepSize", "true")
    _model_exchange(root, cosimulation, 3)
    for old in root.findall("UnitDefinitions"):
        root.remove(old)
    position = list(root).index(cosimulation) + 1
    root.insert(position, _unit_definitions({"s"} | {v.unit for v in tables.values() if not v.integer}))

    variables = root.find("ModelVariables")
    refs = {variable.get("name"): variable.get("valueReference") for variable in variables}
    refs[TIME] = next(variable.get("valueReference") for variable in variables
                      if variable.get("causality") == "independent")
    for variable in variables:
        name = variable.get("name")
        if variable.get("causality") == "independent":
            variable.set("unit", "s")
        v = tables.get(name)
        if v is not None:
            _complete_variable(variable, v, variable.tag == "Float64")
        _declare_states(variable, variable, name, spec, refs)

    parts = _structure(spec, refs, _discrete_outputs(variables, spec))
    structure = root.find("ModelStructure")
    structure.clear()
    for tag, key in (("Output", "outputs"), ("ContinuousStateDerivative", "derivatives")):
        for name, dependencies in sorted(parts[key], key=lambda item: int(refs[item[0]])):
            _unknown(structure, tag, "valueReference", refs[name], dependencies)
    for name, dependencies in sorted(parts["initial"].items(), key=lambda item: int(refs[item[0]])):
        _unknown(structure, "InitialUnknown", "valueReference", refs[name], dependencies)
    for name, dependencies in parts["indicators"]:
        _unknown(structure, "EventIndicator", "valueReference", refs[name], dependencies)
    return root


def documentation(root: ET.Element, spec: FmuSpec) -> bytes:
    """The FMU's ``documentation/index.html``.

    Parameters
    ----------
    root : xml.etree.ElementTree.Element
        The FMU's completed model description (``complete_model_description`` or
        ``complete_model_description3``).
    spec : registry.FmuSpec
        The FMU it describes.

    Returns
    -------
    bytes
        The HTML page, UTF-8.
    """
    units = {"time": "s", "beta_guard_count": "1", **{name: v.unit for name, v in spec.variables.items()}}
    return documentation_html(root, spec.name, units).encode("utf-8")
