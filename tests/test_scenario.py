"""Scenario files: the shipped ones load with the paper's values; bad ones fail with a named key."""

import math

import pytest

from dsc_fmu.models.parameters import CONTROLLER_PARAMETERS, PLANT_PARAMETERS, REFERENCE_PARAMETERS
from dsc_fmu.registry import FMUS
from dsc_fmu.scenario import ScenarioError, load_scenario, scenario_names

PAPER = """
[simulation]
stop_time = 30.0
"""


def write(tmp_path, text, name="case.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_shipped_scenarios():
    assert {"paper", "figure_eight", "ahead_start"} <= set(scenario_names())


def test_paper_scenario_has_the_papers_values():
    s = load_scenario("paper")
    assert s.simulation.stop_time == 30.0 and s.simulation.step_size == 1e-3
    assert s.simulation.order == "gauss-seidel"
    for name, variables in (("MobileRobot", PLANT_PARAMETERS), ("DSCController", CONTROLLER_PARAMETERS)):
        for v in variables:
            assert s.parameters(name)[v.name] == v.start, v.name
    assert (s.reference["x0"], s.reference["y0"], s.reference["theta0"]) == (2.0, 2.0, 0.0)
    assert (s.plant["x0"], s.plant["y0"], s.plant["theta0"]) == (2.5, 1.0, math.pi / 2)
    assert s.reference["vr0"] == 1.0 and s.reference["wr0"] == 0.2


def test_defaults_fill_what_a_file_leaves_out(tmp_path):
    s = load_scenario(write(tmp_path, "[controller]\nk4 = 0.5\n"))
    assert s.controller["k4"] == 0.5
    assert s.controller["k5"] == 1.0
    assert {v.name for v in REFERENCE_PARAMETERS} == set(s.reference)
    assert s.name == "case"


@pytest.mark.parametrize(
    "text, expected",
    [
        ("[plant]\nmass = 3\n", r"unknown key \[plant\] mass; allowed: R, d, r"),
        ("[plant]\nmc = 'heavy'\n", r"\[plant\] mc = 'heavy' is not a number; allowed: > 0"),
        ("[plant]\nmc = -30.0\n", r"\[plant\] mc = -30.0 is not allowed: it must be > 0; allowed: > 0"),
        ("[plant]\nLa1 = 0\n", r"La1 = 0 is not allowed: it must be > 0"),
        ("[controller]\ntau2 = 0.0\n", r"\[controller\] tau2 = 0.0 is not allowed"),
        ("[controller]\nk1 = true\n", r"\[controller\] k1 = True is not a number"),
        ("[reference]\nvr0 = 0.0\n", r"\[reference\] vr0 = 0.0 is not allowed: it must be > 0"),
        ("[reference]\nvr0 = -1.0\n", r"vr0 = -1.0 is not allowed"),
        ("[reference]\nprofile = 'spiral'\n", r"profile = 'spiral' is not allowed; allowed: constant, figure_eight"),
        ("[controller]\ndiscretization = 'tustin'\n", r"discretization = 'tustin' is not allowed; allowed: rk4, euler"),
        ("[controller]\ndiscretization = 1\n", r"discretization = 1 is not allowed; allowed: rk4, euler"),
        ("[simulation]\nstep_size = 0\n", r"\[simulation\] step_size = 0 is not allowed; allowed: > 0"),
        ("[simulation]\nstep_size = -1e-3\n", r"step_size = -0.001 is not allowed"),
        ("[simulation]\nstop_time = 'long'\n", r"stop_time = 'long' is not a number"),
        ("[simulation]\norder = 'random'\n", r"order = 'random' is not allowed; allowed: gauss-seidel, jacobi"),
        ("[simulation]\nsolver = 'rk4'\n", r"unknown key \[simulation\] solver"),
        ("plant = 3\n", r"plant must be a table"),
        ("colour = 'red'\n", r"unknown key colour"),
        ("[plant\n", r"not valid TOML"),
    ],
)
def test_bad_scenarios_name_file_key_value_and_range(tmp_path, text, expected):
    path = write(tmp_path, text)
    with pytest.raises(ScenarioError, match=expected) as error:
        load_scenario(path)
    message = str(error.value)
    assert message.startswith(str(path))
    assert "\n" not in message


def test_unknown_scenario_name_lists_the_allowed_ones():
    with pytest.raises(ScenarioError, match=r"unknown scenario 'nope'; allowed: .*paper"):
        load_scenario("nope")


def test_missing_file(tmp_path):
    with pytest.raises(ScenarioError, match="scenario file not found"):
        load_scenario(tmp_path / "missing.toml")


def test_with_simulation_checks_overrides():
    s = load_scenario("paper")
    assert s.with_simulation(step_size=2e-3, stop_time=None).simulation.step_size == 2e-3
    assert s.with_simulation(step_size=2e-3).simulation.stop_time == 30.0
    for bad in (0.0, -1e-3, float("nan"), float("inf")):
        with pytest.raises(ScenarioError, match="step_size"):
            s.with_simulation(step_size=bad)


def test_choices_are_given_by_name(tmp_path):
    s = load_scenario(write(tmp_path, "[controller]\ndiscretization = 'euler'\n[reference]\nprofile = 'figure_eight'\n"))
    assert s.controller["discretization"] == 1 and s.reference["profile"] == 1


def test_coupling_is_a_simulation_setting_that_sets_the_fmus_parameters(tmp_path):
    scenario = load_scenario("paper")
    assert scenario.simulation.coupling == "hold"
    assert {name: scenario.parameters(name).get("coupling") for name in FMUS} == {
        "ReferenceRobot": None, "MobileRobot": 0, "DSCController": 0}
    for order, controller in (("gauss-seidel", 2), ("jacobi", 1)):  # interpolate, extrapolate
        linear = scenario.with_simulation(coupling="linear", order=order)
        assert (linear.parameters("MobileRobot")["coupling"], linear.parameters("DSCController")["coupling"]) == (
            1, controller)
    with pytest.raises(ScenarioError, match=r"coupling = 'cubic' is not allowed; allowed: hold, linear"):
        scenario.with_simulation(coupling="cubic")
    path = tmp_path / "own.toml"
    path.write_text("[plant]\ncoupling = 1\n")
    with pytest.raises(ScenarioError, match=r"\[plant\] coupling is not set here; allowed: \[simulation\] coupling"):
        load_scenario(path)
