"""SSP export, libcosim and fmpy.ssp runs of it, compared with our master and the matching exchange modes."""

import dataclasses
import re
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from lxml import etree

from dsc_fmu.cosim.exchange import cosimulate_exchange
from dsc_fmu.cosim.master import cosimulate
from dsc_fmu.cosim.model_exchange import DEFAULT_TOLERANCE
from dsc_fmu.models.parameters import START_ON
from dsc_fmu.scenario import Interface, ScenarioError, load_scenario, scenario_names
from dsc_fmu.interop.ssp import SSD_NAMESPACES as NS
from dsc_fmu.errors import CosimulationError, FmiVersionError
from dsc_fmu.interop.ssp import FMI2_ONLY, export_ssp, model_name, run_simulate_ssp, validate_ssp
from needs_libcosimpy import libcosimpy  # noqa: F401 (the fixture)

H, T = 1e-3, 0.2
COMPARED = ("x", "y", "theta", "omega1", "i1", "x_r", "theta_r", "u1", "u2", "a1_hat", "a2_hat", "W1_hat_norm",
            "W2_hat_norm", "S11", "beta")


def relative(a, b, columns=COMPARED):
    return max(float(np.max(np.abs(a[c] - b[c]) / np.maximum(1e-12, np.maximum(np.abs(a[c]), np.abs(b[c])))))
               for c in columns)


@pytest.fixture(scope="module")
def paper():
    return load_scenario("paper")


@pytest.fixture(scope="module")
def ssp_file(paper, fmu_paths, tmp_path_factory):
    return export_ssp(paper, tmp_path_factory.mktemp("ssp") / "paper.ssp", fmu_paths, step_size=H, stop_time=T)


def test_archive_content_and_schema(ssp_file, paper, fmu_paths):
    validate_ssp(ssp_file)
    with zipfile.ZipFile(ssp_file) as archive:
        names = set(archive.namelist())
        assert {f"resources/{n}.fmu" for n in fmu_paths} <= names
        ssd = etree.fromstring(archive.read("SystemStructure.ssd"))
        sets = {n: etree.fromstring(archive.read(f"resources/{n}.ssv")) for n in fmu_paths}
    connections = {(c.get("startElement"), c.get("startConnector"), c.get("endElement"), c.get("endConnector"))
                   for c in ssd.iterfind(".//ssd:Connection", NS)}
    expected = {("MobileRobot", s, "DSCController", s) for s in
                ("x", "y", "theta", "theta_dot", "omega1", "omega2", "i1", "i2")}
    expected |= {("ReferenceRobot", s, "DSCController", s) for s in
                 ("x_r", "y_r", "theta_r", "v_r", "omega_r", "v_r_dot")}
    expected |= {("DSCController", s, "MobileRobot", s) for s in ("u1", "u2")}
    assert connections == expected
    experiment = ssd.find("ssd:DefaultExperiment", NS)
    assert float(experiment.get("startTime")) == 0 and float(experiment.get("stopTime")) == T
    assert float(experiment.find(".//osp:FixedStepAlgorithm", NS).get("baseStepSize")) == H
    for name, root in sets.items():
        values = {p.get("name"): p[0] for p in root.iterfind(".//ssv:Parameter", NS)}
        assert set(values) == set(paper.parameters(name))
        for key, value in paper.parameters(name).items():
            assert float(values[key].get("value")) == value
    assert values["discretization"].tag.endswith("Integer")


OMS_IDENT = re.compile(r"^[a-zA-Z][a-zA-Z0-9_]*$")  # OMSimulator's ComRef::isValidIdent


def read_ssd(ssp_file):
    with zipfile.ZipFile(ssp_file) as archive:
        return etree.fromstring(archive.read("SystemStructure.ssd"))


@pytest.fixture(scope="module")
def odd_name(tmp_path_factory):
    """A user's scenario whose name has a space, a dash and a dot (the paper's loop otherwise)."""
    path = tmp_path_factory.mktemp("scenario") / "odd.toml"
    path.write_text('name = "my run-2.b"\n')
    return path


@pytest.mark.parametrize("name", [*scenario_names(), "odd"])
def test_names_are_identifiers_omsimulator_accepts(name, odd_name, fmu_paths, tmp_path):
    """OMSimulator refuses a model, system or component whose name is not ``^[a-zA-Z][a-zA-Z0-9_]*$``
    ('"dsc-fmu paper" is not a valid ident'); the scenario's own name stays in the description."""
    scenario = load_scenario(odd_name if name == "odd" else name)
    root = read_ssd(export_ssp(scenario, tmp_path / "loop.ssp", fmu_paths, stop_time=T))
    names = [root.get("name"), *(e.get("name") for e in root.iterfind(".//ssd:System", NS)),
             *(e.get("name") for e in root.iterfind(".//ssd:Component", NS))]
    assert all(OMS_IDENT.match(n) for n in names), names
    assert root.get("name") == model_name(scenario.name)
    assert scenario.name in root.get("description")


def test_model_name():
    assert model_name("paper") == "dsc_fmu_paper"
    assert model_name("my run-2.b") == "dsc_fmu_my_run_2_b"
    assert model_name("2é") == "dsc_fmu_2_"


def omsimulator_information(root):
    """The solver element OMSimulator reads (Model::getSystemType): pugixml matches the qualified
    names, so the prefixes count, and it takes the first ssc:Annotation of the system's annotations."""
    annotation = root.find("ssd:System/ssd:Annotations", NS)[0]
    assert annotation.tag == f"{{{NS['ssc']}}}Annotation" and annotation.get("type") == "org.openmodelica"
    wrapper = annotation[0]
    information = wrapper.find("oms:SimulationInformation", NS)
    (solver,) = information
    assert (wrapper.prefix, information.prefix, solver.prefix) == ("oms", "oms", "oms")
    return etree.QName(solver).localname, dict(solver.attrib)


def test_omsimulator_annotation_co_simulation(ssp_file):
    assert omsimulator_information(read_ssd(ssp_file)) == ("FixedStepMaster", {"description": "oms-ma",
                                                                                "stepSize": repr(H)})


@pytest.mark.parametrize("tolerance", (None, 1e-8))
def test_omsimulator_annotation_model_exchange(paper, fmu_paths, tmp_path, tolerance):
    scenario = paper.with_simulation(tolerance=tolerance, output_interval=0.02)
    out = export_ssp(scenario, tmp_path / "me.ssp", fmu_paths, interface="model-exchange", stop_time=T)
    validate_ssp(out)
    kind, attributes = omsimulator_information(read_ssd(out))
    assert kind == "VariableStepSolver"
    assert attributes == {"description": "cvode", "relativeTolerance": repr(tolerance or DEFAULT_TOLERANCE),
                          "maximumStepSize": "0.02"}
    same = export_ssp(scenario, tmp_path / "me2.ssp", fmu_paths, interface=Interface.MODEL_EXCHANGE, stop_time=T)
    assert read_ssd(same).get("name") == read_ssd(out).get("name")
    assert etree.tostring(read_ssd(same)) == etree.tostring(read_ssd(out))


def test_unknown_interface_is_refused(paper, fmu_paths, tmp_path):
    with pytest.raises(ScenarioError, match="interface = 'cs' is not allowed; allowed: co-simulation, model-exchange"):
        export_ssp(paper, tmp_path / "x.ssp", fmu_paths, interface="cs")
    assert list(tmp_path.iterdir()) == []


def test_fmi3_fmus_are_refused_in_one_line_and_nothing_is_written(paper, fmu_paths, fmu3_paths, tmp_path):
    """No SSP importer runs the loop of FMI 3.0 FMUs: an archive of any of them is refused."""
    fmus = dict(fmu_paths, MobileRobot=fmu3_paths["MobileRobot"])
    with pytest.raises(FmiVersionError) as refusal:
        export_ssp(paper, tmp_path / "fmi3.ssp", fmus, stop_time=T)
    assert str(refusal.value) == (f"{fmu3_paths['MobileRobot']} is an FMI 3.0 FMU, not allowed here: {FMI2_ONLY}; "
                                  "allowed: FMI 2.0 FMUs")
    assert list(tmp_path.iterdir()) == []


def test_bad_scenario_writes_nothing(paper, fmu_paths, tmp_path):
    out = tmp_path / "bad.ssp"
    with pytest.raises(ScenarioError):
        export_ssp(paper, out, fmu_paths, step_size=0.0)
    with pytest.raises(FileNotFoundError):
        export_ssp(paper, out, {k: v for k, v in fmu_paths.items() if k != "MobileRobot"})
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("version", (2, 3))
def test_jacobi_mode_is_our_master(paper, fmu_paths, fmu3_paths, version):
    fmus = fmu_paths if version == 2 else fmu3_paths
    ours = cosimulate(paper, fmus, step_size=H, stop_time=T, order="jacobi", output_interval=H).result
    mine = cosimulate_exchange(paper, fmus, "jacobi", step_size=H, stop_time=T).result
    assert np.array_equal(ours, mine)


def test_exchange_modes_keep_the_fmus_coupling_whatever_the_scenario_says_of_input_derivatives(paper, fmu_paths):
    """The other masters set no input derivatives, so the FMUs keep the scenario's coupling (linear here):
    the scenario's ``input_derivatives``, which only our master acts on, changes nothing in their runs."""
    linear = paper.with_simulation(coupling="linear")
    own = cosimulate_exchange(linear, fmu_paths, "libcosim", step_size=H, stop_time=T).result
    told = cosimulate_exchange(linear.with_simulation(input_derivatives=True), fmu_paths, "libcosim",
                               step_size=H, stop_time=T).result
    held = cosimulate_exchange(paper, fmu_paths, "libcosim", step_size=H, stop_time=T).result
    assert np.array_equal(own, told) and not np.array_equal(own, held)


def test_exchange_modes_give_the_same_through_fmi3(paper, fmu_paths, fmu3_paths):
    for mode in ("libcosim", "simulate_ssp"):
        scenario = dataclasses.replace(paper, controller={**paper.controller, "start_on": 1})
        fmi2 = cosimulate_exchange(scenario, fmu_paths, mode, step_size=H, stop_time=T)
        fmi3 = cosimulate_exchange(scenario, fmu3_paths, mode, step_size=H, stop_time=T)
        assert np.array_equal(fmi2.result, fmi3.result)


CHILD = (
    "import sys, numpy; from dsc_fmu.interop.libcosim import run_libcosim; "
    "numpy.save(sys.argv[4], run_libcosim(sys.argv[1], float(sys.argv[2]), float(sys.argv[3])))"
)


def libcosim_in_its_own_process(ssp_file, h, t, folder):
    """``run_libcosim`` in a child process, as a separate importer: libcosim and fmpy's container FMU
    loaded in one process sometimes abort at its exit (a double free while unloading), see the README."""
    out = folder / "libcosim.npy"
    child = subprocess.run([sys.executable, "-c", CHILD, str(ssp_file), repr(h), repr(t), str(out)],
                           capture_output=True, text=True, timeout=300)
    assert child.returncode == 0, child.stderr[-2000:]
    return np.load(out)


@pytest.mark.usefixtures("libcosimpy")
def test_libcosim_matches_the_libcosim_mode(ssp_file, paper, fmu_paths, tmp_path):
    libcosim = libcosim_in_its_own_process(ssp_file, H, T, tmp_path)
    mode = cosimulate_exchange(paper, fmu_paths, "libcosim", step_size=H, stop_time=T).result
    assert len(libcosim) == len(mode) == round(T / H) + 1
    np.testing.assert_allclose(libcosim["time"], mode["time"], rtol=0, atol=1e-12)
    assert relative(libcosim, mode) < 1e-9
    # and it is not our Jacobi: the controller's u reaches the plant one step later
    ours = cosimulate(paper, fmu_paths, step_size=H, stop_time=T, order="jacobi", output_interval=H).result
    assert libcosim["u1"][0] == pytest.approx(ours["u1"][0], rel=1e-12)
    assert relative(libcosim, ours, ("u1",)) > 1e-3


def test_simulate_ssp_refuses_the_first_step_as_its_matching_mode(ssp_file, paper, fmu_paths):
    """simulate_ssp starts every connector at 0.0 and has no initial exchange: with the paper's
    controller (start_on = first_use) the first step gets v_r = 0, which it refuses (Assumption 2),
    in fmpy's loop and in the matching mode alike (ours names the FMU and the time)."""
    from fmpy.fmi1 import FMICallException

    with pytest.raises(FMICallException) as theirs:
        run_simulate_ssp(ssp_file, H, T, start_on=None)
    assert theirs.value.status == 2 and "fmi2DoStep" in str(theirs.value)  # fmi2Discard
    with pytest.raises(CosimulationError, match=r"DSCController failed at t = 0 s: fmi2DoStep failed with status 2 "
                                                r"\(discard\)\. Its last log messages: .*v_r = 0\.0 is not allowed"):
        cosimulate_exchange(paper, fmu_paths, "simulate_ssp", step_size=H, stop_time=T)


@pytest.fixture(scope="module")
def waiting(paper):
    return dataclasses.replace(paper, controller={**paper.controller, "start_on": START_ON.index("valid_inputs")})


def test_start_on_changes_nothing_where_the_first_inputs_are_valid(paper, waiting, fmu_paths):
    for order in ("gauss-seidel", "jacobi"):
        first = cosimulate(paper, fmu_paths, step_size=H, stop_time=T, order=order, output_interval=H).result
        valid = cosimulate(waiting, fmu_paths, step_size=H, stop_time=T, order=order, output_interval=H).result
        assert np.array_equal(first, valid)


def test_simulate_ssp_runs_the_loop_and_matches_its_mode(ssp_file, waiting, fmu_paths):
    """With start_on = valid_inputs (run_simulate_ssp's default) simulate_ssp runs the loop: the
    controller waits out the first step, and the result equals the matching mode to 1e-9 relative.
    Its time stamps: row k holds the values after the step that starts at its time k h."""
    theirs = run_simulate_ssp(ssp_file, H, T)
    mode = cosimulate_exchange(waiting, fmu_paths, "simulate_ssp", step_size=H, stop_time=T).result
    assert len(theirs) == len(mode) == round(T / H)
    np.testing.assert_allclose(theirs["time"], np.arange(len(theirs)) * H, rtol=0, atol=1e-12)
    assert relative(theirs, mode) < 1e-9
    p = waiting.reference
    end = theirs["time"] + H
    np.testing.assert_allclose(theirs["theta_r"], p["theta0"] + p["wr0"] * end, rtol=1e-12)
    np.testing.assert_allclose(theirs["x_r"], p["x0"] + p["vr0"] / p["wr0"] * np.sin(p["wr0"] * end), rtol=1e-12)
    assert theirs["u1"][0] == 0.0 and theirs["u1"][1] != 0.0  # waited one step, then started
    assert theirs["x"][1] == waiting.plant["x0"] and theirs["x"][2] != waiting.plant["x0"]  # u = 0 for two steps


@pytest.mark.usefixtures("libcosimpy")
def test_model_exchange_archive_co_simulates_as_the_other(ssp_file, paper, fmu_paths, tmp_path):
    """Only OMSimulator's annotation differs: libcosim and fmpy.ssp co-simulate the model-exchange
    archive at its fixed step, with the same results as the co-simulation archive's."""
    me = export_ssp(paper, tmp_path / "me.ssp", fmu_paths, interface="model-exchange", step_size=H, stop_time=T)
    assert np.array_equal(run_simulate_ssp(me, H, T), run_simulate_ssp(ssp_file, H, T))
    assert np.array_equal(libcosim_in_its_own_process(me, H, T, tmp_path),
                          libcosim_in_its_own_process(ssp_file, H, T, tmp_path))


def test_simulate_ssp_refuses_an_unknown_start_on(ssp_file):
    with pytest.raises(ValueError, match="start_on = 'later' is not allowed; allowed: first_use, valid_inputs or None"):
        run_simulate_ssp(ssp_file, H, T, start_on="later")
