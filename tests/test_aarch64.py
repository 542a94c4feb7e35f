"""The project on aarch64 Linux, under qemu-user in an arm64 Debian root (``aarch64.py`` on ``debian_root.py``),
against the same run on this x86-64 host: the C master cross-compiled for aarch64, our master (co-simulation and
model exchange) and fmpy's ``simulate_fmu`` as its users call it, with FMI 2.0 and 3.0 FMUs built here."""

import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract

from aarch64 import NAMES, bundled_runtime, cached_arm64_root, compile_for_aarch64, elf_machine, ssp_in_fmpy
from debian_root import (EXCHANGE_TOLERANCE, PAPER_STOP, assert_identical, copied, debian_mirror, fmpy_user,
                         fmu_outputs, paper_cosimulation, paper_model_exchange)
from c_hosts import compile_c, parse_rows, run_c, write_plan

pytestmark = pytest.mark.slow

STEP, EVERY = 1e-3, 100
X86_64, AARCH64 = 62, 183
# fmpy 0.3.32 on aarch64 loads FMI 2.0 binaries from linux64 (here x86-64): glibc refuses the file as missing.
LOAD_ERROR = re.compile(r"Failed to load shared library (?P<library>/tmp/tmp\w+/binaries/linux64/(?P<model>\w+)\.so)\. "
                        r"(?P=library): cannot open shared object file: No such file or directory")


@pytest.fixture(scope="module")
def arm64_root():
    return cached_arm64_root()


@pytest.fixture()
def workspace(arm64_root):
    """A folder in the root with the project's sources, removed after the test."""
    folder = arm64_root.workspace(Path(__file__).parent / "aarch64.py")
    yield folder
    shutil.rmtree(folder)


@pytest.fixture(params=[2, 3])
def version(request):
    return request.param


def fmus_of(version, fmu_paths, fmu3_paths, workspace) -> dict:
    return copied(fmu_paths if version == 2 else fmu3_paths, workspace / "fmus")


def test_the_c_master_cross_compiled_runs_the_paper_loop_on_aarch64_bit_identical(arm64_root, workspace, fmu_paths,
                                                                                  tmp_path):
    steps = round(PAPER_STOP / STEP)
    arm_master = compile_for_aarch64("c_master.c", workspace / "c_master")
    host_master = compile_c("c_master.c", tmp_path / "c_master")
    assert elf_machine(arm_master.read_bytes()) == AARCH64 and elf_machine(host_master.read_bytes()) == X86_64
    unzipped = {name: Path(extract(str(path), unzipdir=workspace / name)) for name, path in fmu_paths.items()}
    record = {"ReferenceRobot": ["x_r", "y_r", "theta_r"],
              "MobileRobot": ["x", "y", "theta", "omega1", "omega2", "i1", "i2"],
              "DSCController": ["u1", "u2", "a1_hat", "a2_hat", "W1_hat_norm", "W2_hat_norm"]}
    plans = [write_plan(folder / "plan.txt", unzipped, steps, STEP, "gauss-seidel", False, EVERY, record, locate=locate)
             for folder, locate in ((tmp_path, str), (workspace, arm64_root.inside))]
    host = run_c([host_master, plans[0]], tmp_path)
    arm = arm64_root.run([arm64_root.inside(arm_master), arm64_root.inside(plans[1])])
    assert host.returncode == 0, host.stderr[-2000:]
    assert arm.returncode == 0, arm.stderr[-2000:]
    rows = parse_rows(arm.stdout)
    assert len(rows) == steps // EVERY + 1 and rows[-1][0] == PAPER_STOP and len(rows[-1]) == 17
    assert arm.stdout == host.stdout


def test_the_paper_scenario_through_our_master_on_aarch64_equals_x86_64(arm64_root, workspace, fmu_paths,
                                                                       fmu3_paths, version):
    """On aarch64 the FMUs' traced C gives the bits of x86-64's, and (FMI 2.0) of their Python path there."""
    fmus = fmus_of(version, fmu_paths, fmu3_paths, workspace)
    arm = arm64_root.run_task(workspace, paper_cosimulation, fmus)
    arm_python = arm64_root.run_task(workspace, paper_cosimulation, fmus, "off") if version == 2 else None
    host = paper_cosimulation(fmus)
    assert arm["steps"] == host["steps"] == round(PAPER_STOP / STEP)
    arm, host = arm["result"], host["result"]
    assert arm.dtype == host.dtype and len(arm) == len(host) and host["time"][-1] == PAPER_STOP
    from_fmus = [c for c in host.dtype.names if c in fmu_outputs(fmus)]
    computed_here = [c for c in host.dtype.names if c not in from_fmus]
    assert len(from_fmus) > 30 and "position_error" in computed_here
    assert_identical(arm, host, from_fmus)
    if arm_python is not None:
        assert_identical(arm_python["result"], arm, arm.dtype.names)
    for column in computed_here:  # numpy's SIMD loops differ by machine (hypot: 1 ulp)
        np.testing.assert_array_max_ulp(arm[column], host[column], maxulp=1)


def test_model_exchange_on_aarch64_equals_x86_64_to_rounding(arm64_root, workspace, fmu_paths, fmu3_paths, version):
    """Not to the bit: SciPy's DOP853 combines its stages with a matrix-vector product, whose BLAS kernels
    round differently on the two machines; the same steps, and a difference a thousand times below the
    solver's tolerance (seen: 1.5e-11 of a column's largest value)."""
    fmus = fmus_of(version, fmu_paths, fmu3_paths, workspace)
    arm = arm64_root.run_task(workspace, paper_model_exchange, fmus)
    host = paper_model_exchange(fmus)
    assert arm["evaluations"] == host["evaluations"] > 100
    arm, host = arm["result"], host["result"]
    assert arm.dtype == host.dtype and len(arm) == len(host)
    for column in host.dtype.names:
        scale = np.abs(host[column]).max()
        np.testing.assert_allclose(arm[column], host[column], rtol=0, atol=1e-3 * EXCHANGE_TOLERANCE * scale,
                                   err_msg=column)


def test_fmpy_simulate_fmu_on_aarch64(arm64_root, workspace, fmu_paths, fmu3_paths, version):
    """FMI 3.0: as on x86-64. FMI 2.0: fmpy loads ``linux64`` and fails; through an ``FMU2Slave`` of the
    ``aarch64-linux`` binary (``libraryPath``) as on x86-64."""
    fmus = fmus_of(version, fmu_paths, fmu3_paths, workspace)
    arm = arm64_root.run_task(workspace, fmpy_user, fmus, *(["aarch64-linux"] if version == 2 else []))
    host = fmpy_user(fmus)
    assert arm["platform"] == ["linux64", "aarch64-linux"] and host["platform"] == ["linux64", "x86_64-linux"]
    for name in NAMES:
        assert isinstance(host[name], np.ndarray), host[name]
        assert len(host[name]) > 100 and host[name]["time"][-1] == 30.0
        if version == 3:
            assert isinstance(arm[name], np.ndarray), arm[name]
            assert arm[name].dtype == host[name].dtype
            assert_identical(arm[name], host[name], host[name].dtype.names)
            continue
        assert arm[name]["type"] == "Exception", arm[name]
        match = LOAD_ERROR.fullmatch(arm[name]["message"])
        assert match and match["model"] == name, arm[name]["message"]
        assert arm[f"{name}-instance"].dtype == host[name].dtype
        assert_identical(arm[f"{name}-instance"], host[name], host[name].dtype.names)


def test_the_fmi_2_binaries_fmpy_takes_on_aarch64_are_x86_64(fmu_paths, tmp_path):
    """Why fmpy fails there: ``linux64`` holds the x86-64 binary, ``aarch64-linux`` the aarch64 one."""
    for name, path in fmu_paths.items():
        folder = Path(extract(str(path), unzipdir=tmp_path / name))
        assert elf_machine((folder / "binaries" / "linux64" / f"{name}.so").read_bytes()) == X86_64
        assert elf_machine((folder / "binaries" / "aarch64-linux" / f"{name}.so").read_bytes()) == AARCH64


def test_the_mirror_is_read_from_either_form_of_apt_sources(tmp_path):
    (tmp_path / "sources.list.d").mkdir()
    (tmp_path / "sources.list").write_text("# deb http://commented.example/debian bookworm main\n"
                                           "deb [arch=amd64] http://one-line.example/debian bookworm main\n")
    assert debian_mirror(tmp_path) == "http://one-line.example/debian"
    (tmp_path / "sources.list.d" / "debian.sources").write_text(
        "Types: deb\nURIs: http://security.example/debian-security\nSuites: bookworm-security\nComponents: main\n\n"
        "Types: deb deb-src\n# a comment\nURIs: http://deb822.example/debian\nSuites: bookworm bookworm-updates\n"
        "Components: main\n")
    assert debian_mirror(tmp_path) == "http://deb822.example/debian"
    (tmp_path / "sources.list").write_text("deb http://other.example/debian trixie main\n")
    (tmp_path / "sources.list.d" / "debian.sources").unlink()
    assert debian_mirror(tmp_path) == ""


def test_bundle_python_built_on_aarch64_carries_this_machine_s_cpython(arm64_root, workspace, fmu_paths):
    """``--bundle-python`` as it runs on aarch64 Linux (the root's Debian CPython 3.11 building): this
    platform is aarch64-linux, an FMU built here carries a CPython for it and for Windows, none for the
    x86-64 Linux it does not run on, and the runtime's libraries (libpython, lib-dynload's modules, what
    they need) are all aarch64 ELF files, with their licences."""
    fmus = copied({"MobileRobot": fmu_paths["MobileRobot"]}, workspace / "fmus")
    bundle = arm64_root.run_task(workspace, bundled_runtime, fmus)
    assert (bundle["host"], bundle["carried"], bundle["platforms"]) == (
        "aarch64-linux", ["aarch64-linux", "x86_64-windows"], ["aarch64-linux"])
    assert bundle["os"] == "linux" and bundle["needs"] == ["glibc 2.36 or newer"]
    machines = bundle["machines"]
    assert "lib/libpython3.11.so.1.0" in machines and any("/lib-dynload/_json." in name for name in machines)
    assert set(machines.values()) == {AARCH64}, machines
    assert "CPython" in bundle["licences"]


def test_fmpy_s_ssp_simulation_is_refused_on_aarch64_in_one_line(arm64_root, workspace, fmu_paths, tmp_path):
    """``run_simulate_ssp`` would have fmpy load the x86-64 binary of ``linux64``: on aarch64 it says so and
    what works instead."""
    from dsc_fmu import load_scenario
    from dsc_fmu.interop.ssp import export_ssp

    archive = export_ssp(load_scenario("paper"), tmp_path / "paper.ssp", fmu_paths)
    copy = copied({"paper": archive}, workspace / "ssp")["paper"]
    error = arm64_root.run_task(workspace, ssp_in_fmpy, {"paper": copy})["error"]
    assert error == (f"{arm64_root.inside(copy)}: fmpy's simulate_ssp loads FMI 2.0 binaries from binaries/linux64, "
                     "which holds x86-64's, and this is aarch64 Linux (its binaries are in binaries/aarch64-linux); "
                     "allowed here: dsc_fmu.cosimulate of the same FMUs, or simulate_ssp on x86-64 Linux, Windows or "
                     "macOS")
