"""Tracking metrics on synthetic results with answers known by hand; the written summary."""

import json
import math

import numpy as np
import pytest
from fmpy.util import read_csv

from dsc_fmu.cosim import signals
from dsc_fmu.cosim.master import CosimulationResult
from dsc_fmu.cosim.metrics import settling_time, tracking_metrics
from dsc_fmu.cosim.results import format_summary, write_results
from dsc_fmu.scenario import load_scenario

E0, T = 1.0, 4.0  # m, s: position error E0 exp(-t / T)


def decaying(stop=30.0, rows=3001):
    """A result whose position error decays as E0 exp(-t/T), with thetae = -0.5 exp(-t/T) rad."""
    result = np.zeros(rows, dtype=signals.DTYPE)
    t = np.linspace(0.0, stop, rows)
    result["time"] = t
    result["position_error"] = E0 * np.exp(-t / T)
    result["thetae"] = -0.5 * np.exp(-t / T)
    result["u1"] = 50.0 * np.sin(t)
    result["u2"] = 20.0 * np.cos(t)
    return result


def test_metrics_of_an_exponential_decay():
    m = tracking_metrics(decaying(), 30.0)
    assert (m["window_start_s"], m["window_end_s"]) == (20.0, 30.0)
    assert m["final_position_error_m"] == pytest.approx(E0 * math.exp(-30 / T), rel=1e-12)
    assert m["max_position_error_m"] == pytest.approx(E0 * math.exp(-20 / T), rel=1e-12)
    # RMS over [20, 30] of the continuous decay: E0^2 T / (2 * 10) (exp(-40/T) - exp(-60/T)).
    rms = math.sqrt(E0**2 * T / 20 * (math.exp(-40 / T) - math.exp(-60 / T)))
    assert m["rms_position_error_m"] == pytest.approx(rms, rel=1e-3)
    assert m["max_abs_thetae_rad"] == pytest.approx(0.5 * math.exp(-20 / T), rel=1e-12)
    # Below 0.1 m from t = T ln(E0 / 0.1), reached on the 0.01 s grid at the next row.
    assert m["settling_time_0p1_s"] == pytest.approx(math.ceil(T * math.log(E0 / 0.1) / 0.01) * 0.01, abs=1e-9)
    assert m["max_abs_u_V"] == pytest.approx(50.0, rel=1e-4)
    assert m["beta_guard_count"] == 0
    json.dumps(m)


def test_settling_time_after_the_last_excursion():
    t = np.arange(10.0)
    error = np.array([0.5, 0.05, 0.05, 0.2, 0.05, 0.05, 0.3, 0.01, 0.01, 0.01])
    assert settling_time(t, error, 0.1) == 7.0
    assert settling_time(t, np.full(10, 0.01), 0.1) == 0.0
    assert settling_time(t, np.r_[np.full(9, 0.01), 0.1], 0.1) is None
    assert settling_time(t, np.r_[0.01, np.nan, np.full(8, 0.01)], 0.1) == 2.0


def test_never_settling_run_has_no_settling_time():
    result = decaying()
    result["position_error"] = 0.5
    assert tracking_metrics(result, 30.0)["settling_time_0p1_s"] is None


def test_max_voltage_takes_either_wheel_and_sign():
    result = decaying(stop=3.0, rows=301)
    result["u2"][100] = -700.0
    assert tracking_metrics(result, 3.0)["max_abs_u_V"] == 700.0


def test_window_is_the_last_third_of_the_run():
    result = decaying(stop=9.0, rows=91)
    m = tracking_metrics(result, 9.0)
    assert m["window_start_s"] == 6.0
    assert m["max_position_error_m"] == pytest.approx(E0 * math.exp(-6.0 / T), rel=1e-12)


def test_bad_stop_time_and_empty_window_are_reported():
    with pytest.raises(ValueError, match="stop_time"):
        tracking_metrics(decaying(), 0.0)
    with pytest.raises(ValueError, match="no row"):
        tracking_metrics(decaying(stop=10.0, rows=11), 30.0)


def test_results_and_summary_written(tmp_path):
    scenario = load_scenario("paper")
    result = decaying()
    run = CosimulationResult(
        result=result, steps=30000, wall_time=1.5,
        settings={"scenario": "paper", "interface": "co-simulation", "step_size": 1e-3, "order": "jacobi",
                  "coupling": "linear", "stop_time": 30.0, "output_interval": 0.01, "tolerance": None,
                  "input_derivatives": False},
        fmu_steps=90000,
        fmus={"MobileRobot": {"path": "MobileRobot.fmu", "build_id": "abc"}},
    )
    metrics = tracking_metrics(result, 30.0)
    paths = write_results(tmp_path / "out", run, scenario, metrics)
    back = read_csv(paths["csv"])
    assert back.dtype.names[0] == "time"
    np.testing.assert_array_equal(back["position_error"], result["position_error"])
    summary = json.loads(paths["summary"].read_text())
    assert summary["scenario"] == "paper" and summary["scenario_source"] == scenario.source
    assert summary["settings"] == {"interface": "co-simulation", "step_size": 1e-3, "order": "jacobi", "coupling": "linear",
                                   "input_derivatives": False, "stop_time": 30.0,
                                   "output_interval": 0.01, "tolerance": None, "steps_rejected": 0, "fmu_steps": 90000,
                                   "steps": 30000, "wall_time_s": 1.5, "stopped_at": None}
    assert summary["metrics"] == metrics
    assert summary["units"]["position_error"] == "m" and summary["units"]["u1"] == "V"
    assert summary["fmus"] == {"MobileRobot": "abc"}
    text = format_summary(run, metrics)
    assert "jacobi, linear coupling" in text and "30000 steps" in text and f"{metrics['settling_time_0p1_s']:.4g} s" in text
