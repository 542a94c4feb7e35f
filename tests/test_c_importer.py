"""The FMUs in C importers without Python: each FMU (FMI 2.0 and 3.0) in ``c_importer.c`` (co-simulation)
and ``c_model_exchange.c`` (model exchange, RK4 in C) and the paper's loop in ``c_master.c``, started with
an empty environment from another working directory, against fmpy and our master; where the binary looks
for its Python, and what it says when there is none."""

import subprocess
import sysconfig
from pathlib import Path

import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi3 import FMU3Slave

from c_hosts import EMPTY_ENVIRONMENT, compile_c, parse_rows, run_c, write_plan
from wine import required
from dsc_fmu.fmubuild.binary import LINUX, OVERRIDE_VARIABLE, PythonRuntime, build_python, compile_binary
from dsc_fmu.cosim.master import cosimulate
from dsc_fmu.scenario import load_scenario

NAMES = ("ReferenceRobot", "MobileRobot", "DSCController")
OTHER_MINORS = (9, 10, 12, 13)  # the oldest CPython the FMUs take, and newer ones
STEPS, STEP = 50, 0.02
SYSTEM_LIBPYTHON = Path("/usr/lib") / (sysconfig.get_config_var("MULTIARCH") or "") / f"libpython{build_python().version}.so.1.0"


@pytest.fixture(scope="module")
def importer(tmp_path_factory):
    return compile_c("c_importer.c", tmp_path_factory.mktemp("c") / "c_importer")


@pytest.fixture(scope="module")
def model_exchange_importer(tmp_path_factory):
    return compile_c("c_model_exchange.c", tmp_path_factory.mktemp("c") / "c_model_exchange")


@pytest.fixture(scope="module")
def master(tmp_path_factory):
    return compile_c("c_master.c", tmp_path_factory.mktemp("c") / "c_master")


def unzipped_fmus(paths, folder: Path) -> dict:
    return {name: Path(extract(str(path), unzipdir=folder / name)) for name, path in paths.items()}


def outputs(md):
    return [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type in ("Real", "Float64")]


def c_run(importer, version, folder, md, refs, cwd, env=None):
    token = md.guid if version == 2 else md.instantiationToken
    return run_c([importer, version, folder, md.coSimulation.modelIdentifier, token, STEPS, STEP, *refs], cwd, env)


def fmpy_run(version, folder, md, refs, max_step=None):
    cls = FMU3Slave if version == 3 else FMU2Slave
    fmu = cls(guid=md.guid, unzipDirectory=str(folder), modelIdentifier=md.coSimulation.modelIdentifier,
              instanceName="fmpy")
    fmu.instantiate()
    if version == 3:
        fmu.enterInitializationMode(startTime=0.0)
    else:
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
    if max_step is not None:
        reference = next(v.valueReference for v in md.modelVariables if v.name == "max_step")
        (fmu.setFloat64 if version == 3 else fmu.setReal)([reference], [max_step])
    fmu.exitInitializationMode()
    get = fmu.getFloat64 if version == 3 else fmu.getReal
    rows = []
    for k in range(STEPS + 1):
        rows.append([k * STEP, *get(refs)])
        if k < STEPS:
            fmu.doStep(k * STEP, STEP)
    fmu.terminate()
    fmu.freeInstance()
    return rows


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", NAMES)
def test_each_fmu_runs_in_a_c_process_without_python_like_in_fmpy(importer, fmu_paths, fmu3_paths, tmp_path, name,
                                                                  version):
    path = (fmu3_paths if version == 3 else fmu_paths)[name]
    md = read_model_description(str(path))
    folder = Path(extract(str(path), unzipdir=tmp_path / name))
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    run = c_run(importer, version, folder, md, outputs(md), cwd)
    assert run.returncode == 0, run.stderr
    assert parse_rows(run.stdout) == fmpy_run(version, folder, md, outputs(md))


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", NAMES)
def test_each_fmu_in_a_c_model_exchange_importer_equals_its_co_simulation(model_exchange_importer, fmu_paths,
                                                                          fmu3_paths, tmp_path, name, version):
    """Model exchange from a C process without Python: RK4 at 0.02 s in C on the FMU's derivatives (its
    inputs held at their start values), against the same FMU's co-simulation with RK4 sub-steps of 0.02 s
    in the FMU: the same equations and the same arithmetic, so the same values to rounding."""
    path = (fmu3_paths if version == 3 else fmu_paths)[name]
    md = read_model_description(str(path))
    folder = Path(extract(str(path), unzipdir=tmp_path / name))
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    token = md.guid if version == 2 else md.instantiationToken
    run = run_c([model_exchange_importer, version, folder, md.modelExchange.modelIdentifier, token,
                 len(md.derivatives), md.numberOfEventIndicators, STEPS, STEP, *outputs(md)], cwd)
    assert run.returncode == 0, run.stderr
    *rows, events = run.stdout.splitlines()
    assert events == "events,0"  # the inputs are held: no switch is crossed
    flat = lambda rows: [value for row in rows for value in row]  # noqa: E731
    expected = fmpy_run(version, folder, md, outputs(md), max_step=STEP)
    assert flat(parse_rows("\n".join(rows))) == pytest.approx(flat(expected), rel=1e-13, abs=1e-13)


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", NAMES)
def test_states_set_by_value_reference_in_a_c_importer_equal_the_state_vector(model_exchange_importer, fmu_paths,
                                                                               fmu3_paths, tmp_path, name, version):
    """The C importer's RK4 with every state set by value reference (``fmi2SetReal`` / ``fmi3SetFloat64``
    in continuous-time mode, as PyFMI sets them), and with ``fmiSetContinuousStates``: the same output
    rows, bit for bit."""
    path = (fmu3_paths if version == 3 else fmu_paths)[name]
    md = read_model_description(str(path))
    folder = Path(extract(str(path), unzipdir=tmp_path / name))
    token = md.guid if version == 2 else md.instantiationToken
    command = [model_exchange_importer, version, folder, md.modelExchange.modelIdentifier, token,
               len(md.derivatives), md.numberOfEventIndicators, STEPS, STEP, *outputs(md)]
    states = ",".join(str(d.variable.derivative.valueReference) for d in md.derivatives)
    by_vector = run_c(command, tmp_path)
    by_reference = run_c(command, tmp_path, {**EMPTY_ENVIRONMENT, "STATE_VRS": states})
    assert by_vector.returncode == by_reference.returncode == 0, by_reference.stderr
    assert by_reference.stdout == by_vector.stdout


def test_the_override_variable_is_the_only_candidate_when_set(importer, fmu_paths, tmp_path):
    md = read_model_description(str(fmu_paths["ReferenceRobot"]))
    folder = extract(str(fmu_paths["ReferenceRobot"]), unzipdir=tmp_path / "r")
    env = {**EMPTY_ENVIRONMENT, OVERRIDE_VARIABLE: "/nonexistent/libpython.so"}
    run = c_run(importer, 2, folder, md, [10], tmp_path, env)
    assert run.returncode == 2
    errors = [line for line in run.stderr.splitlines() if line.startswith("[")]
    assert len(errors) == 1 and f"{OVERRIDE_VARIABLE} = /nonexistent/libpython.so" in errors[0], run.stderr


def shared_cpython(minor: int) -> Path:
    """A shared library of CPython 3.``minor`` on this machine (pyenv's, the system's), or a skip (a
    failure under CI)."""
    places = (Path.home() / ".pyenv" / "versions", Path("/usr/lib"), Path("/usr/local/lib"))
    for place in places:
        for library in sorted(place.glob(f"**/libpython3.{minor}.so.1.0")):
            return library
    required(f"no shared CPython 3.{minor} (libpython3.{minor}.so.1.0) under {', '.join(map(str, places))}")


@pytest.mark.parametrize("minor", OTHER_MINORS, ids=lambda minor: f"3.{minor}")
@pytest.mark.parametrize("version", (2, 3))
def test_any_cpython_from_3_9_on_serves(importer, fmu_paths, fmu3_paths, tmp_path, minor, version):
    """Another minor version than the one that built the FMU, named by the override: the same rows as
    the building one gives (the same C library, so the same bits)."""
    path = (fmu3_paths if version == 3 else fmu_paths)["DSCController"]
    md = read_model_description(str(path))
    folder = Path(extract(str(path), unzipdir=tmp_path / "c"))
    built = c_run(importer, version, folder, md, outputs(md), tmp_path)
    other = c_run(importer, version, folder, md, outputs(md), tmp_path,
                  {**EMPTY_ENVIRONMENT, OVERRIDE_VARIABLE: str(shared_cpython(minor))})
    assert built.returncode == 0 and other.returncode == 0, other.stderr
    assert parse_rows(other.stdout) == parse_rows(built.stdout)


def cpython_home(minor: int) -> Path:
    """The installation folder (prefix) of a shared CPython 3.``minor``: its library's ``lib/`` folder's parent."""
    return shared_cpython(minor).parent.parent


def virtual_environment(minor: int, folder: Path) -> Path:
    """A virtual environment of the shared CPython 3.``minor`` in ``folder`` (its pyvenv.cfg names the
    installation's bin folder)."""
    python = cpython_home(minor) / "bin" / f"python3.{minor}"
    if not python.is_file():
        required(f"no {python} to make a virtual environment with")
    subprocess.run([str(python), "-m", "venv", "--without-pip", str(folder)], check=True, capture_output=True,
                   timeout=300)
    return folder


def refusal(importer, fmu_paths, tmp_path, env: dict, folder: Path | None = None) -> str:
    """The one message of a ReferenceRobot (FMI 2.0) that finds no Python to serve it, in ``env`` (added
    to the empty environment), unzipped into ``folder`` if given."""
    md = read_model_description(str(fmu_paths["ReferenceRobot"]))
    folder = folder or extract(str(fmu_paths["ReferenceRobot"]), unzipdir=tmp_path / "r")
    run = c_run(importer, 2, folder, md, [10], tmp_path, {**EMPTY_ENVIRONMENT, **env})
    assert run.returncode == 2, run.stderr
    (message,) = [line for line in run.stderr.splitlines() if line.startswith("[")]
    return message


@pytest.mark.parametrize("form", ("library", "folder"))
def test_a_cpython_older_than_3_9_is_refused_by_name(importer, fmu_paths, tmp_path, form):
    """Named by the override, as its library or as its installation's folder: refused with its file and
    version."""
    library = shared_cpython(8)
    named, said = (library, f"{OVERRIDE_VARIABLE} =") if form == "library" else (
        cpython_home(8), f"{OVERRIDE_VARIABLE} folder:")
    message = refusal(importer, fmu_paths, tmp_path, {OVERRIDE_VARIABLE: str(named)})
    assert f"{said} {library}: Python 3.8." in message and "older than 3.9" in message


@pytest.mark.parametrize("form", ("installation", "virtual environment"))
def test_the_override_may_name_a_cpythons_folder(importer, fmu_paths, tmp_path, form):
    """DSC_FMU_PYTHON as users write it: an installation's folder (its home), or a virtual environment's;
    the library is found in it, and the rows are the building Python's."""
    minor = OTHER_MINORS[-1]
    named = cpython_home(minor) if form == "installation" else virtual_environment(minor, tmp_path / "venv")
    md = read_model_description(str(fmu_paths["DSCController"]))
    folder = Path(extract(str(fmu_paths["DSCController"]), unzipdir=tmp_path / "c"))
    built = c_run(importer, 2, folder, md, outputs(md), tmp_path)
    other = c_run(importer, 2, folder, md, outputs(md), tmp_path, {**EMPTY_ENVIRONMENT, OVERRIDE_VARIABLE: str(named)})
    assert built.returncode == 0 and other.returncode == 0, other.stderr
    assert parse_rows(other.stdout) == parse_rows(built.stdout)


def test_a_folder_without_a_cpython_is_one_message_naming_it_and_what_was_looked_for(importer, fmu_paths, tmp_path):
    empty = tmp_path / "no python here"
    (empty / "lib").mkdir(parents=True)
    message = refusal(importer, fmu_paths, tmp_path, {OVERRIDE_VARIABLE: str(empty)})
    assert f"{OVERRIDE_VARIABLE} = {empty}: a folder without a CPython library" in message
    assert "looked for lib/libpython3.X.so.1.0 or lib/x86_64-linux-gnu/libpython3.X.so.1.0" in message


def test_a_cpython_older_than_3_9_that_the_loader_finds_is_named_with_its_file_and_version(importer, fmu_paths,
                                                                                          tmp_path):
    """No building Python, and the dynamic loader's search meets only a CPython 3.8 (under a name of this
    test's, so that the machine's own libpython3.X stays out of it): the message names its file and version."""
    built = build_python()
    runtime = PythonRuntime(built.version, "/nonexistent/lib/libpython.so", "/nonexistent", "libdsc-test-python3.%d.so")
    folder = _with_binary(fmu_paths["ReferenceRobot"], tmp_path / "r", runtime)
    loader = tmp_path / "loader"
    loader.mkdir()
    (loader / "libdsc-test-python3.8.so").symlink_to(shared_cpython(8))
    message = refusal(importer, fmu_paths, tmp_path, {"LD_LIBRARY_PATH": str(loader)}, folder)
    assert (f"the system's libdsc-test-python3.8.so ({shared_cpython(8).resolve()}): Python 3.8." in message
            and "older than 3.9" in message), message
    assert "libdsc-test-python3.9.so" in message and "libdsc-test-python3.7.so" not in message  # not found: 3.9+


def _with_binary(fmu: Path, folder: Path, runtime: PythonRuntime) -> Path:
    folder = Path(extract(str(fmu), unzipdir=folder))
    (folder / LINUX.file(2, fmu.stem)).write_bytes(compile_binary(2, LINUX, runtime))
    return folder


@pytest.mark.skipif(not SYSTEM_LIBPYTHON.is_file(), reason=f"no system {SYSTEM_LIBPYTHON.name}")
def test_without_the_building_python_the_systems_libpython_serves(importer, fmu_paths, tmp_path):
    built = build_python()
    runtime = PythonRuntime(built.version, "/nonexistent/lib/libpython.so", "/nonexistent")
    folder = _with_binary(fmu_paths["ReferenceRobot"], tmp_path / "r", runtime)
    md = read_model_description(str(fmu_paths["ReferenceRobot"]))
    run = c_run(importer, 2, folder, md, outputs(md), tmp_path)
    assert run.returncode == 0, run.stderr
    flat = lambda rows: [value for row in rows for value in row]  # noqa: E731
    assert flat(parse_rows(run.stdout)) == pytest.approx(flat(fmpy_run(2, folder, md, outputs(md))), rel=1e-12, abs=1e-12)


def test_no_python_found_is_one_message_and_no_instance(importer, fmu_paths, tmp_path):
    built = build_python()
    runtime = PythonRuntime(built.version, "/nonexistent/lib/libpython.so", "/nonexistent", "libpython-absent-3.%d.so")
    folder = _with_binary(fmu_paths["ReferenceRobot"], tmp_path / "r", runtime)
    md = read_model_description(str(fmu_paths["ReferenceRobot"]))
    run = c_run(importer, 2, folder, md, [10], tmp_path)
    assert run.returncode == 2, run.stderr
    errors = [line for line in run.stderr.splitlines() if line.startswith("[")]
    assert len(errors) == 1, run.stderr
    minors = [f"3.{built.version.split('.')[1]}", *(f"3.{minor}" for minor in range(20, 8, -1))]
    searched = ", ".join(f"libpython-absent-{minor}.so" for minor in dict.fromkeys(minors))
    for looked_at in (f"{OVERRIDE_VARIABLE} not set", "/nonexistent/lib/libpython.so", f"not found: {searched};"):
        assert looked_at in errors[0]


@pytest.mark.parametrize("threads", (False, True), ids=("one thread", "worker threads"))
@pytest.mark.parametrize("order", ("gauss-seidel", "jacobi"))
def test_the_paper_loop_in_a_c_master_equals_ours(master, fmu_paths, tmp_path, order, threads):
    h, steps, every = 1e-3, 2000, 100
    scenario = load_scenario("paper").with_simulation(stop_time=steps * h, output_interval=every * h)
    ours = cosimulate(scenario, fmu_paths, step_size=h, order=order).result
    record = {"MobileRobot": ["x", "y", "theta"], "DSCController": ["u1", "u2", "a1_hat"]}
    plan = write_plan(tmp_path / "plan.txt", unzipped_fmus(fmu_paths, tmp_path), steps, h, order, threads, every,
                      record)
    run = run_c([master, plan], tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = parse_rows(run.stdout)
    columns = ["time", *record["MobileRobot"], *record["DSCController"]]
    assert rows == [[float(ours[c][i]) for c in columns] for i in range(len(ours))]
