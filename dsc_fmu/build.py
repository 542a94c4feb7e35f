"""Build the three FMUs with pythonfmu and complete their model descriptions (units, ranges, structure)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from xml.etree import ElementTree as ET

import pythonfmu
from pythonfmu import FmuBuilder

from . import __version__
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

__all__ = ["FmuSpec", "FMUS", "DEFAULT_FMU_DIR", "build_fmus", "ensure_fmus", "source_hash", "fmu_build_id"]

PACKAGE_DIR = Path(__file__).parent
DEFAULT_FMU_DIR = Path("build") / "fmus"
BUILD_ID_FILE = "resources/dsc_fmu_build.json"

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
    """One FMU: its slave script in ``fmu_sources`` and its variable tables."""

    name: str
    script: str
    parameters: tuple
    inputs: tuple
    outputs: tuple
    depends: dict = field(default_factory=dict)


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


def _bundled_files(spec: FmuSpec) -> list[Path]:
    models = sorted((PACKAGE_DIR / "models").glob("*.py"))
    return [_sources_dir() / spec.script, PACKAGE_DIR / "fmi_slave.py", *models, Path(__file__)]


def source_hash(spec: FmuSpec) -> str:
    """Hash of everything the FMU is built from: its sources, this builder and pythonfmu's version."""
    digest = hashlib.sha256(f"{__version__} {pythonfmu.__version__} {spec.name}".encode())
    for path in _bundled_files(spec):
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


def _stage(spec: FmuSpec, stage: Path, digest: str) -> tuple[Path, Path]:
    """Copy the slave script and its package under names unique to this build (pythonfmu issue 228)."""
    package = f"dsc_fmu_{spec.name.lower()}_{digest[:12]}"
    package_dir = stage / package
    (package_dir / "models").mkdir(parents=True)
    (package_dir / "__init__.py").write_text('"""dsc-fmu code bundled into this FMU."""\n')
    shutil.copy2(PACKAGE_DIR / "fmi_slave.py", package_dir)
    for module in (PACKAGE_DIR / "models").glob("*.py"):
        shutil.copy2(module, package_dir / "models")
    script = stage / f"{Path(spec.script).stem}_{digest[:12]}.py"
    source = (_sources_dir() / spec.script).read_text()
    script.write_text(source.replace("from dsc_fmu.", f"from {package}."))
    return script, package_dir


def _complete_model_description(xml: bytes, spec: FmuSpec) -> bytes:
    """Add units, ranges, output dependencies and initial unknowns that pythonfmu does not write."""
    root = ET.fromstring(xml)
    tables = {v.name: v for v in (*spec.parameters, *spec.inputs, *spec.outputs)}
    used = sorted({v.unit for v in tables.values() if not v.integer})
    units = ET.Element("UnitDefinitions")
    for name in used:
        ET.SubElement(ET.SubElement(units, "Unit", name=name), "BaseUnit", {k: str(e) for k, e in UNITS[name].items()})
    position = list(root).index(root.find("CoSimulation")) + 1
    root.insert(position, units)

    variables = root.find("ModelVariables")
    index = {}
    for i, scalar in enumerate(variables, start=1):
        name = scalar.get("name")
        index[name] = i
        v = tables.get(name)
        typed = scalar[0]
        if v is None:
            continue
        if typed.tag == "Real":
            typed.set("unit", v.unit)
            if typed.get("start") is not None:
                typed.set("start", repr(float(v.start)))
        if v.bound == NONNEGATIVE:
            typed.set("min", "0")
        if v.maximum is not None:
            typed.set("max", f"{v.maximum:g}")

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
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def build_fmu(spec: FmuSpec, out_dir: Path) -> Path:
    """Build one FMU into ``out_dir`` atomically and return its path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    digest = source_hash(spec)
    target = out_dir / f"{spec.name}.fmu"
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_build_") as tmp:
        tmp = Path(tmp)
        script, package_dir = _stage(spec, tmp / "stage", digest)
        raw = FmuBuilder.build_FMU(
            script, dest=tmp / f"{spec.name}_raw.fmu", project_files=[package_dir],
            needsExecutionTool="true", canHandleVariableCommunicationStepSize="true",
            canGetAndSetFMUstate="true", canSerializeFMUstate="true",
        )
        staged = tmp / f"{spec.name}.fmu"
        with zipfile.ZipFile(raw) as src, zipfile.ZipFile(staged, "w", zipfile.ZIP_DEFLATED) as dst:
            for item in src.infolist():
                data = src.read(item)
                if item.filename == "modelDescription.xml":
                    data = _complete_model_description(data, spec)
                dst.writestr(item.filename, data)
            dst.writestr(BUILD_ID_FILE, json.dumps({"source_hash": digest, "dsc_fmu": __version__}))
        fd, partial = tempfile.mkstemp(dir=out_dir, suffix=".fmu.partial")
        os.close(fd)
        shutil.copyfile(staged, partial)
        os.replace(partial, target)
    return target


def build_fmus(out_dir: Path | str = DEFAULT_FMU_DIR, names=tuple(FMUS)) -> dict[str, Path]:
    """Build the named FMUs (all three by default) into ``out_dir``."""
    return {name: build_fmu(FMUS[name], Path(out_dir)) for name in names}


def ensure_fmus(out_dir: Path | str = DEFAULT_FMU_DIR) -> dict[str, Path]:
    """Paths of the three FMUs in ``out_dir``, building those that are missing or stale."""
    out_dir = Path(out_dir)
    paths = {}
    for name, spec in FMUS.items():
        path = out_dir / f"{name}.fmu"
        if fmu_build_id(path) != source_hash(spec):
            path = build_fmu(spec, out_dir)
        paths[name] = path
    return paths
