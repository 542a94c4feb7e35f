"""Build the three FMUs (FMI 2.0 with pythonfmu, FMI 3.0 with pythonfmu3) and complete their model descriptions."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import tempfile
import zipfile
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from xml.etree import ElementTree as ET

import pythonfmu
from pythonfmu import FmuBuilder

from . import __version__
from .binary import binary_folder, binary_sources, build_python, compile_binary
from .fmu_docs import documentation_html
from .models.parameters import (
    CONTROLLER_INPUTS,
    CONTROLLER_OUTPUTS,
    CONTROLLER_PARAMETERS,
    NONNEGATIVE,
    PLANT_INPUTS,
    PLANT_OUTPUTS,
    PLANT_PARAMETERS,
    REFERENCE_OUTPUTS,
    REFERENCE_PARAMETERS,
)

__all__ = [
    "FmuSpec", "FMUS", "DEFAULT_FMU_DIR", "current_fmus", "DEFAULT_FMU_DIRS", "FMI_VERSIONS", "build_fmus", "ensure_fmus",
    "source_hash", "fmu_build_id", "default_fmu_dir",
]

PACKAGE_DIR = Path(__file__).parent
DEFAULT_FMU_DIR = Path("build") / "fmus"
DEFAULT_FMU_DIRS = {2: DEFAULT_FMU_DIR, 3: Path("build") / "fmus3"}
FMI_VERSIONS = (2, 3)
BUILD_ID_FILE = "resources/dsc_fmu_build.json"
# What the binary layer imports and creates: "<bridge module> <slave module> <slave class> <GUID or token>".
ENTRY_FILE = "resources/dsc_fmu_entry.txt"
DOCUMENTATION_FILE = "documentation/index.html"
# The FMI glue bundled beside ``models``, ``slave_core`` and ``slave_models`` for each FMI version.
_GLUE = {2: "fmi_slave.py", 3: "fmi3_slave.py"}

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

_POSE = ("x", "y", "theta", "x_r", "y_r")
_ALL_CONTROLLER_INPUTS = tuple(v.name for v in CONTROLLER_INPUTS)


@dataclass(frozen=True)
class FmuSpec:
    """One FMU: its slave scripts in ``fmu_sources`` (FMI 2.0 and 3.0) and its variable tables."""

    name: str
    script: str
    parameters: tuple
    inputs: tuple
    outputs: tuple
    depends: dict = field(default_factory=dict)

    @property
    def script3(self) -> str:
        """The FMI 3.0 slave script: ``<script stem>_fmi3.py``."""
        return f"{Path(self.script).stem}_fmi3.py"

    def script_for(self, fmi_version: int) -> str:
        return self.script3 if fmi_version == 3 else self.script


FMUS = {
    spec.name: spec
    for spec in (
        FmuSpec("ReferenceRobot", "reference_robot.py", REFERENCE_PARAMETERS, (), REFERENCE_OUTPUTS),
        FmuSpec("MobileRobot", "mobile_robot.py", PLANT_PARAMETERS, PLANT_INPUTS, PLANT_OUTPUTS),
        FmuSpec(
            "DSCController", "dsc_controller.py", CONTROLLER_PARAMETERS, CONTROLLER_INPUTS, CONTROLLER_OUTPUTS,
            depends={
                "u1": _ALL_CONTROLLER_INPUTS,
                "u2": _ALL_CONTROLLER_INPUTS,
                "S11": _POSE,
                "S12": _POSE,
                "S13": (*_POSE, "theta_r", "v_r"),
                "beta": (*_POSE, "v_r"),
                "beta_guard_active": (*_POSE, "v_r"),
                "started": _ALL_CONTROLLER_INPUTS,
            },
        ),
    )
}


def _sources_dir() -> Path:
    """``fmu_sources``: inside the installed package, or beside it in a source checkout."""
    for candidate in (PACKAGE_DIR / "fmu_sources", PACKAGE_DIR.parent / "fmu_sources"):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"fmu_sources not found beside {PACKAGE_DIR}")


def _check_version(fmi_version: int) -> int:
    if fmi_version not in FMI_VERSIONS:
        raise ValueError(f"fmi_version = {fmi_version!r} is not allowed; allowed: 2 or 3")
    return fmi_version


def default_fmu_dir(fmi_version: int = 2) -> Path:
    """Where the FMUs of ``fmi_version`` are built by default: build/fmus (2.0), build/fmus3 (3.0)."""
    return DEFAULT_FMU_DIRS[_check_version(fmi_version)]


def _library_version(fmi_version: int) -> str:
    if fmi_version == 3:
        import pythonfmu3

        return f"pythonfmu3 {pythonfmu3.__version__}"
    return f"pythonfmu {pythonfmu.__version__}"


def _bundled_files(spec: FmuSpec, fmi_version: int = 2) -> list[Path]:
    models = sorted((PACKAGE_DIR / "models").glob("*.py"))
    return [_sources_dir() / spec.script_for(fmi_version), PACKAGE_DIR / _GLUE[fmi_version],
            PACKAGE_DIR / "slave_core.py", PACKAGE_DIR / "slave_models.py", PACKAGE_DIR / "native_bridge.py", *models,
            Path(__file__), PACKAGE_DIR / "fmu_docs.py", PACKAGE_DIR / "binary.py", *binary_sources(fmi_version)]


def source_hash(spec: FmuSpec, fmi_version: int = 2) -> str:
    """Hash of everything the FMU is built from: its sources, this builder, the FMI library's version and
    the Python its binary looks for."""
    _check_version(fmi_version)
    library = _library_version(fmi_version)
    digest = hashlib.sha256(f"{__version__} {library} {spec.name} {build_python()}".encode())
    for path in _bundled_files(spec, fmi_version):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def fmu_build_id(fmu: Path) -> str | None:
    """The source hash an FMU was built from, or None if it is not one of ours."""
    try:
        with zipfile.ZipFile(fmu) as archive:
            return json.loads(archive.read(BUILD_ID_FILE))["source_hash"]
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None


def _stage(spec: FmuSpec, stage: Path, digest: str, fmi_version: int = 2) -> tuple[Path, Path]:
    """Copy the slave script and its package under names unique to this build (pythonfmu issue 228)."""
    package = f"dsc_fmu_{spec.name.lower()}_{digest[:12]}"
    package_dir = stage / package
    (package_dir / "models").mkdir(parents=True)
    (package_dir / "__init__.py").write_text('"""dsc-fmu code bundled into this FMU."""\n')
    shutil.copy2(PACKAGE_DIR / _GLUE[fmi_version], package_dir)
    for module in ("slave_core.py", "slave_models.py", "native_bridge.py"):
        shutil.copy2(PACKAGE_DIR / module, package_dir)
    for module in (PACKAGE_DIR / "models").glob("*.py"):
        shutil.copy2(module, package_dir / "models")
    script_name = spec.script_for(fmi_version)
    script = stage / f"{Path(script_name).stem}_{digest[:12]}.py"
    source = (_sources_dir() / script_name).read_text()
    script.write_text(source.replace("from dsc_fmu.", f"from {package}."))
    return script, package_dir


def _unit_definitions(used) -> ET.Element:
    units = ET.Element("UnitDefinitions")
    for name in sorted(used):
        ET.SubElement(ET.SubElement(units, "Unit", name=name), "BaseUnit", {k: str(e) for k, e in UNITS[name].items()})
    return units


def _tables(spec: FmuSpec) -> dict:
    return {v.name: v for v in (*spec.parameters, *spec.inputs, *spec.outputs)}


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


def _complete_model_description(xml: bytes, spec: FmuSpec) -> ET.Element:
    """Add units, ranges, output dependencies and initial unknowns that pythonfmu does not write (FMI 2.0)."""
    root = ET.fromstring(xml)
    tables = _tables(spec)
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


def _complete_model_description3(xml: bytes, spec: FmuSpec) -> ET.Element:
    """The same for FMI 3.0: units, exact starts, ranges, and ModelStructure with real dependencies
    (by value reference); pythonfmu3 writes units only if registered and no dependencies."""
    root = ET.fromstring(xml)
    tables = _tables(spec)
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


def _documentation(root: ET.Element, spec: FmuSpec) -> bytes:
    units = {"time": "s", "beta_guard_count": "1", **{name: v.unit for name, v in _tables(spec).items()}}
    return documentation_html(root, spec.name, units).encode("utf-8")


def _entry(root: ET.Element, script: Path, package_dir: Path, spec: FmuSpec) -> str:
    """The line of ``ENTRY_FILE``: bridge module, slave module, slave class, GUID (FMI 2.0) or token (FMI 3.0)."""
    token = root.get("guid") or root.get("instantiationToken")
    return f"{package_dir.name}.native_bridge {script.stem} {spec.name} {token}\n"


def _raw_fmu(script: Path, package_dir: Path, dest: Path, fmi_version: int) -> Path:
    """The FMU as the FMI library builds it from the staged script and package."""
    if fmi_version == 3:
        from pythonfmu3 import FmuBuilder as Fmu3Builder

        return Fmu3Builder.build_FMU(
            script, dest=dest, project_files=[package_dir],
            needsExecutionTool="true", canHandleVariableCommunicationStepSize="true",
            canGetAndSetFMUState="true", canSerializeFMUState="true",
        )
    return FmuBuilder.build_FMU(
        script, dest=dest, project_files=[package_dir],
        needsExecutionTool="true", canHandleVariableCommunicationStepSize="true",
        canGetAndSetFMUstate="true", canSerializeFMUstate="true",
    )


def _forget_staged_modules(package: str, script: str) -> None:
    """Drop what the FMI library imported from the stage (removed after the build), so that an FMU of
    this build loaded into this process imports its modules from its own resources."""
    for name in [name for name in sys.modules if name in (package, script) or name.startswith(f"{package}.")]:
        del sys.modules[name]


def build_fmu(spec: FmuSpec, out_dir: Path, fmi_version: int = 2) -> Path:
    """Build one FMU (FMI ``fmi_version``: 2 or 3) into ``out_dir`` atomically and return its path."""
    _check_version(fmi_version)
    out_dir.mkdir(parents=True, exist_ok=True)
    digest = source_hash(spec, fmi_version)
    target = out_dir / f"{spec.name}.fmu"
    complete = _complete_model_description3 if fmi_version == 3 else _complete_model_description
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_build_") as tmp:
        tmp = Path(tmp)
        script, package_dir = _stage(spec, tmp / "stage", digest, fmi_version)
        raw = _raw_fmu(script, package_dir, tmp / f"{spec.name}_raw.fmu", fmi_version)
        _forget_staged_modules(package_dir.name, script.stem)
        staged = tmp / f"{spec.name}.fmu"
        folder = binary_folder(fmi_version)
        own_binary = f"binaries/{folder}/{spec.name}.so" if folder else None
        with zipfile.ZipFile(raw) as src, zipfile.ZipFile(staged, "w", zipfile.ZIP_DEFLATED) as dst:
            for item in src.infolist():
                data = src.read(item)
                if item.filename == "modelDescription.xml":
                    root = complete(data, spec)
                    ET.indent(root)
                    data = ET.tostring(root, encoding="UTF-8", xml_declaration=True)
                    dst.writestr(DOCUMENTATION_FILE, _documentation(root, spec))
                    dst.writestr(ENTRY_FILE, _entry(root, script, package_dir, spec))
                if item.filename == own_binary:
                    data = compile_binary(fmi_version)
                if item.filename != DOCUMENTATION_FILE:
                    dst.writestr(item.filename, data)
            dst.writestr(BUILD_ID_FILE, json.dumps({"source_hash": digest, "dsc_fmu": __version__,
                                                    "fmi_version": fmi_version}))
        fd, partial = tempfile.mkstemp(dir=out_dir, suffix=".fmu.partial")
        os.close(fd)
        shutil.copyfile(staged, partial)
        os.replace(partial, target)
    return target


def build_fmus(out_dir: Path | str | None = None, names=tuple(FMUS), fmi_version: int = 2) -> dict[str, Path]:
    """Build the named FMUs (all three by default) as FMI ``fmi_version`` (2 or 3) FMUs into ``out_dir``
    (default: ``default_fmu_dir(fmi_version)``)."""
    out_dir = Path(out_dir) if out_dir is not None else default_fmu_dir(fmi_version)
    return {name: build_fmu(FMUS[name], out_dir, fmi_version) for name in names}


def ensure_fmus(out_dir: Path | str | None = None, fmi_version: int = 2) -> dict[str, Path]:
    """Paths of the three FMI ``fmi_version`` FMUs in ``out_dir`` (default: ``default_fmu_dir(fmi_version)``),
    building those that are missing or stale."""
    out_dir = Path(out_dir) if out_dir is not None else default_fmu_dir(fmi_version)
    paths = {}
    for name, spec in FMUS.items():
        path = out_dir / f"{name}.fmu"
        if fmu_build_id(path) != source_hash(spec, fmi_version):
            path = build_fmu(spec, out_dir, fmi_version)
        paths[name] = path
    return paths


@contextmanager
def current_fmus(out_dir: Path | str | None = None, fmi_version: int = 2):
    """The three FMUs of ``out_dir`` if they are all current, else ones built into a temporary folder
    that is removed on exit: for exports, which write nothing but their output file."""
    out_dir = Path(out_dir) if out_dir is not None else default_fmu_dir(fmi_version)
    paths = {name: out_dir / f"{name}.fmu" for name in FMUS}
    if all(fmu_build_id(path) == source_hash(FMUS[name], fmi_version) for name, path in paths.items()):
        yield paths
        return
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_fmus_") as tmp:
        yield build_fmus(tmp, fmi_version=fmi_version)
