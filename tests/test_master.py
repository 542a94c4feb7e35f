"""The co-simulation master: time stamps, coupling, orders, divergence, failures and cleanup."""

import math
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from fmpy.util import read_csv, write_csv

from dsc_fmu.cosim import signals
from dsc_fmu.cosim.loop import step_count
from dsc_fmu.cosim.master import CosimulationError, cosimulate
from dsc_fmu.scenario import ScenarioError, load_scenario

ORDERS = ("gauss-seidel", "jacobi")


@pytest.fixture(scope="module")
def paper():
    return load_scenario("paper")


def circle(reference: dict, t):
    """The constant-profile reference robot (9) in closed form: a circle of radius vr/wr."""
    x0, y0, th0, vr, wr = (reference[k] for k in ("x0", "y0", "theta0", "vr0", "wr0"))
    theta = th0 + wr * t
    return x0 + vr / wr * (np.sin(theta) - np.sin(th0)), y0 - vr / wr * (np.cos(theta) - np.cos(th0)), theta


@pytest.mark.parametrize(("stop", "h", "n"), [
    (1.0, 1e-3, 1000), (1.1, 0.1, 11), (0.7, 0.1, 7), (1.0037, 0.01, 101), (0.004, 0.01, 1), (30.0, 1e-3, 30000),
])
def test_step_count_is_ceil_with_tolerance(stop, h, n):
    assert step_count(stop, h) == n


@pytest.mark.parametrize("order", ORDERS)
def test_shorter_last_step_ends_exactly_at_stop_time(paper, fmu_paths, order):
    stop, h = 1.0037, 0.01
    run = cosimulate(paper, fmu_paths, step_size=h, stop_time=stop, order=order, output_interval=0.05)
    r = run.result
    assert run.steps == 101
    assert r["time"][-1] == stop
    np.testing.assert_allclose(r["time"][:-1], np.arange(21) * 0.05, rtol=0, atol=1e-12)
    # The reference robot integrates its own state: its pose stamps each row with the time it reached.
    x_r, y_r, theta_r = circle(paper.reference, r["time"])
    np.testing.assert_allclose(r["x_r"], x_r, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r["y_r"], y_r, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r["theta_r"], theta_r, rtol=0, atol=1e-9)


def test_a_multiple_of_the_step_up_to_rounding_takes_no_extra_step(paper, fmu_paths):
    run = cosimulate(paper, fmu_paths, step_size=0.1, stop_time=1.1, output_interval=0.1)
    assert run.steps == 11
    np.testing.assert_allclose(run.result["time"], np.arange(12) * 0.1, rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.result["x_r"][-1], circle(paper.reference, 1.1)[0], rtol=0, atol=1e-9)


@pytest.mark.parametrize(("h", "interval", "every"), [(1e-3, 0.05, 50), (2e-3, 0.01, 5), (1e-2, 1e-3, 1)])
def test_time_column_is_every_output_interval(paper, fmu_paths, h, interval, every):
    stop = 0.5
    run = cosimulate(paper, fmu_paths, step_size=h, stop_time=stop, output_interval=interval)
    expected = np.arange(0, round(stop / h) + 1, every) * h
    np.testing.assert_allclose(run.result["time"], expected, rtol=0, atol=1e-12)
    assert run.result.dtype == signals.DTYPE
    assert run.settings == {"scenario": "paper", "interface": "co-simulation", "step_size": h, "order": "gauss-seidel",
                            "coupling": "hold", "coupling_order": 1, "stop_time": stop, "tolerance": None,
                            "output_interval": interval, "input_derivatives": False}


@pytest.mark.parametrize("order", ORDERS)
def test_controller_sees_the_recorded_measurements(paper, fmu_paths, order):
    """S11, S12, S13 and beta are functions of the controller's inputs (10), (12), (14): computed
    from the recorded plant and reference outputs they must equal the controller's outputs."""
    r = cosimulate(paper, fmu_paths, stop_time=1.0, order=order, output_interval=0.01).result
    k1 = paper.controller["k1"]
    ex, ey = r["x_r"] - r["x"], r["y_r"] - r["y"]
    S11 = np.cos(r["theta"]) * ex + np.sin(r["theta"]) * ey
    S12 = -np.sin(r["theta"]) * ex + np.cos(r["theta"]) * ey
    S13 = [math.remainder(d, 2 * math.pi) for d in r["theta_r"] - r["theta"]] + np.arctan(k1 * S12 * r["v_r"])
    beta = 1 + k1 * r["v_r"] * S11 / (1 + (k1 * S12 * r["v_r"]) ** 2)
    for name, value in (("S11", S11), ("S12", S12), ("S13", S13), ("beta", beta)):
        np.testing.assert_allclose(r[name], value, rtol=0, atol=1e-12, err_msg=name)


@pytest.mark.parametrize("order", ORDERS)
def test_plant_holds_the_recorded_voltage_over_each_step(paper, fmu_paths, order):
    """Motor equation (5) over [t_k, t_k+1] with u held: La di/dt + Ra i + N KE omega = u_k, by the
    midpoint rule (error O(h^2)); the neighbouring voltages u_{k-1}, u_{k+1} fit an order worse."""
    h = 1e-3
    r = cosimulate(paper, fmu_paths, step_size=h, stop_time=0.5, order=order, output_interval=h).result
    p = paper.plant
    for wheel in (1, 2):
        i, omega, u = r[f"i{wheel}"], r[f"omega{wheel}"], r[f"u{wheel}"]
        applied = (p[f"La{wheel}"] * np.diff(i) / h + p[f"Ra{wheel}"] * (i[1:] + i[:-1]) / 2
                   + p[f"N{wheel}"] * p[f"KE{wheel}"] * (omega[1:] + omega[:-1]) / 2)
        held = np.abs(applied - u[:-1]).max()
        assert held < 0.1 * np.abs(applied[:-1] - u[2:]).max()
        assert held < 0.1 * np.abs(applied[1:] - u[:-2]).max()


def test_orders_differ_by_first_order_in_the_step(paper, fmu_paths):
    def gap(h):
        runs = [cosimulate(paper, fmu_paths, step_size=h, stop_time=1.0, order=o, output_interval=0.01).result
                for o in ORDERS]
        return np.array([np.abs(runs[0][c] - runs[1][c]).max() for c in ("x", "y", "theta", "i1", "a1_hat")])

    coarse, fine = gap(2e-3), gap(1e-3)
    assert np.all(fine > 0)
    np.testing.assert_allclose(coarse / fine, 2.0, rtol=0.25)
    assert fine[:2].max() < 1e-3  # m: the two orders agree closely at h = 1 ms


def test_result_round_trips_through_fmpy_csv(paper, fmu_paths, tmp_path):
    r = cosimulate(paper, fmu_paths, step_size=0.01, stop_time=0.2, output_interval=0.05).result
    write_csv(tmp_path / "r.csv", r)
    back = read_csv(tmp_path / "r.csv")
    assert back.dtype.names == signals.COLUMNS
    for name in signals.COLUMNS:
        np.testing.assert_array_equal(back[name], r[name], err_msg=name)


def test_divergence_names_time_signal_value_and_keeps_the_rows(paper, fmu_paths):
    """Run unbounded, then with a bound the run crosses: the error must point at the first
    exchange where a checked signal leaves the bound, in checking order, and keep the rows before."""
    h = 1e-3
    free = cosimulate(paper, fmu_paths, step_size=h, stop_time=1.0, output_interval=h).result
    checked = [("MobileRobot", n) for n in ("x", "y", "theta", "theta_dot", "omega1", "omega2", "i1", "i2")]
    checked += [("ReferenceRobot", n) for n in ("x_r", "y_r", "theta_r", "v_r", "omega_r", "v_r_dot")]
    checked += [("DSCController", "u1"), ("DSCController", "u2")]
    largest = [max(abs(free[n][k]) for _, n in checked) for k in range(len(free))]
    bound = 0.5 * (largest[0] + max(largest))  # crossed after the start
    row = next(k for k in range(len(free)) if largest[k] > bound)
    assert row > 0
    fmu, name = next((f, n) for f, n in checked if abs(free[n][row]) > bound)

    with pytest.raises(CosimulationError, match=rf"diverged at t = .* s: {fmu}\.{name} = .* exceeds the bound") as info:
        cosimulate(paper.with_simulation(bound=bound), fmu_paths, step_size=h, stop_time=1.0, output_interval=h)
    error = info.value
    assert error.time == pytest.approx(free["time"][row], abs=1e-12)
    assert (error.signal, error.value) == (f"{fmu}.{name}", free[name][row])
    np.testing.assert_array_equal(error.result, free[:row])


def test_tiny_bound_fails_at_the_start(paper, fmu_paths):
    with pytest.raises(CosimulationError, match=r"diverged at t = 0 s: MobileRobot\.x = 2\.5 exceeds the bound 0\.001"):
        cosimulate(paper.with_simulation(bound=1e-3), fmu_paths, stop_time=1.0)


def test_destabilising_step_raises(paper, fmu_paths):
    with pytest.raises(CosimulationError, match="diverged at t = ") as info:
        cosimulate(paper, fmu_paths, step_size=0.2, stop_time=10.0)
    assert info.value.time > 0 and len(info.value.result) > 0
    assert not math.isfinite(info.value.value) or abs(info.value.value) > paper.simulation.bound


def test_failing_fmi_call_names_the_fmu_and_its_log(paper, fmu_paths):
    """With no effective bound the plant's state overflows; its doStep fails and logs why."""
    with pytest.raises(CosimulationError, match=r"MobileRobot failed at t = .* s: fmi2DoStep .*not finite") as info:
        cosimulate(paper.with_simulation(bound=1e300), fmu_paths, step_size=0.1, stop_time=10.0)
    error = info.value
    assert error.signal is None and len(error.result) > 0 and error.fmu == "MobileRobot"
    assert np.all(error.result["time"] <= error.time)
    assert error.steps == round(error.time / 0.1)  # the steps completed before the failing one


def test_a_failing_fmi3_call_names_its_fmu_too(paper, fmu3_paths):
    with pytest.raises(CosimulationError, match=r"MobileRobot failed at t = .* s: fmi3DoStep ") as info:
        cosimulate(paper.with_simulation(bound=1e300), fmu3_paths, step_size=0.1, stop_time=10.0)
    assert info.value.fmu == "MobileRobot"


@pytest.mark.parametrize("setting", [
    {"step_size": 0.0}, {"step_size": -1e-3}, {"step_size": math.nan}, {"stop_time": 0.0},
    {"output_interval": -0.1}, {"order": "bogus"},
])
def test_bad_settings_raise_scenario_error(paper, fmu_paths, setting, tmp_path):
    with pytest.raises(ScenarioError, match=next(iter(setting))):
        cosimulate(paper, fmu_paths, workdir=tmp_path, **setting)
    assert list(tmp_path.iterdir()) == []


def test_missing_fmu_is_reported(paper, fmu_paths, tmp_path):
    paths = {**fmu_paths, "MobileRobot": tmp_path / "nowhere.fmu"}
    with pytest.raises(FileNotFoundError, match="MobileRobot"):
        cosimulate(paper, paths, stop_time=0.1)


@pytest.fixture
def removed(monkeypatch):
    """The folders the master removes, recorded as it removes them."""
    folders = []
    rmtree = shutil.rmtree

    def recording(path, **kwargs):
        folders.append(path)
        rmtree(path, **kwargs)

    monkeypatch.setattr(shutil, "rmtree", recording)
    return folders


@pytest.mark.parametrize(("h", "bound", "fails"), [(0.01, 1e6, False), (0.01, 1e-3, True), (0.1, 1e300, True)],
                         ids=["normal", "diverging", "fmu-failure"])
def test_extracted_folders_are_removed(paper, fmu_paths, tmp_path, removed, h, bound, fails):
    scenario = paper.with_simulation(bound=bound)
    try:
        cosimulate(scenario, fmu_paths, step_size=h, stop_time=3.0, workdir=tmp_path)
    except CosimulationError:
        assert fails
    else:
        assert not fails
    assert len(removed) == 3 and all(str(folder).startswith(str(tmp_path)) for folder in removed)
    assert list(tmp_path.iterdir()) == []


def test_default_extraction_goes_to_the_temp_folder_and_is_removed(paper, fmu_paths, tmp_path, monkeypatch, removed):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    cosimulate(paper, fmu_paths, step_size=0.1, stop_time=0.5)
    assert len(removed) == 3
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_paper_scenario_converges(paper, fmu_paths):
    """docs/model.md §6: the error settles to centimetres by the last third of the paper's 30 s run."""
    run = cosimulate(paper, fmu_paths)
    r = run.result
    assert run.steps == 30000 and r["time"][-1] == 30.0
    late = r["time"] >= 20.0
    assert r["position_error"][late].max() < 0.1
    assert np.abs(r["thetae"][late]).max() < 0.05


def test_a_file_that_is_not_an_fmu_is_reported(paper, fmu_paths, tmp_path, removed):
    (tmp_path / "broken.fmu").write_text("not a zip archive")
    paths = {**fmu_paths, "DSCController": tmp_path / "broken.fmu"}
    with pytest.raises(CosimulationError, match=r"broken\.fmu: not a valid FMU for DSCController"):
        cosimulate(paper, paths, stop_time=0.1, workdir=tmp_path)
    # the two FMUs loaded before it are removed; the broken one was never extracted
    assert len(removed) == 2 and sorted(p.name for p in tmp_path.iterdir()) == ["broken.fmu"]


def test_swapped_fmus_are_reported(paper, fmu_paths):
    paths = {**fmu_paths, "DSCController": fmu_paths["MobileRobot"]}
    with pytest.raises(CosimulationError, match="DSCController has no variable"):
        cosimulate(paper, paths, stop_time=0.1)


def test_a_relative_work_folder_is_fine(fmu_paths, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "work").mkdir()
    run = cosimulate(load_scenario("paper"), fmu_paths, stop_time=0.01, workdir=Path("work"))
    assert run.steps == 10 and not any((tmp_path / "work").iterdir())
