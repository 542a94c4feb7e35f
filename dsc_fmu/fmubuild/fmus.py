"""Build the three FMUs (FMI 2.0 with pythonfmu, FMI 3.0 with pythonfmu3): stage, build, complete, put in our binaries."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import sys
import tempfile
import textwrap
import warnings
import zipfile
from contextlib import contextmanager
from pathlib import Path
from xml.etree import ElementTree as ET

import pythonfmu
from pythonfmu import FmuBuilder

from .. import __version__
from ..files import atomic_write
from ..identity import BUILD_ID_FILE, fmu_build_id, fmu_bundled_python
from ..macho import universal
from ..registry import FMUS, FmuSpec
from .binary import ENTRY_FILE as _BINARY_ENTRY_FILE
from .binary import TARGETS, WINDOWS, BinaryBuildError, binary_sources, compile_binary
from .folders import (
    DEFAULT_FMU_DIR, DEFAULT_FMU_DIRS, FMI_VERSIONS, check_fmi_version, default_fmu_dir, resolve_fmu_dir,
)
from .bundle import MANIFEST, ROOT, Runtime, bundle_minor, bundled_runtimes
from .bundle.runtime import bytecode
from .documentation import REQUIREMENTS, bundled_requirements
from .traced_models import fmu_source
from .model_description import complete_model_description, documentation

__all__ = [
    "DEFAULT_FMU_DIR", "DEFAULT_FMU_DIRS", "FMI_VERSIONS", "build_fmus", "ensure_fmus", "current_fmus",
]

PACKAGE_DIR = Path(__file__).parents[1]
ENTRY_FILE = f"resources/{_BINARY_ENTRY_FILE}"
DOCUMENTATION_FILE = "documentation/index.html"
# FMI 3.0's file for the external resources an FMU needs to load (FMI 2.0 FMUs carry it too).
DEPENDENCIES_FILE = "documentation/externalDependencies.txt"
# The licences of what a carried runtime holds, by name and platform (FMI 3.0's place for licences).
LICENCE_FILE = "documentation/licenses/{name}-{platform}.txt"
# What each FMU bundles from the package, beside its slave script: ``models`` and ``fmu`` with the slave's
# module of its FMI version only (``fmi2`` on pythonfmu, ``fmi3`` on pythonfmu3).
_FMU_MODULES = ("__init__.py", "model.py", "robot_models.py", "controller_model.py", "slave.py", "directional.py",
                "native_bridge.py")
_VERSION_MODULE = {2: "fmi2.py", 3: "fmi3.py"}
# The FMI library each FMU carries, under its build's private package.
_LIBRARY = {2: "pythonfmu", 3: "pythonfmu3"}


def _sources_dir() -> Path:
    """``fmu_sources``: inside the installed package, or beside it in a source checkout."""
    for candidate in (PACKAGE_DIR / "fmu_sources", PACKAGE_DIR.parent / "fmu_sources"):
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError(f"fmu_sources not found beside {PACKAGE_DIR}")


def _library_version(fmi_version: int) -> str:
    if fmi_version == 3:
        import pythonfmu3

        return f"pythonfmu3 {pythonfmu3.__version__}"
    return f"pythonfmu {pythonfmu.__version__}"


def _bundle(fmi_version: int) -> list[Path]:
    """The package files bundled into an FMI ``fmi_version`` FMU, relative to the package."""
    fmu = [Path("fmu") / name for name in (*_FMU_MODULES, _VERSION_MODULE[fmi_version])]
    return [*fmu, *sorted(path.relative_to(PACKAGE_DIR) for path in (PACKAGE_DIR / "models").glob("*.py"))]


def _bundled_files(spec: FmuSpec, fmi_version: int = 2) -> list[Path]:
    """Every file the FMU is built from: its script, the bundle, this subpackage, the binary's sources."""
    builder = sorted(Path(__file__).parent.glob("*.py"))
    return [_sources_dir() / spec.script_for(fmi_version), *(PACKAGE_DIR / path for path in _bundle(fmi_version)),
            *builder, *binary_sources(fmi_version)]


def source_hash(spec: FmuSpec, fmi_version: int = 2) -> str:
    """The SHA-256 (hex) of an FMU's sources, this builder, the binary's sources and the FMI library's version.
    An FMU whose build id (``identity.fmu_build_id``) equals it is current, whichever machine and CPython built it.
    """
    check_fmi_version(fmi_version)
    library = _library_version(fmi_version)
    digest = hashlib.sha256(f"{__version__} {library} {spec.name}".encode())
    for path in _bundled_files(spec, fmi_version):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _stage(spec: FmuSpec, stage: Path, digest: str, fmi_version: int = 2) -> tuple[Path, Path]:
    """Copy the slave script and the bundle under names unique to this build (pythonfmu issue 228)."""
    package = f"dsc_fmu_{spec.name.lower()}_{digest[:12]}"
    package_dir = stage / package
    for path in _bundle(fmi_version):
        (package_dir / path).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(PACKAGE_DIR / path, package_dir / path)
    (package_dir / "__init__.py").write_text('"""dsc-fmu code bundled into this FMU."""\n')
    script_name = spec.script_for(fmi_version)
    script = stage / f"{Path(script_name).stem}_{digest[:12]}.py"
    source = (_sources_dir() / script_name).read_text()
    script.write_text(source.replace("from dsc_fmu.", f"from {package}."))
    return script, package_dir


def _entry(root: ET.Element, script: Path, package_dir: Path, spec: FmuSpec) -> str:
    """The line of ``ENTRY_FILE``: bridge module, slave module, slave class, GUID or token."""
    token = root.get("guid") or root.get("instantiationToken")
    return f"{package_dir.name}.fmu.native_bridge {script.stem} {spec.name} {token}\n"


def _private(name: str, data: bytes, package: str, library: str) -> tuple[str, bytes]:
    """A file of the FMU as the binary loads it: the FMI library under the build's private package, and
    every bundled module importing it by that name, so that no other FMU build and no host shares it."""
    public = f"resources/{library}/"
    if name.startswith(public):
        name = f"resources/{package}/{library}/{name[len(public):]}"
    if name.startswith("resources/") and name.endswith(".py"):
        text = re.sub(rf"^(\s*from\s+){library}\b", rf"\g<1>{package}.{library}", data.decode("utf-8"), flags=re.M)
        public = re.search(rf"\bimport\s+(?:[\w.]+\s*,\s*)*{library}\b"
                           rf"|(?:import_module|__import__)\(\s*['\"]{library}\b", text)
        if public:
            raise BinaryBuildError(f"{name} imports {library} by its public name ({public.group().strip()}); "
                                   f"allowed: 'from {library}... import ...', which the build makes private")
        data = text.encode("utf-8")
    return name, data


def _bytecode(name: str, data: bytes) -> tuple[str, bytes]:
    """The bundled module's bytecode for the building Python, checked against its source by hash (PEP 552)."""
    folder, _, file = name.rpartition("/")
    return f"{folder}/__pycache__/{file[:-3]}.{sys.implementation.cache_tag}.pyc", bytecode(data, name, check_source=True)


@contextmanager
def _slave_class_named(class_name: str):
    """Give pythonfmu3's builder the slave class: it looks for a class statement naming ``Fmi3Slave``, and ours
    derive from it through ``Fmi3ModelSlave``."""
    from pythonfmu3 import builder

    find = builder.get_class_name
    builder.get_class_name = lambda script: class_name
    try:
        yield
    finally:
        builder.get_class_name = find


def _raw_fmu(script: Path, package_dir: Path, dest: Path, spec: FmuSpec, fmi_version: int) -> Path:
    """The FMU as the FMI library builds it from the staged script and package (no execution tool needed)."""
    if fmi_version == 3:
        from pythonfmu3 import FmuBuilder as Fmu3Builder

        with _slave_class_named(spec.name):
            return Fmu3Builder.build_FMU(
                script, dest=dest, project_files=[package_dir],
                needsExecutionTool="false", canHandleVariableCommunicationStepSize="true",
                canGetAndSetFMUState="true", canSerializeFMUState="true",
            )
    return FmuBuilder.build_FMU(
        script, dest=dest, project_files=[package_dir],
        needsExecutionTool="false", canHandleVariableCommunicationStepSize="true",
        canGetAndSetFMUstate="true", canSerializeFMUstate="true",
    )


def _forget_staged_modules(package: str, script: str) -> None:
    """Drop the build's modules from ``sys.modules``: before the build, those a loaded FMU of the same build
    imported from its resources; after it, those imported from the stage, which is removed."""
    for name in [name for name in sys.modules if name in (package, script) or name.startswith(f"{package}.")]:
        del sys.modules[name]


def _binaries(spec: FmuSpec, fmi_version: int, traced: str) -> dict[str, bytes]:
    """The binaries by path, with the model's ``traced`` C; targets that share a folder (macOS's ``darwin64``) joined
    in a universal file."""
    slices = {}
    for target in TARGETS:
        binary = compile_binary(fmi_version, target, model_identifier=spec.name, traced=traced)
        for name in target.files(fmi_version, spec.name):
            slices.setdefault(name, []).append(binary)
    return {name: images[0] if len(images) == 1 else universal(images) for name, images in slices.items()}


def _runtime_files(runtime: Runtime, platform: str, fmi_version: int) -> dict:
    """The files of ``runtime`` in an FMU, beside the binary of ``platform``."""
    root = f"binaries/{_target(platform).folder(fmi_version)}/{ROOT}"
    return {**{f"{root}/{path}": data for path, data in runtime.files.items()}, f"{root}/{MANIFEST}": runtime.manifest(),
            **{LICENCE_FILE.format(name=name, platform=platform): text for name, text in runtime.licences.items()}}


def _target(platform: str):
    return next(target for target in TARGETS if target.name == platform)


def _uncarried(runtimes: dict) -> list[str]:
    return [target.name for target in TARGETS if target.name not in runtimes]


def _requirements(runtimes: dict, fmi_version: int) -> str:
    if not runtimes:
        return REQUIREMENTS
    folders = {platform: f"binaries/{_target(platform).folder(fmi_version)}/{ROOT}" for platform in runtimes}
    licences = {platform: [LICENCE_FILE.format(name=name, platform=platform) for name in runtime.licences]
                for platform, runtime in runtimes.items()}
    return bundled_requirements(runtimes, folders, licences, _uncarried(runtimes))


def build_fmu(spec: FmuSpec, out_dir: Path | str, fmi_version: int | None = None,
              bundle_python: bool | str = False, traced: bool = True) -> Path:
    """Build one FMU, ``out_dir/<name>.fmu``, atomically; the arguments and errors are those of ``build_fmus``."""
    out_dir, fmi_version = resolve_fmu_dir(out_dir, fmi_version)
    if bundle_python:
        bundle_minor(bundle_python)  # a bad version is refused before anything is built
    digest = source_hash(spec, fmi_version)
    target = out_dir / f"{spec.name}.fmu"
    model, untraceable = fmu_source(spec.name, traced)
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_build_") as tmp:
        tmp = Path(tmp)
        script, package_dir = _stage(spec, tmp / "stage", digest, fmi_version)
        _forget_staged_modules(package_dir.name, script.stem)
        raw = _raw_fmu(script, package_dir, tmp / f"{spec.name}_raw.fmu", spec, fmi_version)
        _forget_staged_modules(package_dir.name, script.stem)
        runtimes = {}
        if bundle_python:
            entry = f"{package_dir.name}.fmu.native_bridge {script.stem}"
            runtimes = bundled_runtimes(raw, entry, bundle_python, [target.name for target in TARGETS])
        staged = tmp / f"{spec.name}.fmu"
        with zipfile.ZipFile(raw) as src, zipfile.ZipFile(staged, "w", zipfile.ZIP_DEFLATED) as dst:
            for name, data in _binaries(spec, fmi_version, model).items():
                dst.writestr(name, data)
            for platform, runtime in runtimes.items():
                for name, data in _runtime_files(runtime, platform, fmi_version).items():
                    dst.writestr(name, data)
            requirements = _requirements(runtimes, fmi_version)
            for item in src.infolist():
                if item.filename.startswith("binaries/"):
                    continue
                data = src.read(item)
                if item.filename == "modelDescription.xml":
                    root = complete_model_description(data, spec, fmi_version)
                    ET.indent(root)
                    data = ET.tostring(root, encoding="UTF-8", xml_declaration=True)
                    dst.writestr(DOCUMENTATION_FILE, documentation(root, spec, requirements))
                    dst.writestr(DEPENDENCIES_FILE, textwrap.fill(requirements, 100) + "\n")
                    dst.writestr(ENTRY_FILE, _entry(root, script, package_dir, spec))
                if item.filename != DOCUMENTATION_FILE:
                    name, data = _private(item.filename, data, package_dir.name, _LIBRARY[fmi_version])
                    dst.writestr(name, data)
                    if name.startswith("resources/") and name.endswith(".py"):
                        dst.writestr(*_bytecode(name, data))
            record = {"source_hash": digest, "dsc_fmu": __version__, "fmi_version": fmi_version,
                      "traced": {"untraceable": untraceable} if traced else None}
            if runtimes:
                record["python"] = {platform: runtime.version for platform, runtime in runtimes.items()}
            dst.writestr(BUILD_ID_FILE, json.dumps(record))
        out_dir.mkdir(parents=True, exist_ok=True)
        path = atomic_write(target, staged.read_bytes())
    if runtimes:
        warnings.warn(f"--bundle-python: the FMUs carry a CPython for {', '.join(runtimes)} and none for "
                      f"{', '.join(_uncarried(runtimes))}, where they use the importing machine's CPython 3.9 or newer",
                      stacklevel=2)
    return path


def build_fmus(out_dir: Path | str | None = None, names=tuple(FMUS), fmi_version: int | None = None,
               bundle_python: bool | str = False, traced: bool = True) -> dict[str, Path]:
    """Build some or all of the three FMUs, each atomically.

    Parameters
    ----------
    out_dir : pathlib.Path or str or None, optional
        The directory, created if missing. Default None: ``default_fmu_dir`` of the version.
    names : iterable of str, optional
        The FMUs to build, keys of ``registry.FMUS``. Default: all three.
    fmi_version : {2, 3} or None, optional
        The FMI version. Default None: that of the FMUs in the directory, else 2 (``resolve_fmu_dir``).
    bundle_python : bool or str, optional
        Carry a CPython for the platforms it can (``fmubuild.bundle``: x86-64 Windows, and Linux of the
        building machine's CPU; a warning names the others): True for the building CPython's minor
        version, or ``"3.X"`` for Windows' (Linux's is the building CPython). Default False: the FMUs use
        the importing machine's.
    traced : bool, optional
        Compile the C traced from each model into its binaries (docs/traced-c.md; the build record names what could
        not be traced, which runs in Python). Default True; False: the models run in Python only.

    Returns
    -------
    dict of str to pathlib.Path
        The path of each FMU built, by name.

    Raises
    ------
    KeyError
        If a name is not one of the three FMUs.
    ValueError
        If ``fmi_version`` is not 2 or 3.
    FmiVersionError
        If the directory holds FMUs of another FMI version; nothing is written.
    BinaryBuildError
        If the binary does not compile or a bundled module imports the FMI library by its public name.
    BundleError
        If a CPython cannot be bundled (``bundle_minor``, ``bundled_runtimes``); nothing is written.
    """
    out_dir, fmi_version = resolve_fmu_dir(out_dir, fmi_version)
    return {name: build_fmu(FMUS[name], out_dir, fmi_version, bundle_python, traced) for name in names}


def ensure_fmus(out_dir: Path | str | None = None, fmi_version: int | None = None) -> dict[str, Path]:
    """The three FMUs of a directory, building those that are missing or stale.

    Parameters
    ----------
    out_dir : pathlib.Path or str or None, optional
        The directory. Default None: ``default_fmu_dir`` of the version.
    fmi_version : {2, 3} or None, optional
        The FMI version. Default None: that of the FMUs in the directory, else 2 (``resolve_fmu_dir``).

    Returns
    -------
    dict of str to pathlib.Path
        The path of each of the three FMUs, by name.

    Raises
    ------
    ValueError, FmiVersionError, BinaryBuildError
        As ``build_fmus``.
    """
    out_dir, fmi_version = resolve_fmu_dir(out_dir, fmi_version)
    paths = {}
    for name, spec in FMUS.items():
        path = out_dir / f"{name}.fmu"
        if fmu_build_id(path) != source_hash(spec, fmi_version):
            path = build_fmu(spec, out_dir, fmi_version)
        paths[name] = path
    return paths


@contextmanager
def current_fmus(out_dir: Path | str | None = None, fmi_version: int | None = None, bundle_python: bool | str = False):
    """The three current FMUs, for exports, which write nothing but their output file (a context manager).

    Those of ``out_dir`` if they are all current, else ones built into a temporary folder removed on exit.

    Parameters
    ----------
    out_dir : pathlib.Path or str or None, optional
        The directory to look in; nothing is written there. Default None: ``default_fmu_dir`` of the version.
    fmi_version : {2, 3} or None, optional
        The FMI version. Default None: that of the FMUs in the directory, else 2 (``resolve_fmu_dir``).
    bundle_python : bool or str, optional
        FMUs that carry a CPython (``build_fmus``): those of ``out_dir`` serve if they carry one of that
        version for Windows. Default False: any current FMUs serve.

    Yields
    ------
    dict of str to pathlib.Path
        The path of each of the three FMUs, by name.

    Raises
    ------
    ValueError, FmiVersionError, BinaryBuildError, BundleError
        As ``build_fmus``.
    """
    out_dir, fmi_version = resolve_fmu_dir(out_dir, fmi_version)
    paths = {name: out_dir / f"{name}.fmu" for name in FMUS}
    if all(fmu_build_id(path) == source_hash(FMUS[name], fmi_version) and _carries(path, bundle_python)
           for name, path in paths.items()):
        yield paths
        return
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_fmus_") as tmp:
        yield build_fmus(tmp, fmi_version=fmi_version, bundle_python=bundle_python)


def _carries(fmu: Path, bundle_python: bool | str) -> bool:
    """Whether ``fmu`` carries the CPython ``bundle_python`` asks for: Linux's is always the building one's."""
    if not bundle_python:
        return True
    windows = (fmu_bundled_python(fmu) or {}).get(WINDOWS.name, "")
    return windows.startswith(f"3.{bundle_minor(bundle_python)}.")
