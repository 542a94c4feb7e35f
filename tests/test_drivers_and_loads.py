"""The plant's motor drivers and disturbance torques (docs/model.md §1, §5.14): equation (2) with a known load
against an independent numpy solution, in the model and through the FMUs' model exchange; the applied voltages
against numpy.clip at every communication point, with the count and time of the limit from the recorded series;
the drivers' switches held between events and their events in model exchange; the derivatives through a limited
and a free input; FMI 2.0 and 3.0."""

import dataclasses
import math

import numpy as np
import pytest

from dsc_fmu.cosim.master import cosimulate
from dsc_fmu.cosim.model_exchange import simulate_model_exchange
from dsc_fmu.cosim.reference_solution import reference_solution
from dsc_fmu.fmu.robot_models import MobileRobotModel
from dsc_fmu.models import parameters as P
from dsc_fmu.models.plant import applied_voltages, plant_coefficients, saturation_indicators
from dsc_fmu.scenario import load_scenario
from in_process import InProcess
from test_directional_derivatives import _assert_differences, _jacobian, _knowns, _unknowns
from test_model_exchange import Model, model  # noqa: F401 (fixture)

PLANT = P.defaults(P.PLANT_PARAMETERS)
U_MAX = 200.0  # V: clips the paper's start (its peak is 399 V, docs/model.md §6)
LIMIT = {"voltage_limit": 1, "u_max1": U_MAX, "u_max2": U_MAX}
LOADS = {
    "constant": {"tau_dc1": 3.0, "tau_dc2": -1.5},
    "sinusoid": {"tau_da1": 2.0, "f_d1": 0.7, "phi_d1": 0.3, "tau_da2": 4.0, "f_d2": 1.3, "phi_d2": -1.1},
    "constant and sinusoid": {"tau_dc1": -2.0, "tau_da1": 1.0, "f_d1": 0.25, "tau_dc2": 5.0, "tau_da2": 0.5,
                              "f_d2": 2.0, "phi_d2": 2.0},
}
STATE = [0.3, -0.2, 0.8, 4.0, 3.1, 2.5, 1.7]  # x, y, theta, omega1, omega2, i1, i2
TIMES = (0.0, 0.37, 2.9)


def _wheel_accelerations(p: dict, t: float, x: list) -> np.ndarray:
    """``z_dot`` of (2) with the load, ``M z_dot + C z + D z = tau - tau_d``, solved by numpy from the physical
    parameters (docs/model.md §1), independently of models/plant.py."""
    r, R, d, mc, mw = p["r"], p["R"], p["d"], p["mc"], p["mw"]
    m, inertia = mc + 2 * mw, mc * d ** 2 + 2 * mw * R ** 2 + p["Ic"] + 2 * p["Im"]
    k = r ** 2 / (4 * R ** 2)
    M = np.array([[k * (m * R ** 2 + inertia) + p["Iw"], k * (m * R ** 2 - inertia)],
                  [k * (m * R ** 2 - inertia), k * (m * R ** 2 + inertia) + p["Iw"]]])
    z = np.array(x[3:5])
    heading_rate = r / (2 * R) * (z[0] - z[1])
    C = r ** 2 * mc * d / (2 * R) * np.array([[0.0, heading_rate], [-heading_rate, 0.0]])
    D = np.diag([p["d11"], p["d22"]])
    tau = np.array([p["N1"] * p["KT1"] * x[5], p["N2"] * p["KT2"] * x[6]])
    tau_d = np.array([p[f"tau_dc{j}"] + p[f"tau_da{j}"] * np.sin(2 * np.pi * p[f"f_d{j}"] * t + p[f"phi_d{j}"])
                      for j in (1, 2)])
    return np.linalg.solve(M, tau - C @ z - D @ z - tau_d)


def _model(**parameters) -> MobileRobotModel:
    plant = MobileRobotModel()
    plant.p.update(parameters)
    return plant


@pytest.mark.parametrize("t", TIMES)
@pytest.mark.parametrize("case", LOADS)
def test_the_load_enters_2_as_written(case, t):
    """The wheels' rows are M^-1 (N KT ia - C z - D z - tau_d(t)); every other row is the undisturbed plant's."""
    disturbed, undisturbed = _model(**LOADS[case]), _model()
    u = [40.0, -25.0]
    rates, plain = disturbed.rates(t, STATE, u), undisturbed.rates(t, STATE, u)
    assert rates[3:5] == pytest.approx(_wheel_accelerations({**PLANT, **LOADS[case]}, t, STATE), rel=1e-12)
    assert rates[:3] + rates[5:] == plain[:3] + plain[5:]
    assert plain[3:5] == pytest.approx(_wheel_accelerations(PLANT, t, STATE), rel=1e-12)


@pytest.mark.parametrize("case", LOADS)
def test_the_fmus_derivatives_carry_the_load(model, case):
    """Model exchange through the binary (FMI 2.0 and 3.0): the derivatives at a set time and state."""
    instance = model("MobileRobot")
    instance.set(LOADS[case])
    instance.set({"u1": 40.0, "u2": -25.0})
    instance.start()
    for t in TIMES:
        instance.fmu.setTime(t)
        instance.states(STATE)
        assert instance.derivatives()[3:5] == pytest.approx(
            _wheel_accelerations({**PLANT, **LOADS[case]}, t, STATE), rel=1e-12)
    instance.close()


def test_a_zero_load_and_no_limit_leave_the_equations_as_they_were():
    """A load whose constant and amplitude are 0 is none, whatever its frequency and phase; a limit that does not act
    applies u itself: the rates are bit for bit those of the plant without them."""
    assert plant_coefficients(PLANT).loads is None and plant_coefficients(PLANT).u_max is None
    quiet = _model(f_d1=3.0, phi_d1=1.0, phi_d2=-2.0, f_d2=0.1, **LIMIT)
    assert quiet.constants.loads is None
    u = [U_MAX - 1e-9, -U_MAX + 1e-9]
    for t in TIMES:
        assert quiet.rates(t, STATE, u) == _model().rates(t, STATE, u)


def test_the_applied_voltages_are_clip():
    k = plant_coefficients({**PLANT, **LIMIT, "u_max2": 120.0})
    values = [-500.0, -200.0, -199.9, -120.0, -0.0, 0.0, 37.5, 120.0, 120.1, 200.0, 200.1, 1e6]
    for u1 in values:
        for u2 in values:
            assert applied_voltages(k, u1, u2) == (np.clip(u1, -200.0, 200.0), np.clip(u2, -120.0, 120.0))
            indicators = saturation_indicators(k, u1, u2)
            assert [value < 0 for value in indicators] == [u1 > 200.0, u1 < -200.0, u2 > 120.0, u2 < -120.0]
    assert applied_voltages(plant_coefficients(PLANT), 1e6, -1e6) == (1e6, -1e6)
    assert saturation_indicators(plant_coefficients(PLANT), 1e6, -1e6) == [1.0] * 4


def _limited_paper(**settings):
    scenario = load_scenario("paper").with_simulation(**settings)
    return dataclasses.replace(scenario, plant={**scenario.plant, **LIMIT})


@pytest.mark.parametrize("order, coupling", [("gauss-seidel", "hold"), ("jacobi", "linear")])
@pytest.mark.parametrize("version", (2, 3))
def test_the_applied_voltages_are_clip_of_u_at_every_step(fmu_paths, fmu3_paths, version, order, coupling):
    """The paper's start with u_max = 200 V, a row at every step: the plant's u1_applied, u2_applied equal
    numpy.clip of the controller's u1, u2 at every communication point; with held inputs, saturation_time is
    the step times the steps whose u was beyond the limit, saturation_count the runs of such steps."""
    h = 1e-3
    scenario = _limited_paper(stop_time=4.0, output_interval=h, order=order, coupling=coupling)
    result = cosimulate(scenario, fmu_paths if version == 2 else fmu3_paths).result
    for j in (1, 2):
        assert np.array_equal(result[f"u{j}_applied"], np.clip(result[f"u{j}"], -U_MAX, U_MAX))
    limited = (np.abs(result["u1"]) > U_MAX) | (np.abs(result["u2"]) > U_MAX)
    assert 100 < limited.sum() < len(limited) // 2  # the limit acts, and not throughout
    if coupling == "hold":  # step k holds the u of row k; its share shows from row k + 1 on
        steps = np.concatenate([[0], np.cumsum(limited[:-1])])
        np.testing.assert_allclose(result["saturation_time"], h * steps, rtol=1e-12, atol=1e-15)
        begins = limited & ~np.concatenate([[False], limited[:-1]])
        assert np.array_equal(result["saturation_count"], np.concatenate([[0], np.cumsum(begins[:-1])]))
    else:  # the inputs ramp: each onset and release within a step
        assert result["saturation_time"][-1] == pytest.approx(h * limited.sum(), abs=4 * h)
        assert result["saturation_count"][-1] >= 1


@pytest.mark.parametrize("version", (2, 3))
def test_model_exchange_with_the_limit_is_the_reference_and_co_simulation(fmu_paths, fmu3_paths, version):
    """The events at the indicators' roots engage and release the limit where the reference solution's roots
    are: the same count, the same time, the same path; co-simulation converges to it at first order in the step
    (the zero-order hold of u: 2.4 mm at 0.1 ms, ten times that at 1 ms)."""
    scenario = _limited_paper(stop_time=4.0, output_interval=0.01)
    paths = fmu_paths if version == 2 else fmu3_paths
    run = simulate_model_exchange(scenario, paths, tolerance=1e-9)
    me, ref = run.result, reference_solution(scenario)
    cs, coarse = (cosimulate(scenario.with_simulation(step_size=h), paths).result for h in (1e-4, 1e-3))
    assert ref["saturation_count"][-1] >= 1 and run.settings["events"] >= 2 * ref["saturation_count"][-1]
    assert np.array_equal(me["saturation_count"], ref["saturation_count"])
    np.testing.assert_allclose(me["saturation_time"], ref["saturation_time"], atol=1e-6)
    for j in (1, 2):
        assert np.array_equal(me[f"u{j}_applied"], np.clip(me[f"u{j}"], -U_MAX, U_MAX))
    assert np.max(np.hypot(me["x"] - ref["x"], me["y"] - ref["y"])) < 1e-5
    fine, rough = (np.max(np.hypot(me["x"] - r["x"], me["y"] - r["y"])) for r in (cs, coarse))
    assert fine < 3e-3 and 8 < rough / fine < 12
    assert cs["saturation_time"][-1] == pytest.approx(ref["saturation_time"][-1], abs=2e-3)


def _drive(instance: Model, u1: float, t: float) -> dict:
    instance.fmu.setTime(t)
    instance.set({"u1": u1})
    refs = [instance.refs[n] for n in ("saturation_active", "saturation_count")]
    active, count = instance.fmu.getBoolean(refs[:1])[0], instance.loaded.get_integers(refs[1:])[0]
    return {**instance.get(["u1_applied", "saturation_time", "u1_upper_indicator", "u1_lower_indicator"]),
            "der(i1)": instance.derivatives()[5], "active": bool(active), "count": count}


def test_the_limit_changes_only_at_events(model):
    """In continuous-time mode the drivers' switches stay as chosen at the last event while u1 crosses +-u_max1;
    the indicator shows the crossing; the event switches, counts and times it (docs/model.md §5.13, §5.14)."""
    instance = model("MobileRobot")
    instance.loaded.set_integers([instance.refs["voltage_limit"]], [1])
    instance.set({"u_max1": U_MAX, "u_max2": U_MAX, "u1": 150.0})
    instance.start()
    x = instance.vector("getContinuousStates")
    La, Ra = PLANT["La1"], PLANT["Ra1"]

    def der_i1(u):
        return (u - Ra * x[5] - PLANT["N1"] * PLANT["KE1"] * x[3]) / La

    free = _drive(instance, 150.0, 1.0)
    assert free["u1_upper_indicator"] == U_MAX - 150.0 and not free["active"] and free["count"] == 0
    crossed = _drive(instance, 230.0, 1.5)  # beyond the limit, no event yet: still free
    assert crossed["u1_upper_indicator"] < 0 and crossed["u1_applied"] == 230.0 and not crossed["active"]
    assert crossed["der(i1)"] == pytest.approx(der_i1(230.0), rel=1e-14)
    instance.event()
    held = _drive(instance, 230.0, 1.5)
    assert (held["u1_applied"], held["active"], held["count"]) == (U_MAX, True, 1)
    assert held["der(i1)"] == pytest.approx(der_i1(U_MAX), rel=1e-14)
    back = _drive(instance, 120.0, 2.25)  # below again, no event: still limited, the time running
    assert back["u1_upper_indicator"] > 0 and back["u1_applied"] == U_MAX
    assert back["saturation_time"] == pytest.approx(0.75, rel=1e-12)
    instance.event()
    released = _drive(instance, 120.0, 2.5)
    assert (released["u1_applied"], released["active"], released["count"]) == (120.0, False, 1)
    assert released["saturation_time"] == pytest.approx(0.75, rel=1e-12)
    low = _drive(instance, -260.0, 3.0)
    assert low["u1_lower_indicator"] < 0 < low["u1_upper_indicator"]
    instance.event()
    assert _drive(instance, -260.0, 3.0)["u1_applied"] == -U_MAX
    assert _drive(instance, -260.0, 3.0)["count"] == 2
    instance.close()


def _plant(version: int, model_exchange: bool, u1: float, u2: float, limit: bool) -> InProcess:
    inst = InProcess("MobileRobot", version).initialize({"u_max1": U_MAX, "u_max2": U_MAX},
                                                        {"voltage_limit": int(limit)})
    inst.set(["u1", "u2"], [u1, u2])
    if model_exchange:
        inst.slave.set_point(0.8, STATE)
        inst.slave.start_continuous_time()
    return inst


@pytest.mark.parametrize("model_exchange", (True, False), ids=("ME", "CS"))
@pytest.mark.parametrize("version", (2, 3))
def test_derivatives_through_a_limited_input_are_zero_and_through_a_free_one_unchanged(version, model_exchange):
    """u1 = 250 V beyond the limit, u2 = 60 V within it: every entry by u1 is 0, every other entry is the
    plant's without the limit, and all agree with central differences of the slave's values (the held switch
    in model exchange: the differences do not leave it)."""
    limited = _plant(version, model_exchange, 250.0, 60.0, True)
    plain = _plant(version, model_exchange, 250.0, 60.0, False)
    unknowns, knowns = _unknowns(limited, model_exchange), _knowns(limited, model_exchange)
    jacobian = _jacobian(limited, unknowns, knowns, model_exchange)
    expected = _jacobian(plain, unknowns, knowns, model_exchange)
    column = knowns.index("u1")
    assert [row[column] for row in jacobian] == [0.0] * len(unknowns)
    others = [[row[:column] + row[column + 1:] for row in rows] for rows in (jacobian, expected)]
    assert others[0] == others[1]
    assert expected[unknowns.index("u1_applied")][column] == 1.0
    _assert_differences(limited, jacobian, unknowns, knowns)
    if model_exchange:
        assert expected[unknowns.index("der(i1)")][column] == pytest.approx(1.0 / PLANT["La1"], rel=1e-15)


def test_an_fmu_state_restores_the_drivers_switches_and_counts():
    inst = _plant(2, True, 250.0, 60.0, True)
    saved = inst.get_state()
    other = _plant(2, True, 10.0, 60.0, True)
    other.set_state(saved)
    assert other.slave.model.held == (1, 0) and other.slave.model.saturation_count == 1
    assert other.slave.model._limited_since == 0.8
    assert math.isclose(other.get1("u1_applied"), U_MAX)


def test_model_structure_declares_what_the_limit_reaches(fmu_paths):
    """With the drivers limited, ``der(i1)`` and ``u1_applied`` are ``u_max1``'s (and only the first motor's):
    the dependencies found with the switches held high, declared in ModelStructure's InitialUnknowns (FMI 2.0)."""
    from fmpy import read_model_description

    md = read_model_description(str(fmu_paths["MobileRobot"]))
    unknowns = {unknown.variable.name: {v.name for v in unknown.dependencies} for unknown in md.initialUnknowns
                if unknown.dependencies is not None}  # the discrete outputs declare none
    for motor, other in ((1, 2), (2, 1)):
        for name in (f"der(i{motor})", f"u{motor}_applied"):
            assert f"u_max{motor}" in unknowns[name] and f"u_max{other}" not in unknowns[name], name
    assert not any(name.startswith("u_max") for name in unknowns["der(x)"] | unknowns["x"])
