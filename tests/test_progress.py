"""Runs that say what they are doing and stop when asked: a watch ends a run at a row (co-simulation,
error-controlled, model exchange) with the rows a full run has up to there; the command line's
forecast, the coupling ``--tolerance`` picks, and Ctrl-C: exit 130 with the results up to that time
written. The progress line on a real terminal: test_terminal.py."""

import io
import json
import signal
import subprocess
import sys

import numpy as np
import pytest

from dsc_fmu.cli import main
from dsc_fmu.cosim import progress
from dsc_fmu.cosim.master import Cosimulator
from dsc_fmu.cosim.model_exchange import simulate_model_exchange
from dsc_fmu.cosim.progress import TerminalWatch
from dsc_fmu.scenario import load_scenario

PAPER = load_scenario("paper").with_simulation(stop_time=1.0)


@pytest.fixture(scope="module")
def simulator(fmu_paths):
    with Cosimulator(fmu_paths) as simulator:
        yield simulator


def stopping_at(at: float):
    """A watch that stops a run at its first row at or after ``at`` (s), and the calls it saw."""
    seen = []

    def watch(time: float, steps: int) -> bool:
        seen.append((time, steps))
        return time < at

    return watch, seen


@pytest.mark.parametrize("settings", ({}, {"coupling": "linear", "tolerance": 1e-3}), ids=("fixed", "controlled"))
def test_a_watch_ends_a_co_simulation_at_a_row_with_the_rows_of_a_full_run(simulator, settings):
    full = simulator.run(PAPER, **settings)
    watch, seen = stopping_at(0.5)
    stopped = simulator.run(PAPER, watch=watch, **settings)
    rows = len(stopped.result)
    assert full.stopped_at is None and stopped.stopped_at == stopped.result["time"][-1] == seen[-1][0]
    assert 0.5 <= stopped.stopped_at < 0.5 + 0.03
    for name in full.result.dtype.names:
        np.testing.assert_array_equal(stopped.result[name], full.result[name][:rows], err_msg=name)
    assert stopped.steps == seen[-1][1] < full.steps
    assert [time for time, _ in seen] == list(stopped.result["time"][1:])  # once per row after the start


def test_a_watch_ends_model_exchange_where_it_says_stop(fmu_paths):
    full = simulate_model_exchange(PAPER, fmu_paths, tolerance=1e-7)
    watch, seen = stopping_at(0.4)
    stopped = simulate_model_exchange(PAPER, fmu_paths, tolerance=1e-7, watch=watch)
    end = stopped.stopped_at
    assert full.stopped_at is None and end == stopped.result["time"][-1] and 0.4 <= end < 0.41
    assert end == next(time for time, _ in seen if time >= 0.4)  # the evaluation that was told stop
    before = stopped.result["time"] < end
    for name in full.result.dtype.names:  # the same solver steps up to there: the same rows
        np.testing.assert_array_equal(stopped.result[name][before], full.result[name][: before.sum()], err_msg=name)


@pytest.fixture()
def clock(monkeypatch):
    """The watch's wall clock, set by the test."""
    now = [100.0]
    monkeypatch.setattr(progress.clock, "monotonic", lambda: now[0])
    return now


def test_a_long_run_gets_one_forecast_line_and_no_carriage_return_off_a_terminal(clock):
    stream = io.StringIO()
    watch = TerminalWatch(30.0, "paper", hint="--coupling linear is faster", stream=stream)
    assert watch(0.1, 10)
    clock[0] += 3.0  # 3 s for 0.2 s of 30: 450 s in all
    assert watch(0.2, 20)
    clock[0] += 3.0
    assert watch(0.3, 30)
    lines = stream.getvalue().splitlines()
    assert lines == ["dsc-fmu: at this pace the run takes about 3,000 steps and 7.5 min in all (0.2 of 30 s "
                     "simulated in 3 s); --coupling linear is faster"]
    assert "\r" not in stream.getvalue()


def test_quiet_and_short_runs_get_no_forecast(clock):
    for quiet, step in ((True, 3.0), (False, 0.1)):
        stream = io.StringIO()
        watch = TerminalWatch(30.0, "paper", quiet=quiet, stream=stream)
        watch(0.1, 10)
        clock[0] += step
        watch(29.0, 2900)
        assert stream.getvalue() == ""


def test_tolerance_without_coupling_takes_the_linear_coupling_and_says_so(tmp_path, fmu_paths, capsys):
    out = tmp_path / "out"
    fmu_dir = fmu_paths["MobileRobot"].parent
    assert main(["run", "paper", "--stop-time", "1", "--tolerance", "1e-3", "--no-plots", "--out", str(out),
                 "--fmu-dir", str(fmu_dir)]) == 0
    captured = capsys.readouterr()
    assert captured.err.splitlines()[0].startswith("dsc-fmu: --tolerance without --coupling: error control with "
                                                    "the linear coupling")
    settings = json.loads((out / "summary.json").read_text())["settings"]
    assert settings["coupling"] == "linear" and settings["coupling_order"] == 2 and settings["tolerance"] == 1e-3
    # the last step takes in a remainder shorter than h_min
    assert settings["h_min"] <= settings["step_min"] <= settings["step_max"] <= settings["h_max"] + settings["h_min"]
    assert settings["stopped_at"] is None
    assert "coupling of order 2" in captured.out and "\r" not in captured.err


@pytest.mark.slow
def test_ctrl_c_stops_a_run_with_its_results_written_and_exit_130(tmp_path, fmu_paths):
    """``dsc-fmu run`` in a pipe, 300 s of the paper's scenario with h = 1e-4 s (minutes: the forecast
    comes on any machine), Ctrl-C (SIGINT) once it is under way: exit status 130, no traceback, no
    progress line, the summary says where it stopped, and results.csv and summary.json hold the run up
    to there."""
    out = tmp_path / "out"
    command = [sys.executable, "-m", "dsc_fmu", "run", "paper", "--stop-time", "300", "--step-size", "1e-4",
               "--no-plots", "--out", str(out), "--fmu-dir", str(fmu_paths["MobileRobot"].parent)]
    with subprocess.Popen(command, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as run:
        forecast = run.stderr.readline()  # 2 s into the run: it is under way
        run.send_signal(signal.SIGINT)
        stdout, stderr = run.communicate(timeout=120)
    assert forecast.startswith("dsc-fmu: at this pace the run takes about"), forecast + stderr
    assert run.returncode == 130, stderr
    assert "Traceback" not in stderr and "failed" not in stderr and "\r" not in forecast + stderr
    summary = json.loads((out / "summary.json").read_text())
    stopped = summary["settings"]["stopped_at"]
    assert 0 < stopped < 300 and stdout.startswith(f"stopped at t = {stopped:g} s of 300 s (interrupted)")
    rows = np.genfromtxt(out / "results.csv", delimiter=",", names=True)
    assert rows["time"][-1] == pytest.approx(stopped) and summary["settings"]["steps"] == round(stopped / 1e-4)
    assert summary["metrics"]["window_end_s"] == stopped
