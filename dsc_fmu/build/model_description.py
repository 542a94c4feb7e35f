"""The model descriptions pythonfmu writes, completed: units, exact start values, ranges, output
dependencies and initial unknowns (FMI 2.0 and 3.0), and the documentation page made from them."""

from __future__ import annotations

from xml.etree import ElementTree as ET

from ..models.parameters import NONNEGATIVE
from ..registry import FmuSpec
from .documentation import documentation_html

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


def complete_model_description(xml: bytes, spec: FmuSpec) -> ET.Element:
    """Add units, ranges, output dependencies and initial unknowns that pythonfmu does not write (FMI 2.0);
    an FMU with inputs declares ``canInterpolateInputs`` (the project's binary takes input derivatives)."""
    root = ET.fromstring(xml)
    tables = spec.variables
    if spec.inputs:
        root.find("CoSimulation").set("canInterpolateInputs", "true")
    position = list(root).index(root.find("CoSimulation")) + 1
    root.insert(position, _unit_definitions({v.unit for v in tables.values() if not v.integer}))

    variables = root.find("ModelVariables")
    index = {}
    for i, scalar in enumerate(variables, start=1):
        name = scalar.get("name")
        index[name] = i
        v = tables.get(name)
        if v is not None:
            _complete_variable(scalar[0], v, scalar[0].tag == "Real")

    structure = root.find("ModelStructure")
    structure.clear()
    outputs = ET.SubElement(structure, "Outputs")
    initial = ET.SubElement(structure, "InitialUnknowns")
    for scalar in variables:
        if scalar.get("causality") != "output":
            continue
        name = scalar.get("name")
        depends = " ".join(str(index[d]) for d in spec.depends.get(name, ()))
        ET.SubElement(outputs, "Unknown", index=str(index[name]), dependencies=depends)
        ET.SubElement(initial, "Unknown", index=str(index[name]))
    return root


def complete_model_description3(xml: bytes, spec: FmuSpec) -> ET.Element:
    """The same for FMI 3.0: units, exact starts, ranges, and ModelStructure with real dependencies
    (by value reference); pythonfmu3 writes units only if registered and no dependencies."""
    root = ET.fromstring(xml)
    tables = spec.variables
    cosimulation = root.find("CoSimulation")
    # pythonfmu3 0.3.4 copies the last common option's value into canHandleVariableCommunicationStepSize.
    cosimulation.set("canHandleVariableCommunicationStepSize", "true")
    for old in root.findall("UnitDefinitions"):
        root.remove(old)
    position = list(root).index(cosimulation) + 1
    root.insert(position, _unit_definitions({"s"} | {v.unit for v in tables.values() if not v.integer}))

    variables = root.find("ModelVariables")
    refs = {}
    for variable in variables:
        name = variable.get("name")
        refs[name] = variable.get("valueReference")
        if variable.get("causality") == "independent":
            variable.set("unit", "s")
        v = tables.get(name)
        if v is not None:
            _complete_variable(variable, v, variable.tag == "Float64")

    structure = root.find("ModelStructure")
    structure.clear()
    outputs = [variable.get("name") for variable in variables if variable.get("causality") == "output"]
    for name in outputs:
        depends = " ".join(refs[d] for d in spec.depends.get(name, ()))
        ET.SubElement(structure, "Output", valueReference=refs[name], dependencies=depends)
    for name in outputs:
        ET.SubElement(structure, "InitialUnknown", valueReference=refs[name])
    return root


def documentation(root: ET.Element, spec: FmuSpec) -> bytes:
    """The FMU's ``documentation/index.html`` from its completed model description."""
    units = {"time": "s", "beta_guard_count": "1", **{name: v.unit for name, v in spec.variables.items()}}
    return documentation_html(root, spec.name, units).encode("utf-8")
