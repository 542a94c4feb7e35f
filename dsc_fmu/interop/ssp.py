"""The closed loop as an SSP 1.0 archive, and runs of it with fmpy.ssp (libcosim's: ``interop.libcosim``).

The SSD and the parameter sets are validated against the SSP 1.0 schemas (``dsc_fmu/interop/schemas/ssp``, from
the Modelica Association, BSD licence) before anything is written; what the archive holds and how each tool
runs it: docs/other-tools.md."""

from __future__ import annotations

import io
import math
import re
import zipfile
from pathlib import Path

import numpy as np
from lxml import etree

from ..cosim import signals
from ..errors import DscFmuError
from ..identity import require_fmi2
from ..models.parameters import START_ON
from ..platforms import LINUX_AARCH64, host_platform
from ..registry import CONNECTIONS, CONTROLLER, ORDER, fmu_files
from ..scenario import Interface, Scenario, ScenarioError, one_of

__all__ = ["FMI2_ONLY", "SSD_NAMESPACES", "SCHEMA_DIR", "export_ssp", "run_simulate_ssp", "SSPError"]

SSD, SSC, SSV = (f"http://ssp-standard.org/SSP1/{name}" for name in
                 ("SystemStructureDescription", "SystemStructureCommon", "SystemStructureParameterValues"))
OSP = "http://opensimulationplatform.com/SSP/OSPAnnotations"
OMS = "https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd"
SSD_NAMESPACES = {"ssd": SSD, "ssc": SSC, "ssv": SSV, "osp": OSP, "oms": OMS}
FMI2_ONLY = ("no SSP importer runs the loop of FMI 3.0 FMUs (fmpy's and libcosim's take FMI 2.0, OMSimulator "
             "refuses ReferenceRobot's FMI 3.0 dependencies)")
SCHEMA_DIR = Path(__file__).parent / "schemas" / "ssp"
SYSTEM_NAME = "DSCClosedLoop"
_NOT_IDENT = re.compile(r"[^A-Za-z0-9_]")
"""A character OMSimulator refuses in a name: its identifiers match ``^[a-zA-Z][a-zA-Z0-9_]*$``."""


class SSPError(DscFmuError, RuntimeError):
    """An SSP archive that does not validate or that a tool cannot run."""


def _schema(name: str) -> etree.XMLSchema:
    folder = SCHEMA_DIR
    if not (folder / name).is_file():  # an install without the package data: fmpy ships the same files
        import fmpy.ssp

        folder = Path(fmpy.ssp.__file__).parent / "schema"
    return etree.XMLSchema(etree.parse(str(folder / name)))


def _variables(path: Path) -> dict:
    from fmpy import read_model_description

    return {v.name: v for v in read_model_description(str(path)).modelVariables}


def _number(value: float) -> str:
    return repr(float(value))


def model_name(scenario_name: str) -> str:
    """The SSD's name for a scenario, an identifier OMSimulator accepts: ``dsc_fmu_`` and the name, each
    character other than an ASCII letter, digit or underscore replaced by ``_`` (``my run-2``: ``dsc_fmu_my_run_2``)."""
    return _NOT_IDENT.sub("_", f"dsc_fmu_{scenario_name}")


def _annotation(parent: etree._Element, kind: str) -> etree._Element:
    """An ``ssd:Annotations`` holding one ``ssc:Annotation`` of ``kind``; returns the annotation."""
    annotations = etree.SubElement(parent, f"{{{SSD}}}Annotations")
    return etree.SubElement(annotations, f"{{{SSC}}}Annotation", type=kind)


def _omsimulator_system(system: etree._Element, scenario: Scenario, interface: Interface) -> None:
    """OMSimulator's simulation information, which tells its kind of system: a fixed-step master of
    co-simulation FMUs (``oms-ma`` at the communication step) or CVode over model-exchange FMUs (at
    the scenario's tolerance, its largest step and result interval the output interval; CVode
    chooses the first and the smallest step)."""
    annotation = _annotation(system, "org.openmodelica")
    information = etree.SubElement(etree.SubElement(annotation, f"{{{OMS}}}Annotations"),
                                   f"{{{OMS}}}SimulationInformation")
    simulation = scenario.simulation
    if interface is Interface.CO_SIMULATION:
        etree.SubElement(information, f"{{{OMS}}}FixedStepMaster", description="oms-ma",
                         stepSize=_number(simulation.step_size))
        return
    from ..cosim.model_exchange import DEFAULT_TOLERANCE

    tolerance = DEFAULT_TOLERANCE if simulation.tolerance is None else simulation.tolerance
    etree.SubElement(information, f"{{{OMS}}}VariableStepSolver", description="cvode",
                     relativeTolerance=_number(tolerance), maximumStepSize=_number(simulation.output_interval))


def _parameter_set(name: str, parameters: dict, variables: dict) -> etree._Element:
    root = etree.Element(f"{{{SSV}}}ParameterSet", nsmap={"ssv": SSV}, version="1.0", name=name)
    holder = etree.SubElement(root, f"{{{SSV}}}Parameters")
    for key, value in parameters.items():
        parameter = etree.SubElement(holder, f"{{{SSV}}}Parameter", name=key)
        if variables[key].type == "Integer":
            etree.SubElement(parameter, f"{{{SSV}}}Integer", value=str(int(value)))
        else:
            etree.SubElement(parameter, f"{{{SSV}}}Real", value=_number(value))
    return root


def _connectors(name: str, variables: dict) -> list[tuple[str, str, str]]:
    """(connector name, kind, SSP type) of a component: its inputs and the outputs we record."""
    names = [v for v in variables.values() if v.causality == "input"]
    names += [variables[o] for o in signals.RECORDED[name]]
    return [(v.name, v.causality, v.type) for v in names]


def _build_ssd(scenario: Scenario, variables: dict[str, dict],
               interface: Interface = Interface.CO_SIMULATION) -> tuple[bytes, dict]:
    """The SSD (not yet validated) and the parameter sets (archive path -> XML) of a scenario's closed loop;
    ``variables`` by FMU and name, ``interface`` for OMSimulator's annotation (libcosim's is written for both)."""
    root = etree.Element(f"{{{SSD}}}SystemStructureDescription", nsmap=SSD_NAMESPACES, version="1.0",
                         name=model_name(scenario.name), description=f"dsc-fmu, scenario {scenario.name}")
    system = etree.SubElement(root, f"{{{SSD}}}System", name=SYSTEM_NAME,
                              description=f"DSC closed loop, scenario {scenario.name}")
    elements = etree.SubElement(system, f"{{{SSD}}}Elements")
    sets = {}
    for name in ORDER:
        component = etree.SubElement(elements, f"{{{SSD}}}Component", name=name,
                                     source=f"resources/{name}.fmu", type="application/x-fmu-sharedlibrary")
        holder = etree.SubElement(component, f"{{{SSD}}}Connectors")
        for connector, kind, kind_type in _connectors(name, variables[name]):
            element = etree.SubElement(holder, f"{{{SSD}}}Connector", name=connector, kind=kind)
            etree.SubElement(element, f"{{{SSC}}}{kind_type}")
        source = f"resources/{name}.ssv"
        sets[source] = etree.tostring(_parameter_set(f"{scenario.name}_{name}", scenario.parameters(name),
                                                     variables[name]),
                                      xml_declaration=True, encoding="UTF-8", pretty_print=True)
        bindings = etree.SubElement(component, f"{{{SSD}}}ParameterBindings")
        etree.SubElement(bindings, f"{{{SSD}}}ParameterBinding", source=source,
                         type="application/x-ssp-parameter-set")
    holder = etree.SubElement(system, f"{{{SSD}}}Connections")
    for c in CONNECTIONS:
        etree.SubElement(holder, f"{{{SSD}}}Connection", startElement=c.start, startConnector=c.signal,
                         endElement=c.end, endConnector=c.signal)
    _omsimulator_system(system, scenario, interface)
    experiment = etree.SubElement(root, f"{{{SSD}}}DefaultExperiment", startTime="0.0",
                                  stopTime=_number(scenario.simulation.stop_time))
    # declared on the root: libcosim reads every child of osp:Algorithm, attributes included, as an algorithm
    algorithm = etree.SubElement(_annotation(experiment, "com.opensimulationplatform"), f"{{{OSP}}}Algorithm")
    etree.SubElement(algorithm, f"{{{OSP}}}FixedStepAlgorithm", baseStepSize=_number(scenario.simulation.step_size))
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True), sets


def _check(xml: bytes, schema: str, what: str) -> None:
    validator = _schema(schema)
    if not validator.validate(etree.fromstring(xml)):
        problems = "; ".join(f"line {e.line}: {e.message}" for e in validator.error_log)
        raise SSPError(f"{what} does not validate against {schema}: {problems}")


def validate_ssp(ssp_file: Path | str) -> None:
    """Validate an archive's SSD and parameter sets against the SSP 1.0 schemas; SSPError naming each problem's line."""
    with zipfile.ZipFile(ssp_file) as archive:
        _check(archive.read("SystemStructure.ssd"), "SystemStructureDescription.xsd", f"{ssp_file}: SystemStructure.ssd")
        for item in archive.namelist():
            if item.endswith(".ssv"):
                _check(archive.read(item), "SystemStructureParameterValues.xsd", f"{ssp_file}: {item}")


def export_ssp(scenario: Scenario, out_file: Path | str, fmu_paths: dict, *,
               interface: Interface | str = Interface.CO_SIMULATION, step_size: float | None = None,
               stop_time: float | None = None) -> Path:
    """Write the scenario's closed loop as an SSP 1.0 archive, its model named ``model_name(scenario.name)``.

    Only ``out_file`` is written, and only once everything has been checked.

    Parameters
    ----------
    scenario : Scenario
        The closed loop to export.
    out_file : pathlib.Path or str
        The archive to write (``.ssp``).
    fmu_paths : dict
        FMU name (``registry.ORDER``) -> path of each of the three FMUs.
    interface : {"co-simulation", "model-exchange"} or Interface, optional
        What OMSimulator's annotation asks for: its fixed-step master at the communication step (default), or
        CVode over the three FMUs at the scenario's ``tolerance`` (``DEFAULT_TOLERANCE`` if it has none), at
        most one ``output_interval`` per step. libcosim and fmpy co-simulate either archive.
    step_size, stop_time : float or None, optional
        The communication step and the stop time, in s. Default None: the scenario's.

    Returns
    -------
    pathlib.Path
        ``out_file``.

    Raises
    ------
    ScenarioError
        If ``interface`` is not one of ``Interface``'s, a simulation setting is bad or not finite, or an FMU
        lacks a parameter of the scenario.
    FmuNotFoundError
        If one of the three FMUs is not given or not a file.
    FmiVersionError
        If an FMU is not an FMI 2.0 FMU (``FMI2_ONLY`` says why).
    SSPError
        If the SSD or a parameter set does not validate against the SSP 1.0 schemas.
    """
    interface = one_of(Interface, interface, "interface")
    scenario = scenario.with_simulation(step_size=step_size, stop_time=stop_time)
    for name, value in (("step_size", scenario.simulation.step_size), ("stop_time", scenario.simulation.stop_time)):
        if not math.isfinite(value):
            raise ScenarioError(f"{scenario.source}: [simulation] {name} = {value!r} is not allowed; allowed: > 0")
    paths = fmu_files(fmu_paths)
    require_fmi2(paths.values(), FMI2_ONLY)
    variables = {name: _variables(path) for name, path in paths.items()}
    for name in ORDER:
        missing = [p for p in scenario.parameters(name) if p not in variables[name]]
        if missing:
            raise ScenarioError(f"{paths[name]}: {name} has no parameter {missing[0]!r}: not the FMU expected")
    ssd, sets = _build_ssd(scenario, variables, interface)
    _check(ssd, "SystemStructureDescription.xsd", "SystemStructure.ssd")
    for source, xml in sets.items():
        _check(xml, "SystemStructureParameterValues.xsd", source)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("SystemStructure.ssd", ssd)
        for source, xml in sets.items():
            archive.writestr(source, xml)
        for name, path in paths.items():
            archive.write(path, f"resources/{name}.fmu")
    out_file = Path(out_file)
    out_file.write_bytes(buffer.getvalue())
    return out_file


# --------------------------------------------------------------------------------------------- fmpy.ssp


def run_simulate_ssp(ssp_file: Path | str, step_size: float, stop_time: float, *,
                     start_on: str | None = "valid_inputs") -> np.ndarray:
    """Co-simulate an SSP archive with ``fmpy.ssp.simulate_ssp``, passing it the archive's parameters.

    ``simulate_ssp`` ignores the archive's parameter bindings and starts every connection at 0 without an
    initial exchange, so the controller's first step sees v_r = 0, which it refuses (Assumption 2) unless its
    ``start_on`` is valid_inputs (docs/model.md §5.2).

    Parameters
    ----------
    ssp_file : pathlib.Path or str
        The archive (``export_ssp``).
    step_size, stop_time : float
        The communication step and the stop time, in s.
    start_on : {"valid_inputs", "first_use"} or None, optional
        The controller's ``start_on`` (``models.parameters.START_ON``) instead of the archive's; None keeps
        it. Default "valid_inputs".

    Returns
    -------
    numpy.ndarray
        One row per step (dtype ``cosim.signals.DTYPE``), **stamped as simulate_ssp stamps them**: each row
        holds the values after the step that *starts* at its ``time`` (s).

    Raises
    ------
    ValueError
        If ``start_on`` is not one of the allowed names or None.
    SSPError
        On aarch64 Linux, where ``simulate_ssp`` loads the FMI 2.0 FMUs' x86-64 binary from ``linux64``.
    """
    if start_on is not None and start_on not in START_ON:
        raise ValueError(f"start_on = {start_on!r} is not allowed; allowed: {', '.join(START_ON)} or None")
    if host_platform() is LINUX_AARCH64:
        raise SSPError(f"{ssp_file}: fmpy's simulate_ssp loads FMI 2.0 binaries from binaries/linux64, which holds "
                       f"x86-64's, and this is aarch64 Linux (its binaries are in binaries/aarch64-linux); allowed "
                       f"here: dsc_fmu.cosimulate of the same FMUs, or simulate_ssp on x86-64 Linux, Windows or macOS")
    from fmpy.ssp.simulation import simulate_ssp
    from fmpy.ssp.ssd import Parameter, ParameterSet, read_ssd

    ssd = read_ssd(str(ssp_file))
    bound = {f"{component.name}.{p.name}": (p.type, p.value)
             for component in ssd.system.elements for binding in component.parameterBindings
             for parameter_set in binding.parameterValues for p in parameter_set.parameters}
    if start_on is not None:
        bound[f"{CONTROLLER}.start_on"] = ("Integer", START_ON.index(start_on))
    parameters = ParameterSet(name="bindings")
    parameters.parameters = [Parameter(name=name, type=kind, value=value) for name, (kind, value) in bound.items()]
    raw = simulate_ssp(str(ssp_file), stop_time=stop_time, step_size=step_size, parameter_set=parameters)
    result = np.zeros(len(raw), dtype=signals.DTYPE)
    result["time"] = raw["time"]
    for name in ORDER:
        for signal in signals.RECORDED[name]:
            result[signal] = raw[f"{name}.{signal}"]
    signals.add_tracking_errors(result)
    return result
