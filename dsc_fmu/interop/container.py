"""The closed loop as one FMI 2.0 co-simulation FMU: fmpy's container FMU around our three FMUs (FMI 2.0 or 3.0).

The connections are listed measurements first, then the controller's ``u1, u2``, so the container couples as
our master's Jacobi at its internal step (docs/other-tools.md, "How the other masters exchange")."""

from __future__ import annotations

import json
import math
import shutil
import tempfile
import uuid
import zipfile
from pathlib import Path

from fmpy import read_model_description
from fmpy.model_description import CoSimulation, DefaultExperiment, ModelDescription, ModelVariable, Unknown

from ..cosim import signals
from ..cosim.instance import type_name
from ..registry import CONNECTIONS, ORDER, fmu_files
from ..scenario import Scenario, ScenarioError

__all__ = ["export_fmu", "EXPOSED_OUTPUTS"]

EXPOSED_OUTPUTS = tuple(name for fmu in ORDER for name in signals.RECORDED[fmu])


def _literal(value, integer: bool) -> str:
    return str(int(value)) if integer else repr(float(value))


def _macos_binaries(staged: zipfile.ZipFile) -> dict[str, bytes]:
    """The container's macOS binaries laid out as ours are (``dsc_fmu.platforms``): fmpy writes both of its
    dylibs to ``darwin64``, the second over the first, leaving Intel's alone; ``darwin64`` becomes the
    universal file of both and ``aarch64-darwin`` holds Apple Silicon's."""
    import fmpy

    from ..macho import universal

    name = next((item for item in staged.namelist() if item.startswith("binaries/darwin64/") and item.endswith(".dylib")),
                None)
    if name is None:
        return {}
    shipped = Path(fmpy.__file__).parent / "container_fmu" / "binaries"
    arm64, x86_64 = ((shipped / folder / Path(name).name).read_bytes() for folder in ("aarch64-darwin", "x86_64-darwin"))
    return {name: universal([arm64, x86_64]), name.replace("/darwin64/", "/aarch64-darwin/"): arm64}


def _repair(staged: Path, repaired: Path) -> None:
    """Work around three slips of fmpy 0.3.32's ``create_container_fmu`` for FMI 2.0 components:
    connections are written with the FMI 2 type names (``Real``, ``Integer``), which the container
    refuses ("unknown variant `Real`"): they become ``Float64`` and ``Int32`` as the variables are;
    the archive holds a stray empty ``Container.zip``, which is dropped; and ``darwin64`` holds Intel's
    binary only (``_macos_binaries``)."""
    names = {"Real": "Float64", "Integer": "Int32"}
    with zipfile.ZipFile(staged) as src, zipfile.ZipFile(repaired, "w", zipfile.ZIP_DEFLATED) as dst:
        macos = _macos_binaries(src)
        for item in src.infolist():
            if item.filename == "Container.zip" or item.filename in macos:
                continue
            data = src.read(item)
            if item.filename == "resources/container.json":
                config = json.loads(data)
                for connection in config["connections"]:
                    connection["variableType"] = names.get(connection["variableType"], connection["variableType"])
                data = json.dumps(config, indent=4).encode()
            dst.writestr(item, data)
        for name, data in macos.items():
            dst.writestr(name, data)


def _exposed(scenario: Scenario, paths: dict, variables: dict, components: dict):
    """The container's variables: time, every parameter of the three FMUs as ``<FMU>.<parameter>``
    (start: the scenario's value), every recorded output under its own name; and their mappings."""
    model_variables = [ModelVariable(type="Real", variability="continuous", causality="independent", name="time")]
    mappings, outputs = {}, []
    for name in ORDER:
        for key, value in scenario.parameters(name).items():
            inner = variables[name].get(key)
            if inner is None:
                raise ScenarioError(f"{paths[name]}: {name} has no parameter {key!r}: not the FMU expected")
            kind = type_name(inner)
            integer = kind == "Integer"
            outer = ModelVariable(type=kind, variability=inner.variability, causality="parameter",
                                  initial="exact", name=f"{name}.{key}", start=_literal(value, integer),
                                  description=inner.description)
            outer.unit = getattr(inner, "unit", None) if not integer else None
            model_variables.append(outer)
            mappings[outer] = [(components[name], inner)]
    for name in ORDER:
        for key in signals.RECORDED[name]:
            inner = variables[name][key]
            outer = ModelVariable(type=type_name(inner), variability=inner.variability,
                                  causality="output", initial="calculated", name=key,
                                  description=f"{name}.{key}: {inner.description}")
            outer.unit = getattr(inner, "unit", None)
            model_variables.append(outer)
            mappings[outer] = [(components[name], inner)]
            outputs.append(outer)
    return model_variables, mappings, outputs


def _model_description(scenario: Scenario, descriptions: dict, model_variables: list, outputs: list) -> ModelDescription:
    """The container's model description: Jacobi at the scenario's fixed internal step."""
    h, stop = scenario.simulation.step_size, scenario.simulation.stop_time
    guid = "{" + str(uuid.uuid4()) + "}"
    model_description = ModelDescription(
        fmiVersion="2.0", modelName=f"DSCClosedLoop_{scenario.name}", instantiationToken=guid,
        description=f"dsc-fmu closed loop ({', '.join(ORDER)}), scenario {scenario.name}, "
                    f"fmpy container, Jacobi coupling at a fixed internal step of {h!r} s",
        defaultExperiment=DefaultExperiment(startTime="0.0", stopTime=repr(float(stop)), stepSize=repr(float(h))),
        coSimulation=CoSimulation(modelIdentifier="container_fmu", fixedInternalStepSize=h,
                                  needsExecutionTool=False),  # as its components (docs/other-tools.md)
        modelVariables=model_variables,
        unitDefinitions=list({unit.name: unit for md in descriptions.values() for unit in md.unitDefinitions}.values()),
    )
    model_description.outputs = [Unknown(index=model_variables.index(v) + 1, variable=v) for v in outputs]
    model_description.initialUnknowns = [Unknown(index=model_variables.index(v) + 1, variable=v) for v in outputs]
    model_description.guid = guid
    return model_description


def export_fmu(scenario: Scenario, out_file: Path | str, fmu_paths: dict, *, step_size: float | None = None,
               stop_time: float | None = None) -> Path:
    """Write the scenario's closed loop as one FMI 2.0 co-simulation FMU (an fmpy container).

    It couples by Jacobi at a fixed internal step. Every parameter of the three FMUs is a parameter ``<FMU>.<parameter>`` (``MobileRobot.x0``, say) whose start
    value is the scenario's; the outputs are those of ``cosim.signals.RECORDED`` under their own names.

    Parameters
    ----------
    scenario : Scenario
        The closed loop to export.
    out_file : pathlib.Path or str
        The FMU file to write.
    fmu_paths : dict
        FMU name (``registry.ORDER``) -> path of each of the three FMUs (FMI 2.0 or 3.0).
    step_size, stop_time : float or None, optional
        The internal step and the default experiment's stop time, in s. Default None: the scenario's.

    Returns
    -------
    pathlib.Path
        ``out_file``.

    Raises
    ------
    ScenarioError
        If a simulation setting is bad or not finite, or an FMU lacks a parameter of the scenario; raised
        before anything is written.
    FmuNotFoundError
        If one of the three FMUs is not given or not a file.
    """
    from fmpy.container_fmu.cli import create_container_fmu
    from fmpy.container_fmu.config import Component, Configuration, Connection

    scenario = scenario.with_simulation(step_size=step_size, stop_time=stop_time)
    if not (math.isfinite(scenario.simulation.step_size) and math.isfinite(scenario.simulation.stop_time)):
        raise ScenarioError(f"{scenario.source}: [simulation] step_size and stop_time must be finite")
    paths = fmu_files(fmu_paths)
    descriptions = {name: read_model_description(str(path)) for name, path in paths.items()}
    variables = {name: {v.name: v for v in md.modelVariables} for name, md in descriptions.items()}
    components = {name: Component(name=name, filename=paths[name], modelDescription=descriptions[name])
                  for name in ORDER}
    model_variables, mappings, outputs = _exposed(scenario, paths, variables, components)
    connections = [
        Connection(components[c.start], [variables[c.start][c.signal]], components[c.end], [variables[c.end][c.signal]])
        for c in CONNECTIONS
    ]
    configuration = Configuration(
        parallelDoStep=False, modelDescription=_model_description(scenario, descriptions, model_variables, outputs),
        components=[components[name] for name in ORDER], connections=connections, variableMappings=mappings,
    )
    out_file = Path(out_file)
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_container_") as tmp:
        unzipdir = Path(tmp) / "container"
        unzipdir.mkdir()
        staged = Path(tmp) / "DSCClosedLoop.fmu"
        create_container_fmu(configuration, unzipdir, staged)
        _repair(staged, Path(tmp) / "repaired.fmu")
        shutil.copyfile(Path(tmp) / "repaired.fmu", out_file)
    return out_file
