"""The closed loop as one container FMU: fmpy simulates it as our master's Jacobi at its internal step."""

import zipfile
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

from dsc_fmu.interop.container import EXPOSED_OUTPUTS, export_fmu
from dsc_fmu.interop.libcosim import run_libcosim_fmu_in_own_process
from dsc_fmu.macho import read_slices
from needs_libcosimpy import libcosimpy  # noqa: F401 (the fixture)
from dsc_fmu.cosim.master import cosimulate
from dsc_fmu.scenario import ScenarioError, load_scenario

H, T = 1e-3, 0.2
SHOWN = ["x", "y", "theta", "x_r", "y_r", "theta_r", "u1", "u2", "a1_hat", "W1_hat_norm"]


@pytest.fixture(scope="module")
def container(fmu_paths, tmp_path_factory):
    scenario = load_scenario("paper")
    return scenario, export_fmu(scenario, tmp_path_factory.mktemp("container") / "loop.fmu", fmu_paths,
                                step_size=H, stop_time=T)


def test_valid_with_parameters_and_outputs(container):
    scenario, fmu = container
    assert validate_fmu(str(fmu)) == []
    variables = {v.name: v for v in read_model_description(str(fmu)).modelVariables}
    for name in SHOWN:
        assert variables[name].causality == "output"
    assert float(variables["MobileRobot.x0"].start) == scenario.parameters("MobileRobot")["x0"]
    assert variables["DSCController.discretization"].type == "Integer"
    with zipfile.ZipFile(fmu) as archive:  # needs no execution tool, as its components (PyFMI loads it)
        cosimulation = ElementTree.fromstring(archive.read("modelDescription.xml")).find("CoSimulation")
    assert cosimulation.get("needsExecutionTool", "false") == "false"  # the schema's default: false


@pytest.mark.parametrize("interval", [H, 10 * H])
def test_fmpy_run_is_our_jacobi(container, fmu_paths, interval):
    """Communication step `interval`, internal step H: the container runs our Jacobi at H exactly
    (same FMU calls in the same order), so the tolerance is 0 up to the last bits of t."""
    scenario, fmu = container
    theirs = simulate_fmu(str(fmu), stop_time=T, step_size=interval, output_interval=interval, output=SHOWN)
    ours = cosimulate(scenario, fmu_paths, step_size=H, stop_time=T, order="jacobi", output_interval=interval).result
    assert len(theirs) == len(ours)
    np.testing.assert_allclose(theirs["time"], ours["time"], rtol=0, atol=1e-12)
    for name in SHOWN:
        np.testing.assert_allclose(theirs[name], ours[name], rtol=1e-12, atol=1e-12)


@pytest.mark.usefixtures("libcosimpy")
@pytest.mark.parametrize("interval", [H, 10 * H])
def test_libcosim_run_is_fmpys_run(container, interval):
    """libcosim runs the container FMU alone (CosimExecution.from_step_size, CosimLocalSlave, a time
    series observer; in a process of its own, see dsc_fmu.interop.libcosim) at the communication step
    `interval`. One FMU, no connections: both importers make the same calls (doStep(t_k, interval),
    then read the outputs), so the values are expected equal to the bit: tolerance 0, measured 0
    (the importers' t_k differ in the last bits but leave no trace: the container evidently steps
    its components on its own internal time). Only the time stamps differ: libcosim's are
    k * interval in integer nanoseconds, fmpy's in floating point (measured at most 2.8e-17 s)."""
    _, fmu = container
    theirs = simulate_fmu(str(fmu), stop_time=T, step_size=interval, output_interval=interval,
                          output=list(EXPOSED_OUTPUTS))
    libcosim = run_libcosim_fmu_in_own_process(fmu, interval, T, EXPOSED_OUTPUTS)
    assert len(libcosim) == len(theirs) == round(T / interval) + 1
    np.testing.assert_allclose(libcosim["time"], theirs["time"], rtol=0, atol=1e-15)
    for name in EXPOSED_OUTPUTS:
        assert np.array_equal(libcosim[name], theirs[name]), name


def test_the_container_s_macos_binaries_are_fmpy_s_for_both_cpus(container):
    """``darwin64`` is the universal file of the two dylibs fmpy ships (not Intel's alone, as fmpy writes
    it), ``aarch64-darwin`` Apple Silicon's, byte for byte."""
    import fmpy

    shipped = Path(fmpy.__file__).parent / "container_fmu" / "binaries"
    with zipfile.ZipFile(container[1]) as fmu:
        darwin64 = fmu.read("binaries/darwin64/container_fmu.dylib")
        arm64 = fmu.read("binaries/aarch64-darwin/container_fmu.dylib")
    slices = {s.cpu: darwin64[s.offset:s.offset + s.size] for s in read_slices(darwin64)}
    assert slices == {"x86_64": (shipped / "x86_64-darwin" / "container_fmu.dylib").read_bytes(),
                      "arm64": (shipped / "aarch64-darwin" / "container_fmu.dylib").read_bytes()}
    assert arm64 == slices["arm64"]


def test_start_values_reach_the_components(container, fmu_paths):
    scenario, fmu = container
    theirs = simulate_fmu(str(fmu), stop_time=10 * H, step_size=H, output=["x", "y"],
                          start_values={"MobileRobot.x0": 3.0})
    assert theirs["x"][0] == 3.0 and theirs["y"][0] == scenario.parameters("MobileRobot")["y0"]


def test_bad_scenario_writes_nothing(fmu_paths, tmp_path):
    with pytest.raises(ScenarioError):
        export_fmu(load_scenario("paper"), tmp_path / "bad.fmu", fmu_paths, step_size=-1.0)
    assert list(tmp_path.iterdir()) == []
