"""The command line: the main job's files, and one-line errors with a non-zero exit for bad input."""

import csv
import json
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pytest

from dsc_fmu.cli import main
from dsc_fmu.scenario import load_scenario
from dsc_fmu.cosim.signals import COLUMNS

REPO = Path(__file__).resolve().parents[1]
REQUIRED = (
    "time x y theta x_r y_r theta_r xe ye thetae u1 u2 omega1 omega2 i1 i2 "
    "a1_hat a2_hat W1_hat_norm W2_hat_norm"
).split()


def console_script() -> str:
    """The ``dsc-fmu`` script installed with this Python, whether or not its environment is activated."""
    folders = [sysconfig.get_path("scripts"), sysconfig.get_path("scripts", f"{os.name}_user"), Path(sys.executable).parent]
    for folder in folders:
        script = Path(folder) / ("dsc-fmu.exe" if os.name == "nt" else "dsc-fmu")
        if script.is_file():
            return str(script)
    raise AssertionError(f"dsc-fmu is not installed in any of {folders}")


@pytest.fixture(scope="module")
def fmu_dir(fmu_paths):
    return next(iter(fmu_paths.values())).parent


def test_run_writes_results_summary_and_figures(tmp_path, fmu_dir, capsys):
    out = tmp_path / "out"
    status = main(["run", "paper", "--stop-time", "1.5", "--step-size", "2e-3", "--order", "jacobi",
                   "--output-interval", "0.1", "--out", str(out), "--fmu-dir", str(fmu_dir)])
    assert status == 0
    printed = capsys.readouterr().out
    assert "scenario paper: jacobi, hold coupling, step 0.002 s, stop 1.5 s" in printed
    with open(out / "results.csv") as f:
        rows = list(csv.reader(f))
    header = rows[0]
    assert set(REQUIRED) <= set(header) and header[0] == "time"
    assert header == list(COLUMNS)
    times = np.array([float(r[0]) for r in rows[1:]])
    np.testing.assert_allclose(times, np.arange(16) * 0.1, atol=1e-12)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scenario"] == "paper"
    settings = summary["settings"]
    assert (settings["step_size"], settings["order"], settings["stop_time"], settings["steps"]) == (2e-3, "jacobi", 1.5, 750)
    assert settings["wall_time_s"] > 0
    for key in ("final_position_error_m", "rms_position_error_m", "max_position_error_m", "max_abs_thetae_rad",
                "settling_time_0p1_s", "max_abs_u_V"):
        assert key in summary["metrics"]
    assert summary["units"]["u1"] == "V" and summary["units"]["thetae"] == "rad"
    for figure in ("trajectory.png", "signals.png"):
        assert (out / figure).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_run_without_plots(tmp_path, fmu_dir):
    out = tmp_path / "out"
    assert main(["run", "--stop-time", "0.2", "--no-plots", "--out", str(out), "--fmu-dir", str(fmu_dir)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["results.csv", "summary.json"]


def test_run_takes_the_standard_route_of_the_linear_coupling(tmp_path, fmu_dir):
    """--input-derivatives: the master's slopes through fmi2SetRealInputDerivatives, with Jacobi the
    same rows as the FMUs' coupling parameters."""
    rows = {}
    for route in ([], ["--input-derivatives"]):
        out = tmp_path / ("route" if route else "parameters")
        assert main(["run", "--stop-time", "0.5", "--order", "jacobi", "--coupling", "linear", *route, "--no-plots",
                     "--out", str(out), "--fmu-dir", str(fmu_dir)]) == 0
        rows[bool(route)] = (out / "results.csv").read_text()
    assert rows[True] == rows[False]


def test_run_through_model_exchange_writes_the_same_files(tmp_path, fmu_dir, capsys):
    """--interface model-exchange: the three FMUs as one ODE; the same columns, times and metrics as a
    co-simulation, the summary naming the interface, the solver and its tolerance."""
    out = tmp_path / "me"
    assert main(["run", "paper", "--interface", "model-exchange", "--stop-time", "1", "--tolerance", "1e-7",
                 "--output-interval", "0.1", "--no-plots", "--out", str(out), "--fmu-dir", str(fmu_dir)]) == 0
    printed = capsys.readouterr().out
    assert "scenario paper: model exchange, DOP853 at relative tolerance 1e-07, stop 1 s" in printed
    with open(out / "results.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == list(COLUMNS)
    np.testing.assert_allclose([float(r[0]) for r in rows[1:]], np.arange(11) * 0.1, atol=1e-12)
    settings = json.loads((out / "summary.json").read_text())["settings"]
    assert (settings["interface"], settings["method"], settings["tolerance"], settings["events"]) == (
        "model-exchange", "DOP853", 1e-7, 0)
    assert settings["steps"] > 0


@pytest.mark.parametrize("option, stability, reference", [
    ([], "local", "monolithic"), (["--stability", "settled", "--reference", "model-exchange"], "settled", "model-exchange"),
])
def test_sweep_judges_by_the_scenarios_stability_unless_told(tmp_path, fmu_dir, option, stability, reference):
    from dsc_fmu.study.rows import stability_definition
    out = tmp_path / "sweep"
    assert main(["sweep", "on_reference", *option, "--stop-time", "3", "--step-sizes", "0.01", "--orders",
                 "gauss-seidel", "--couplings", "hold", "--tolerances", "", "--no-refine", "--jobs", "1",
                 "--out", str(out), "--fmu-dir", str(fmu_dir)]) == 0
    summary = json.loads((out / "sweep.json").read_text())
    assert summary["settings"]["stability"] == stability
    assert summary["settings"]["reference"] == reference
    assert summary["stability_definition"] == stability_definition(stability)
    with open(out / "sweep.csv") as file:
        assert [(row["stability"], row["stable"]) for row in csv.DictReader(file)] == [(stability, "True")]


BAD_SCENARIO = "[plant]\nmc = -30.0\n"


@pytest.mark.parametrize(
    "arguments, message",
    [
        (["run", "--step-size", "0"], "step_size = 0.0 is not allowed; allowed: > 0"),
        (["run", "--step-size=-1e-3"], "step_size = -0.001 is not allowed"),
        (["run", "--stop-time=-5"], "stop_time = -5.0 is not allowed"),
        (["run", "--output-interval", "nan"], "output_interval = nan is not allowed"),
        (["run", "no_such_scenario"], "unknown scenario 'no_such_scenario'; allowed:"),
        (["run", "{bad}"], "[plant] mc = -30.0 is not allowed: it must be > 0"),
        (["run", "{missing}"], "scenario file not found"),
        (["run", "--input-derivatives"], "input_derivatives = true realises the linear coupling at a fixed step"),
        (["run", "--interface", "model-exchange", "--step-size", "1e-3"],
         "--step-size is a co-simulation setting; allowed with --interface model-exchange: --tolerance"),
        (["run", "--interface", "model-exchange", "--tolerance", "0"], "tolerance = 0.0 is not allowed"),
    ],
)
def test_bad_input_gives_one_line_and_writes_nothing(tmp_path, capsys, arguments, message):
    bad = tmp_path / "bad.toml"
    bad.write_text(BAD_SCENARIO)
    arguments = [a.format(bad=bad, missing=tmp_path / "missing.toml") for a in arguments]
    out = tmp_path / "out"
    status = main([*arguments, "--out", str(out), "--fmu-dir", str(tmp_path / "fmus")])
    captured = capsys.readouterr()
    assert status == 1
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("dsc-fmu: error: ")
    assert message in lines[0]
    assert captured.out == ""
    assert not out.exists() and not (tmp_path / "fmus").exists()


def test_bad_order_is_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["run", "--order", "random"])
    assert exit_.value.code == 2
    assert "invalid choice: 'random'" in capsys.readouterr().err


@pytest.mark.parametrize("command", [[console_script()], [sys.executable, "-m", "dsc_fmu"]], ids=["script", "module"])
def test_console_script_error_has_no_traceback(tmp_path, command):
    """``dsc-fmu`` and ``python -m dsc_fmu``, run with an environment that is not activated (PATH without it)."""
    env = {key: value for key, value in os.environ.items() if key != "VIRTUAL_ENV"}
    env["PATH"] = "/usr/bin:/bin"
    process = subprocess.run([*command, "run", "--step-size", "0"], capture_output=True, text=True, cwd=tmp_path, env=env)
    assert process.returncode == 1
    assert "Traceback" not in process.stderr
    assert process.stderr.strip() == (
        f"dsc-fmu: error: {load_scenario('paper').source}"
        + ": [simulation] step_size = 0.0 is not allowed; allowed: > 0"
    )


def test_build_command(tmp_path, capsys):
    assert main(["build", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out.split()
    assert sorted(printed) == sorted(str(tmp_path / f"{n}.fmu") for n in ("ReferenceRobot", "MobileRobot", "DSCController"))


def test_scenarios_command_lists_the_shipped_ones(capsys):
    assert main(["scenarios"]) == 0
    names = [line.split(":")[0] for line in capsys.readouterr().out.splitlines()]
    assert {"paper", "figure_eight", "ahead_start"} <= set(names)


def test_build_fmus_script(tmp_path):
    script = REPO / "build_fmus.py"
    process = subprocess.run([sys.executable, str(script), "--out", str(tmp_path)], capture_output=True, text=True)
    assert process.returncode == 0, process.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["DSCController.fmu", "MobileRobot.fmu", "ReferenceRobot.fmu"]


@pytest.mark.parametrize("command, suffix", [("export-ssp", ".ssp"), ("export-fmu", ".fmu")])
def test_exports_write_one_file(tmp_path, fmu_dir, capsys, command, suffix):
    out = tmp_path / f"loop{suffix}"
    assert main([command, "on_reference", "-o", str(out), "--stop-time", "2", "--fmu-dir", str(fmu_dir)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == [out.name]
    if suffix == ".ssp":
        from dsc_fmu.interop.ssp import validate_ssp
        validate_ssp(out)
    else:
        from fmpy.validation import validate_fmu
        assert validate_fmu(str(out)) == []


@pytest.mark.parametrize("command", ["export-ssp", "export-fmu"])
def test_export_of_a_bad_scenario_writes_nothing(tmp_path, fmu_dir, capsys, command):
    bad = tmp_path / "bad.toml"
    bad.write_text(BAD_SCENARIO)
    out = tmp_path / "loop.out"
    assert main([command, str(bad), "-o", str(out), "--fmu-dir", str(fmu_dir)]) == 1
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and "[plant] mc = -30.0 is not allowed" in error[0]
    assert not out.exists()


def test_build_fmi_3(tmp_path, capsys):
    assert main(["build", "--fmi-version", "3", "--out", str(tmp_path)]) == 0
    from fmpy import read_model_description
    for path in capsys.readouterr().out.split():
        assert read_model_description(path).fmiVersion == "3.0"


def test_export_writes_only_its_file_when_no_fmus_are_built(tmp_path, capsys):
    out = tmp_path / "out" / "loop.ssp"
    out.parent.mkdir()
    empty = tmp_path / "fmus"
    assert main(["export-ssp", "-o", str(out), "--stop-time", "1", "--fmu-dir", str(empty)]) == 0
    assert not empty.exists()
    assert [p.name for p in out.parent.iterdir()] == ["loop.ssp"]


def test_crosscheck_command_writes_the_layout(tmp_path, fmu_dir, capsys):
    assert main(["crosscheck", "-o", str(tmp_path), "--stop-time", "0.5", "--fmu-dir", str(fmu_dir)]) == 0
    folders = [Path(line) for line in capsys.readouterr().out.split()]
    assert sorted(f.name for f in folders) == ["DSCController", "MobileRobot", "ReferenceRobot"]
    for folder in folders:
        assert folder.is_relative_to(tmp_path / "fmus" / "2.0" / "cs")
        assert (folder / f"{folder.name}.fmu").is_file() and (folder / f"{folder.name}_ref.csv").is_file()
        assert (folder / f"{folder.name}_ref.opt").is_file()
    assert (folders[0].parent / "MobileRobot" / "MobileRobot_in.csv").is_file()


HEAVY = ("control", "distributed", "matplotlib")


@pytest.mark.parametrize("arguments,heavy", [
    (["--help"], ()),
    (["run", "--no-plots"], ()),
    (["run"], ("matplotlib",)),
], ids=["help", "run-no-plots", "run"])
def test_commands_import_heavy_libraries_only_when_they_need_them(tmp_path, fmu_dir, arguments, heavy):
    """python-control, Dask and matplotlib are imported by the commands that use them, not by ``--help`` or ``run``."""
    if arguments[0] == "run":
        arguments = [*arguments, "--stop-time", "0.05", "--out", str(tmp_path), "--fmu-dir", str(fmu_dir)]
    code = ("import sys; from dsc_fmu.cli import main\n"
            "try:\n    status = main(sys.argv[1:])\nexcept SystemExit as exit_:\n    status = exit_.code\n"
            f"print(status, *[name for name in {HEAVY!r} if name in sys.modules])")
    process = subprocess.run([sys.executable, "-c", code, *arguments], capture_output=True, text=True, cwd=tmp_path)
    assert process.stdout.splitlines()[-1].split() == ["0", *heavy], process.stderr
