"""The error-controlled communication step: honest against the reference solution, exact where the
step is fixed, one clear error where h_min cannot meet the tolerance."""

import dataclasses
import json

import numpy as np
import pytest

from dsc_fmu.cli import main
from dsc_fmu.cosim import loop
from dsc_fmu.cosim.master import CosimulationError, Cosimulator
from dsc_fmu.cosim.reference_solution import output_times, reference_solution
from dsc_fmu.scenario import ScenarioError, load_scenario

PAPER = load_scenario("paper")


@pytest.fixture(scope="module")
def simulator(fmu_paths):
    with Cosimulator(fmu_paths) as simulator:
        yield simulator


def _deviation(result, reference):
    t = result["time"]
    return np.hypot(result["x"] - np.interp(t, reference["time"], reference["x"]),
                    result["y"] - np.interp(t, reference["time"], reference["y"])).max()


def test_with_one_allowed_step_size_the_controlled_run_is_the_fixed_step_run(simulator):
    """h_min = h_max = h and a tolerance nothing misses: every step accepted, the same rows (to rounding:
    the controlled run's time is the sum of its steps, the fixed run's k h)."""
    h = 2e-3
    scenario = PAPER.with_simulation(stop_time=1.0, step_size=h, output_interval=h, coupling="linear")
    fixed = simulator.run(scenario)
    controlled = simulator.run(dataclasses.replace(scenario, simulation=dataclasses.replace(
        scenario.simulation, tolerance=1e9, h_min=h, h_max=h)))
    assert controlled.rejected == 0 and controlled.steps == fixed.steps == 500
    for name in fixed.result.dtype.names:
        np.testing.assert_allclose(controlled.result[name], fixed.result[name], rtol=1e-9, atol=1e-12, err_msg=name)
    assert controlled.fmu_steps == fixed.fmu_steps == 1500


def test_steps_tile_the_run_within_their_bounds_and_meet_the_tolerance(simulator):
    scenario = PAPER.with_simulation(stop_time=3.0, coupling="linear", tolerance=1e-3)
    run = simulator.run(scenario)
    steps = run.step_sizes
    assert run.rejected > 0  # the start-up transient makes it shrink the step
    np.testing.assert_allclose(steps["time"][1:], steps["time"][:-1] + steps["step_size"][:-1], rtol=0, atol=1e-12)
    assert steps["time"][0] == 0.0 and steps["time"][-1] + steps["step_size"][-1] == pytest.approx(3.0, abs=1e-12)
    settings = scenario.simulation
    assert (steps["step_size"] >= settings.h_min).all()  # the last one too: it takes in a remainder < h_min
    assert (steps["step_size"] <= settings.h_max + settings.h_min).all()
    assert (steps["estimated_error"] <= 1e-3).all()
    np.testing.assert_array_equal(run.result["time"], np.concatenate([[0.0], steps["time"] + steps["step_size"]]))
    assert run.fmu_steps == 3 * (run.steps + run.rejected)


def test_an_h_min_that_cannot_meet_the_tolerance_is_one_error_naming_the_time(simulator):
    scenario = PAPER.with_simulation(stop_time=2.0, coupling="hold", tolerance=1e-6, h_min=1e-3)
    with pytest.raises(CosimulationError, match=r"^the error-controlled step cannot meet the tolerance 1e-06 m at "
                       r"t = [0-9.e-]+ s: the estimated error of a step of h_min = 0\.001 s is .* m; allowed: a "
                       r"smaller h_min or a larger tolerance \(or the linear coupling\)$") as error:
        simulator.run(scenario)
    assert 0.0 <= error.value.time < 2.0 and "\n" not in str(error.value)


def test_steps_of_h_min_that_miss_the_tolerance_end_the_run_wherever_they_start(simulator):
    """At t = 1.9 s the paper's hold coupling needs steps below h_min = 1e-5 s for 1 mm. A step of h_min
    ends at t + h_min, and (t + h_min) - t rounds to a little more than h_min: it still counts as
    h_min, so the run ends with the error instead of trying the same step for ever."""
    scenario = PAPER.with_simulation(stop_time=2.0, coupling="hold", tolerance=1e-3)
    with pytest.raises(CosimulationError, match=r"cannot meet the tolerance 0\.001 m at t = 1\.9.* h_min = 1e-05 s"):
        simulator.run(scenario)


def _replay(simulator, scenario, sizes, monkeypatch):
    """``scenario`` run with exactly the step sizes ``sizes``, every one accepted (no rollback)."""
    following = iter(sizes[1:])
    monkeypatch.setattr(loop, "next_step", lambda *arguments: next(following, 1.0))
    settings = dataclasses.replace(scenario.simulation, tolerance=1e9, step_size=sizes[0])
    run = simulator.run(dataclasses.replace(scenario, simulation=settings))
    monkeypatch.undo()
    return run


@pytest.mark.parametrize("order", ["gauss-seidel", "jacobi"])
def test_rejected_steps_leave_no_trace(simulator, monkeypatch, order):
    """A controlled run with rejections is bit for bit the run that takes its accepted steps directly:
    the rollback through fmi2GetFMUstate/SetFMUstate restores the coupling history too."""
    scenario = PAPER.with_simulation(stop_time=2.0, coupling="linear", order=order, tolerance=1e-3)
    run = simulator.run(scenario)
    assert run.rejected > 0
    again = _replay(simulator, scenario, run.step_sizes["step_size"], monkeypatch)
    assert again.rejected == 0 and again.steps == run.steps
    assert again.result.tobytes() == run.result.tobytes()


def test_a_step_an_fmu_discards_is_taken_again_smaller(simulator, monkeypatch):
    """The plant advances and then discards every step longer than 4 ms (fmi2Discard): each such step
    is taken again, smaller, from the saved states, and the run is the one of its accepted steps."""
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Slave

    do_step, discarded = FMU2Slave.doStep, []

    def discarding(self, t, h, *rest):
        do_step(self, t, h, *rest)
        if self.instanceName == "MobileRobot" and h > 4e-3:
            discarded.append(t)
            raise FMICallException(function="fmi2DoStep", status=2)

    scenario = PAPER.with_simulation(stop_time=2.0, coupling="linear", tolerance=1e-2)
    monkeypatch.setattr(FMU2Slave, "doStep", discarding)
    run = simulator.run(scenario)
    monkeypatch.undo()
    sizes = run.step_sizes["step_size"]
    assert discarded and run.rejected >= len(discarded) and (sizes <= 4e-3).all()
    assert run.fmu_steps == 3 * (run.steps + run.rejected)
    assert _replay(simulator, scenario, sizes, monkeypatch).result.tobytes() == run.result.tobytes()


@pytest.mark.parametrize("settings,message", [
    ({"tolerance": 0.0}, r"tolerance = 0\.0 is not allowed; allowed: > 0"),
    ({"h_min": 0.1, "h_max": 0.01}, r"h_min = 0\.1 is not allowed; allowed: <= h_max = 0\.01"),
    ({"error_gain": -1.0}, r"error_gain = -1\.0 is not allowed; allowed: > 0"),
])
def test_bad_step_control_settings_are_refused(settings, message):
    with pytest.raises(ScenarioError, match=message):
        PAPER.with_simulation(**settings)


def test_run_command_writes_the_step_size_history(tmp_path, fmu_paths, capsys):
    out = tmp_path / "out"
    fmu_dir = next(iter(fmu_paths.values())).parent
    assert main(["run", "--stop-time", "1", "--coupling", "linear", "--tolerance", "1e-3", "--out", str(out),
                 "--fmu-dir", str(fmu_dir)]) == 0
    assert "error-controlled to 0.001 m" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())["settings"]
    assert summary["tolerance"] == 1e-3 and summary["fmu_steps"] == 3 * (summary["steps"] + summary["steps_rejected"])
    header = (out / "step_sizes.csv").read_text().splitlines()[0]
    assert header.replace('"', "") == "time,step_size,estimated_error"
    assert (out / "step_sizes.png").stat().st_size > 0


@pytest.mark.slow
@pytest.mark.parametrize("order", ["gauss-seidel", "jacobi"])
def test_the_estimate_is_honest_against_the_reference_solution(simulator, order):
    """Over the paper's 30 s, the largest deviation from the reference solution is within 3 times the
    tolerance, for tolerances from 1e-2 m to 1e-4 m, with the linear coupling."""
    reference = reference_solution(PAPER, times=output_times(30.0, 1e-3), rtol=1e-10, atol=1e-10, method="DOP853")
    for tolerance in (1e-2, 1e-3, 1e-4):
        run = simulator.run(PAPER.with_simulation(coupling="linear", order=order, tolerance=tolerance))
        assert _deviation(run.result, reference) <= 3 * tolerance, tolerance
