"""The FMUs' Windows binaries under Wine: what they import and export; each FMU (FMI 2.0 and 3.0, co-simulation
and model exchange) and the paper's loop in the project's C importers cross-compiled for Windows, equal to Linux to the last bit; any
embeddable CPython from 3.9 on, found on PATH, under PEP 514 or through the override; the message when
none serves; every form of resource URI; hosts with other streams; unloading and loading again."""

import re
import shutil
import sys
import zipfile
from pathlib import Path

import numpy as np
import pefile
import pytest
from fmpy import extract, read_model_description

from c_hosts import compile_c, parse_rows, run_c, write_plan
from dsc_fmu.fmubuild.binary import OVERRIDE_VARIABLE, TARGETS, WINDOWS
from wine import embeddable_python, windows_path

NAMES = ("ReferenceRobot", "MobileRobot", "DSCController")
STEPS, STEP = 50, 0.02
BUILD_MINOR = sys.version_info.minor
OTHER_MINORS = (9, 12)  # the oldest CPython the FMUs take, and a newer one
UCRT = re.compile(r"api-ms-win-crt-[a-z]+-l1-1-0\.dll")
# What a user's environment may hold and the binary must ignore.
MISLEADING = {"PYTHONHOME": r"Z:\nonexistent", "PYTHONPATH": r"Z:\nonexistent", "PYTHONSTARTUP": r"Z:\nonexistent.py"}

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def pythons(tmp_path_factory):
    """Embeddable CPythons by minor version, downloaded when first asked for."""
    root = tmp_path_factory.mktemp("python-embed")
    found = {}

    def python(minor: int) -> Path:
        if minor not in found:
            found[minor] = embeddable_python(minor, root / f"3.{minor}")
        return found[minor]

    return python


@pytest.fixture(scope="module")
def importers(tmp_path_factory):
    """The C co-simulation importer, for Linux and for Windows."""
    folder = tmp_path_factory.mktemp("importers")
    return {"linux": compile_c("c_importer.c", folder / "c_importer"),
            "windows": compile_c("c_importer.c", folder / "c_importer.exe", windows=True)}


def fmi_functions(version: int) -> set[str]:
    """The functions of FMI ``version`` as the standard's header declares them (FMPy's copy)."""
    import fmpy

    header = (Path(fmpy.__file__).parent / "c-code" / f"fmi{version}Functions.h").read_text()
    return set(re.findall(rf"FMI{version}_Export\s+fmi{version}\w+TYPE\s+(fmi{version}\w+)\s*;", header))


def outputs(md):
    return [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type in ("Real", "Float64")]


def token_of(md, version):
    return md.guid if version == 2 else md.instantiationToken


def runs(importers, wine, version, folder, md, env=None, steps=STEPS, **streams):
    """The same importer run on Linux and under Wine: (Linux rows, the Windows run)."""
    arguments = [version, folder, md.coSimulation.modelIdentifier, token_of(md, version), steps, STEP, *outputs(md)]
    linux = run_c([importers["linux"], *arguments], folder.parent)
    assert linux.returncode == 0, linux.stderr
    arguments[1] = windows_path(folder)
    return parse_rows(linux.stdout), wine.run([importers["windows"], *arguments], env, **streams)


def assert_like_linux(windows: list, linux: list) -> None:
    """The same rows to the rounding of the math library: CPython's sin, cos and atan come from the C
    library, and Wine's rounds about 3 % of sin and cos results and 6 % of atan results differently
    from glibc in the last bit (README, "Windows"); everything else is the same arithmetic."""
    assert np.shape(windows) == np.shape(linux)
    np.testing.assert_allclose(windows, linux, rtol=1e-12, atol=1e-12)


def errors(run) -> list[str]:
    """The messages the FMU logged."""
    return [line for line in run.stderr.splitlines() if line.startswith("[")]


@pytest.mark.parametrize("version", (2, 3))
def test_every_fmu_carries_our_binaries_for_every_platform_and_no_other(fmu_paths, fmu3_paths, version, tmp_path):
    """Each FMU holds exactly our binaries, one file per platform folder; the Windows one imports KERNEL32
    and the UCRT only and exports exactly the standard's functions."""
    for name, path in (fmu3_paths if version == 3 else fmu_paths).items():
        with zipfile.ZipFile(path) as fmu:
            binaries = {item for item in fmu.namelist() if item.startswith("binaries/") and not item.endswith("/")}
            assert binaries == {file for target in TARGETS for file in target.files(version, name)}
            dll = pefile.PE(data=fmu.read(WINDOWS.file(version, name)))
        imports = {entry.dll.decode() for entry in dll.DIRECTORY_ENTRY_IMPORT}
        assert "KERNEL32.dll" in imports and all(d == "KERNEL32.dll" or UCRT.fullmatch(d) for d in imports), imports
        assert {symbol.name.decode() for symbol in dll.DIRECTORY_ENTRY_EXPORT.symbols} == fmi_functions(version)
        assert dll.FILE_HEADER.Machine == pefile.MACHINE_TYPE["IMAGE_FILE_MACHINE_AMD64"]


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", NAMES)
def test_each_fmu_in_a_windows_c_importer_equals_linux(importers, wine, pythons, fmu_paths, fmu3_paths, tmp_path,
                                                       name, version):
    """The embeddable CPython of the building minor at the end of a Windows PATH of over 7,000 characters,
    the environment's PYTHON* variables pointing elsewhere (ignored): the same rows as on Linux."""
    path = (fmu3_paths if version == 3 else fmu_paths)[name]
    md = read_model_description(str(path))
    folder = Path(extract(str(path), unzipdir=tmp_path / name))
    crowded = ";".join([r"Z:\nonexistent\tool\bin"] * 300 + [windows_path(pythons(BUILD_MINOR))])
    linux, windows = runs(importers, wine, version, folder, md, {"WINEPATH": crowded, **MISLEADING})
    assert windows.returncode == 0, windows.stderr
    assert_like_linux(parse_rows(windows.stdout), linux)


@pytest.mark.parametrize("name", NAMES)
def test_the_traced_c_under_wine_gives_the_bits_of_the_python_path(importers, wine, pythons, fmu_paths,
                                                                  untraced_fmu_paths, tmp_path, name):
    """On Windows the traced C takes sin, cos, atan and fmod from the UCRT, as CPython does (docs/traced-c.md): the
    Windows importer gives the same bits with the FMU as built and built with ``--no-traced`` (Wine's UCRT)."""
    rows = []
    for label, paths in (("traced", fmu_paths), ("python", untraced_fmu_paths)):
        md = read_model_description(str(paths[name]))
        folder = Path(extract(str(paths[name]), unzipdir=tmp_path / label))
        arguments = [2, windows_path(folder), name, token_of(md, 2), STEPS, STEP, *outputs(md)]
        run = wine.run([importers["windows"], *arguments], {"WINEPATH": windows_path(pythons(BUILD_MINOR))})
        assert run.returncode == 0, run.stderr
        rows.append(run.stdout)
    assert rows[0] == rows[1] and len(rows[0].splitlines()) == STEPS + 1


def test_model_exchange_in_a_windows_c_importer_equals_linux(wine, pythons, fmu3_paths, tmp_path):
    """The project's model-exchange importer (RK4 in C on the FMU's derivatives), on Windows as on Linux
    (FMI 3.0; the FMI 2.0 adapter is the same C on both systems, tested on Linux)."""
    version, path = 3, fmu3_paths["DSCController"]
    md = read_model_description(str(path))
    folder = Path(extract(str(path), unzipdir=tmp_path / "c"))
    arguments = [version, folder, md.modelExchange.modelIdentifier, token_of(md, version), len(md.derivatives),
                 md.numberOfEventIndicators, STEPS, STEP, *outputs(md)]
    linux = run_c([compile_c("c_model_exchange.c", tmp_path / "me"), *arguments], tmp_path)
    assert linux.returncode == 0, linux.stderr
    arguments[1] = windows_path(folder)
    windows = wine.run([compile_c("c_model_exchange.c", tmp_path / "me.exe", windows=True), *arguments],
                       {"WINEPATH": windows_path(pythons(BUILD_MINOR))})
    assert windows.returncode == 0, windows.stderr
    *linux_rows, linux_events = linux.stdout.splitlines()
    *windows_rows, windows_events = windows.stdout.splitlines()
    assert windows_events == linux_events
    assert_like_linux(parse_rows("\n".join(windows_rows)), parse_rows("\n".join(linux_rows)))


@pytest.mark.parametrize(("threads", "stop_time"), ((False, 30.0), (True, 3.0)), ids=("one thread", "worker threads"))
def test_the_paper_loop_in_a_windows_c_master_equals_linux(wine, pythons, fmu_paths, tmp_path, threads, stop_time):
    """The paper's 30 s at 1 ms through the three FMI 2.0 FMUs from a C master without Python, on
    Windows as on Linux; with worker threads (the first 3 s), every doStep on a thread Python does not
    know, whose thread state the binary deletes when the thread ends."""
    h, every = 1e-3, 1000
    steps = round(stop_time / h)
    unzipped = {name: Path(extract(str(path), unzipdir=tmp_path / name)) for name, path in fmu_paths.items()}
    record = {"MobileRobot": ["x", "y", "theta"], "DSCController": ["u1", "u2", "a1_hat", "W1_hat_norm"]}
    rows = {}
    for system in ("linux", "windows"):
        master = compile_c("c_master.c", tmp_path / f"c_master_{system}", windows=system == "windows")
        locate = windows_path if system == "windows" else str
        plan = write_plan(tmp_path / f"plan_{system}.txt", unzipped, steps, h, "gauss-seidel", threads, every, record,
                          locate)
        if system == "windows":
            run = wine.run([master, windows_path(plan)], {"WINEPATH": windows_path(pythons(BUILD_MINOR))})
        else:
            run = run_c([master, plan], tmp_path)
        assert run.returncode == 0, run.stderr[-2000:]
        rows[system] = parse_rows(run.stdout)
    assert len(rows["linux"]) == steps // every + 1
    assert_like_linux(rows["windows"], rows["linux"])


IN_PROCESS = r"""
import importlib.util, sys
spec = importlib.util.spec_from_file_location("fmi_ctypes", sys.argv[1])
driver = importlib.util.module_from_spec(spec)
spec.loader.exec_module(driver)
version, folder, steps, step = int(sys.argv[2]), sys.argv[3], int(sys.argv[4]), float(sys.argv[5])
fmu = (driver.Fmi3Slave if version == 3 else driver.Fmi2Slave)(folder)
fmu.instantiate()
if version == 2:
    fmu.setup_experiment(0.0)
    fmu.enter_initialization_mode()
else:
    fmu.enter_initialization_mode(0.0)
fmu.exit_initialization_mode()
names = [n for n, (_, kind, causality) in fmu.variables.items() if causality == "output" and kind in ("Real", "Float64")]
get = fmu.get_float64 if version == 3 else fmu.get_real
for k in range(steps + 1):
    print(",".join(repr(v) for v in [k * step, *get(names)]))
    if k < steps:
        fmu.do_step(k * step, step)
fmu.terminate()
fmu.free_instance()
"""


def test_a_windows_python_host_lends_its_python(importers, wine, pythons, fmu3_paths, tmp_path):
    """The embeddable python.exe drives the FMU through ctypes (the project's stdlib-only driver): the
    binary finds the CPython already in the process and uses it, nothing else on PATH."""
    version, path = 3, fmu3_paths["MobileRobot"]
    md = read_model_description(str(path))
    folder = Path(extract(str(path), unzipdir=tmp_path / "m"))
    linux, _ = runs(importers, wine, version, folder, md)
    python = pythons(BUILD_MINOR) / "python.exe"
    driver = Path(__file__).parent / "fmi_ctypes.py"
    run = wine.run([python, "-c", IN_PROCESS, windows_path(driver), version, windows_path(folder), STEPS, STEP])
    assert run.returncode == 0, run.stderr
    assert_like_linux(parse_rows(run.stdout), linux)


@pytest.mark.parametrize(("version", "minor"), ((3, OTHER_MINORS[0]), (2, OTHER_MINORS[1])),
                         ids=lambda value: f"3.{value}" if value > 3 else f"FMI {value}")
def test_any_embeddable_cpython_from_3_9_on_serves(importers, wine, pythons, fmu_paths, fmu3_paths, tmp_path, minor,
                                                   version):
    """Another minor than the one that built the FMU, named by the override: the same rows."""
    path = (fmu3_paths if version == 3 else fmu_paths)["ReferenceRobot"]
    md = read_model_description(str(path))
    folder = Path(extract(str(path), unzipdir=tmp_path / "r"))
    library = windows_path(pythons(minor) / f"python3{minor}.dll")
    linux, windows = runs(importers, wine, version, folder, md, {OVERRIDE_VARIABLE: library})
    assert windows.returncode == 0, windows.stderr
    assert_like_linux(parse_rows(windows.stdout), linux)


def test_pep_514_registrations_are_found_and_the_building_minor_comes_first(importers, wine, pythons, fmu_paths,
                                                                              tmp_path):
    """A CPython registered in HKCU serves with nothing on PATH. With a CPython of the building minor on
    PATH that fails to start, that one is tried first (and, started once, the only one), although the
    registered one is found first."""
    md = read_model_description(str(fmu_paths["ReferenceRobot"]))
    folder = Path(extract(str(fmu_paths["ReferenceRobot"]), unzipdir=tmp_path / "r"))
    other = OTHER_MINORS[-1]
    broken = tmp_path / "broken"
    shutil.copytree(pythons(BUILD_MINOR), broken)
    (broken / f"python3{BUILD_MINOR}.zip").write_bytes(b"PK\x05\x06" + bytes(18))  # an empty zip: no encodings
    wine.register_python(other, pythons(other))
    try:
        linux, registered = runs(importers, wine, 2, folder, md)
        _, preferred = runs(importers, wine, 2, folder, md, {"WINEPATH": windows_path(broken)})
    finally:
        wine.register_python(other, None)
    assert registered.returncode == 0, registered.stderr
    assert_like_linux(parse_rows(registered.stdout), linux)
    assert preferred.returncode == 2
    (message,) = errors(preferred)
    assert f"on PATH: {windows_path(broken / f'python3{BUILD_MINOR}.dll')}" in message
    assert "Python did not start" in message and "PEP 514" not in message


def test_no_python_is_one_message_and_no_instance(importers, wine, fmu_paths, tmp_path):
    md = read_model_description(str(fmu_paths["ReferenceRobot"]))
    folder = Path(extract(str(fmu_paths["ReferenceRobot"]), unzipdir=tmp_path / "r"))
    _, run = runs(importers, wine, 2, folder, md)
    assert run.returncode == 2, run.stderr
    (message,) = errors(run)
    for said in (f"{OVERRIDE_VARIABLE} not set", "the Python that built the FMU is not on this system",
                 "no CPython 3.9 or newer is installed where this system registers one", "python3X.dll"):
        assert said in message


def test_a_python_too_old_or_broken_is_one_message_and_no_instance(importers, wine, pythons, fmu3_paths, tmp_path):
    """CPython 3.8, named by the override, in the override's folder or the only one on PATH, is refused
    before it starts and named with its file and version; one whose standard library is missing is
    refused before it starts; one whose standard library is empty fails to start: each a NULL and one
    message, and the host goes on."""
    version = 3
    md = read_model_description(str(fmu3_paths["ReferenceRobot"]))
    folder = Path(extract(str(fmu3_paths["ReferenceRobot"]), unzipdir=tmp_path / "r"))
    no_stdlib, empty_stdlib = tmp_path / "no stdlib", tmp_path / "empty stdlib"
    for copy in (no_stdlib, empty_stdlib):
        shutil.copytree(pythons(BUILD_MINOR), copy)
    (no_stdlib / f"python3{BUILD_MINOR}.zip").unlink()
    (empty_stdlib / f"python3{BUILD_MINOR}.zip").write_bytes(b"PK\x05\x06" + bytes(18))
    too_old = windows_path(pythons(8) / "python38.dll")
    expected = [({OVERRIDE_VARIABLE: too_old}, too_old, "Python 3.8."),
                ({OVERRIDE_VARIABLE: windows_path(pythons(8))}, f"{OVERRIDE_VARIABLE} folder: {too_old}",
                 "Python 3.8."),
                ({"WINEPATH": windows_path(pythons(8))}, f"on PATH: {too_old}", "Python 3.8."),
                ({"WINEPATH": windows_path(no_stdlib)}, windows_path(no_stdlib), "no standard library in"),
                ({"WINEPATH": windows_path(empty_stdlib)}, windows_path(empty_stdlib), "Python did not start")]
    for env, named, said in expected:
        _, run = runs(importers, wine, version, folder, md, env)
        assert run.returncode == 2, run.stderr
        (message,) = errors(run)
        assert said in message and named in message, message
        assert "older than 3.9" in message or said != "Python 3.8."


def test_the_override_may_name_a_cpythons_folder(importers, wine, pythons, fmu_paths, tmp_path):
    """DSC_FMU_PYTHON as users write it, the folder of python3X.dll (here an embeddable package's): the
    same rows as on Linux. A folder without one is a NULL and one message naming it and what was looked for."""
    md = read_model_description(str(fmu_paths["ReferenceRobot"]))
    folder = Path(extract(str(fmu_paths["ReferenceRobot"]), unzipdir=tmp_path / "r"))
    linux, windows = runs(importers, wine, 2, folder, md, {OVERRIDE_VARIABLE: windows_path(pythons(BUILD_MINOR))})
    assert windows.returncode == 0, windows.stderr
    assert_like_linux(parse_rows(windows.stdout), linux)
    empty = tmp_path / "no python here"
    empty.mkdir()
    _, run = runs(importers, wine, 2, folder, md, {OVERRIDE_VARIABLE: windows_path(empty)})
    assert run.returncode == 2, run.stderr
    (message,) = errors(run)
    said = f"{OVERRIDE_VARIABLE} = {windows_path(empty)}: a folder without a CPython library (looked for python3X.dll"
    assert said in message, message


URIS = ("file:///", "file:/", "file://localhost/")


@pytest.mark.parametrize("form", URIS)
def test_every_form_of_resource_location(importers, wine, pythons, fmu3_paths, tmp_path, form):
    """The resources of an FMU unzipped into a folder whose name needs escaping in a URI, given as a
    file URI of each form, percent-escaped (FMI 3.0 takes a URI or the native path, which every FMI
    3.0 run here gives; FMI 2.0's URI goes through the same parser)."""
    version = 3
    path = fmu3_paths["ReferenceRobot"]
    md = read_model_description(str(path))
    folder = Path(extract(str(path), unzipdir=tmp_path / "a folder #1"))
    uri = form + windows_path(folder / "resources").replace("\\", "/").replace(" ", "%20").replace("#", "%23")
    env = {"WINEPATH": windows_path(pythons(BUILD_MINOR)), "DSC_TEST_RESOURCES": uri}
    linux, windows = runs(importers, wine, version, folder, md, env)
    assert windows.returncode == 0, windows.stderr
    assert_like_linux(parse_rows(windows.stdout), linux)


def test_unloaded_and_loaded_again_and_side_by_side(importers, wine, pythons, fmu_paths, tmp_path):
    """Two copies of an FMU in one process, run, freed and unloaded (FreeLibrary), then all again."""
    md = read_model_description(str(fmu_paths["ReferenceRobot"]))
    folders = [Path(extract(str(fmu_paths["ReferenceRobot"]), unzipdir=tmp_path / f"copy{i}")) for i in (1, 2)]
    linux, _ = runs(importers, wine, 2, folders[0], md, steps=5)
    env = {"WINEPATH": windows_path(pythons(BUILD_MINOR)), "DSC_TEST_ROUNDS": "2"}
    run = wine.run([importers["windows"], 2, ",".join(windows_path(f) for f in folders), "ReferenceRobot",
                    f"{md.guid},{md.guid}", 5, STEP, *outputs(md)], env)
    assert run.returncode == 0, run.stderr
    side_by_side = [[row[0], *row[1:], *row[1:]] for row in linux]
    assert_like_linux(parse_rows(run.stdout), side_by_side * 2)


@pytest.mark.parametrize("stdout", ("devnull", "file"))
def test_hosts_whose_output_is_not_a_pipe(importers, wine, pythons, fmu_paths, tmp_path, stdout):
    """A host whose standard output goes nowhere runs; one whose standard output is a file gets, under
    Wine 8.0 (where CPython cannot start so: see the README), a NULL and one message, never an exit."""
    md = read_model_description(str(fmu_paths["ReferenceRobot"]))
    folder = Path(extract(str(fmu_paths["ReferenceRobot"]), unzipdir=tmp_path / "r"))
    env = {"WINEPATH": windows_path(pythons(BUILD_MINOR))}
    with open(tmp_path / "stdout.txt", "w") if stdout == "file" else open("/dev/null", "w") as target:
        linux, run = runs(importers, wine, 2, folder, md, env, stdout=target)
    if stdout == "devnull" or run.returncode == 0:
        assert run.returncode == 0, run.stderr
        if stdout == "file":
            assert_like_linux(parse_rows((tmp_path / "stdout.txt").read_text()), linux)
    else:
        assert run.returncode == 2, run.stderr
        (message,) = errors(run)
        assert "Python did not start: init_sys_streams" in message


@pytest.fixture(scope="module")
def windows_threads(tmp_path_factory):
    return compile_c("c_threads.c", tmp_path_factory.mktemp("threads") / "c_threads.exe", windows=True)


def fields(line: str) -> dict:
    return {key: value for key, _, value in (item.partition("=") for item in line.split())}


def test_windows_hosts_with_threads(wine, pythons, windows_threads, fmu_paths, tmp_path):
    """The binary layer's promises on Windows (tests/test_real_hosts.py has them on Linux, FMI 2.0 and
    3.0): a logger that blocks holds up no other instance; 300 short-lived threads leave no Python
    thread state behind (each deleted when its thread ends, seen through fiber-local storage); a host
    may join a worker while holding the GIL."""
    version, paths = 2, fmu_paths
    env = {"WINEPATH": windows_path(pythons(BUILD_MINOR))}
    plant, reference = (Path(extract(str(paths[name]), unzipdir=tmp_path / name)) for name in ("MobileRobot", "ReferenceRobot"))
    md = {folder: read_model_description(str(folder)) for folder in (plant, reference)}
    token = {folder: token_of(md[folder], version) for folder in (plant, reference)}
    mass = {v.name: v.valueReference for v in md[plant].modelVariables}["mc"]
    steps = 100
    logger = wine.run([windows_threads, "logger", version, windows_path(plant), "MobileRobot", token[plant], mass, -1.0,
                       steps], env)
    assert logger.returncode == 0, logger.stderr
    assert fields(logger.stdout) == {"steps_while_logger_waited": str(steps), "logger_calls": "1", "timed_out": "0"}
    threads = wine.run([windows_threads, "threads", version, windows_path(reference), "ReferenceRobot",
                        token[reference], 300], env)
    assert threads.returncode == 0, threads.stderr
    states = [int(n) for n in fields(threads.stdout)["thread_states"].split(",")]
    assert states[1] == states[0], threads.stdout
    join = wine.run([windows_threads, "join", version, windows_path(reference), "ReferenceRobot", token[reference]],
                    env, timeout=120)
    assert join.returncode == 0 and fields(join.stdout) == {"joined": "1"}, join.stdout + join.stderr
