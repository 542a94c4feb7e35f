"""The FMUs' directional derivatives put to use: the loop's Jacobian for SciPy's implicit integrators
(``--method Radau``, ``BDF``) and the FMUs or the closed loop linearised at a time of a run as
python-control systems, checked against finite differences of the FMUs' own values."""

import numpy as np
import pytest

from dsc_fmu.cosim.linear import closed_loop_state_space
from dsc_fmu.cosim.loading import LoadedFmus
from dsc_fmu.cosim.model_exchange import _integrate, _Ode, _start, linearise_at, simulate_model_exchange
from dsc_fmu.cosim.wiring import Recorder, Wiring
from dsc_fmu.registry import ORDER
from dsc_fmu.scenario import Method, ScenarioError, load_scenario

AT = 5.0


def loaded_loop(fmu_paths, scenario, at: float, tmp_path):
    """The paper loop through model exchange, integrated to ``at``: (the open FMUs, the loop, its state)."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    fmus = LoadedFmus(fmu_paths, tmp_path, [], model_exchange=True)
    wiring = Wiring(fmus.by_name)
    ode = _Ode(wiring, scenario.simulation.bound)
    _start(ode, scenario.with_simulation(stop_time=at))
    _integrate(ode, Recorder(wiring, 2), np.array([0.0, at]), 1e-8, Method.DOP853)
    return fmus, ode, ode.states()


def central_differences(f, y: np.ndarray) -> np.ndarray:
    """The Jacobian of ``f`` at ``y`` by five-point central differences, each column at its value's scale."""
    columns = []
    for j in range(len(y)):
        h = 1e-3 * max(abs(y[j]), 1e-3)
        shifted = lambda k: f(np.where(np.arange(len(y)) == j, y[j] + k * h, y))  # noqa: E731
        columns.append((shifted(-2) - 8 * shifted(-1) + 8 * shifted(1) - shifted(2)) / (12 * h))
    return np.array(columns).T


@pytest.mark.parametrize("version", (2, 3))
def test_the_loops_jacobian_from_the_fmus_equals_finite_differences_of_its_derivatives(fmu_paths, fmu3_paths,
                                                                                       tmp_path, version):
    """The assembly of the three FMUs' blocks (each exact to rounding, tests/test_directional_*.py) into the
    loop's Jacobian, against the five-point differences of the whole loop's derivatives at 5 s of the paper
    run: to 1e-7 of each row's largest entry, the differences' own error through the loop being about 1e-8."""
    paths = fmu3_paths if version == 3 else fmu_paths
    fmus, loop, y = loaded_loop(paths, load_scenario("paper"), AT, tmp_path)
    with fmus:
        jacobian = loop.jacobian(AT, y)
        expected = central_differences(lambda z: loop.derivatives(AT, z), y)
    scale = np.maximum(np.abs(expected).max(axis=1, keepdims=True), 1.0)
    assert jacobian.shape == (30, 30)
    np.testing.assert_allclose(jacobian / scale, expected / scale, rtol=0, atol=1e-7)


def test_fmi2_and_fmi3_give_the_same_jacobian(fmu_paths, fmu3_paths, tmp_path):
    found = []
    for version, paths in ((2, fmu_paths), (3, fmu3_paths)):
        fmus, loop, y = loaded_loop(paths, load_scenario("paper"), AT, tmp_path / str(version))
        with fmus:
            found.append(loop.jacobian(AT, y))
    np.testing.assert_array_equal(found[0], found[1])


def test_the_plants_blocks_have_the_kinematics_and_motor_entries_of_the_paper(fmu_paths, tmp_path):
    """(1): d x_dot / d theta = -r (v1 + v2) / 2 sin(theta); (5): d i1_dot / d u1 = 1 / La1, d i1_dot / d i1
    = -Ra1 / La1, d i1_dot / d v1 = -N1 KE1 / La1."""
    fmus, loop, y = loaded_loop(fmu_paths, load_scenario("paper"), AT, tmp_path)
    with fmus:
        blocks = loop.blocks()["MobileRobot"]
        p = load_scenario("paper").plant
    x, _, theta, v1, v2, i1, _ = y[3:10]
    states = list(blocks.states)
    A, B = blocks.A, blocks.B
    assert A[0, states.index("theta")] == pytest.approx(-p["r"] * (v1 + v2) / 2 * np.sin(theta), rel=1e-14)
    assert B[states.index("i1"), blocks.inputs.index("u1")] == pytest.approx(1 / p["La1"], rel=1e-14)
    assert A[states.index("i1"), states.index("i1")] == pytest.approx(-p["Ra1"] / p["La1"], rel=1e-14)
    assert A[states.index("i1"), states.index("omega1")] == pytest.approx(-p["N1"] * p["KE1"] / p["La1"], rel=1e-14)


@pytest.mark.parametrize("method", ("Radau", "BDF"))
def test_implicit_methods_with_the_fmus_jacobian_agree_with_dop853(fmu_paths, method):
    scenario = load_scenario("paper")
    runs = {m: simulate_model_exchange(scenario, fmu_paths, stop_time=10.0, tolerance=1e-8, method=m)
            for m in ("DOP853", method)}
    assert runs[method].settings["method"] == method and runs[method].settings["jacobian_evaluations"] > 0
    assert runs["DOP853"].settings["jacobian_evaluations"] == 0
    for column in ("x", "y", "theta", "u1", "a1_hat"):
        ours, reference = runs[method].result[column], runs["DOP853"].result[column]
        assert np.max(np.abs(ours - reference)) <= 1e-5 * max(1.0, np.max(np.abs(reference))), column


def test_a_method_that_is_not_one_is_refused_in_one_line(fmu_paths):
    with pytest.raises(ScenarioError, match="method.*'RK45'.*allowed: DOP853, Radau, BDF"):
        simulate_model_exchange(load_scenario("paper"), fmu_paths, stop_time=0.1, method="RK45")


def test_the_closed_loop_at_20_s_as_a_python_control_system(fmu_paths, tmp_path):
    """The documented example: the loop linearised at t = 20 s of the paper's run; its matrix is the loop's
    Jacobian there, its inputs disturb the plant's voltages, its outputs are the plant's measured outputs."""
    loop = linearise_at(load_scenario("paper"), fmu_paths, 20.0, tolerance=1e-8)
    assert (loop.nstates, loop.ninputs, loop.noutputs) == (30, 2, 8)
    assert loop.input_labels == ["d_u1", "d_u2"] and loop.output_labels[:3] == ["x", "y", "theta"]
    assert loop.state_labels[0] == "ReferenceRobot.x_r" and loop.state_labels[-1].startswith("DSCController.")
    poles = loop.poles()
    assert np.all(poles.real <= 0.0)
    small = np.sort(poles[np.abs(poles) < 1e-5].real)  # the estimates' leakage, then the reference's pose
    c = load_scenario("paper").controller
    expected = [-c["Gamma2_5"] * c["sigma4"]] * 2 + [-c["Gamma1_1"] * c["sigma3"]] * 6 + [0.0] * 3
    np.testing.assert_allclose(np.sort(small)[::-1], sorted(expected, reverse=True), rtol=1e-5, atol=1e-13)
    fmus, loaded, y = loaded_loop(fmu_paths, load_scenario("paper"), 20.0, tmp_path)
    with fmus:
        blocks = loaded.blocks()
    np.testing.assert_allclose(loop.A, closed_loop_state_space(blocks).A, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("which", ORDER)
def test_each_fmu_alone_as_a_python_control_system(fmu_paths, which):
    system = linearise_at(load_scenario("paper"), fmu_paths, 2.0, which=which)
    sizes = {"ReferenceRobot": (3, 0, 6), "MobileRobot": (7, 2, 8), "DSCController": (20, 14, 2)}
    assert (system.nstates, system.ninputs, system.noutputs) == sizes[which]


def test_an_unknown_fmu_name_is_refused(fmu_paths):
    with pytest.raises(ScenarioError, match="'Plant' is not one of the FMUs; allowed: ReferenceRobot"):
        linearise_at(load_scenario("paper"), fmu_paths, 1.0, which="Plant")
