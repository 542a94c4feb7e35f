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
from dsc_fmu.scenario import INTERFACES, load_scenario
from dsc_fmu.cosim.signals import COLUMNS
from dsc_fmu.interop import crosscheck, ssp

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


@pytest.fixture(scope="module")
def fmu3_dir(fmu3_paths):
    return next(iter(fmu3_paths.values())).parent


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
    assert settings["evaluations"] > 0 and "steps" not in settings


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


@pytest.mark.parametrize("arguments, message", [
    (["run", "--order", "random"], "invalid choice: 'random'"),
    (["sweep", "--orders", " , "], "argument --orders: ' , ' names none; allowed: one or more names, comma-separated"),
])
def test_bad_options_are_refused_by_the_parser(capsys, arguments, message):
    with pytest.raises(SystemExit) as exit_:
        main(arguments)
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err


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


def test_build_fmus_script_builds_fmi2_by_default(tmp_path):
    """``build_fmus.py`` is ``dsc-fmu build`` (test_fmi3 runs it with ``--fmi-version 3``): it prints the FMUs' paths,
    and for the controller what runs in Python, not traced to C (its Euler step, per law and coupling)."""
    from fmpy import read_model_description

    process = subprocess.run([sys.executable, str(REPO / "build_fmus.py"), "--out", str(tmp_path)], capture_output=True,
                             text=True)
    assert process.returncode == 0, process.stderr
    lines = process.stdout.splitlines()
    paths = [Path(line.split(": ")[0]) for line in lines]
    assert lines[-1] == (f"{tmp_path / 'DSCController.fmu'}: 8 functions run in Python, not traced to C (listed in its "
                         "resources/dsc_fmu_build.json): discretization = euler takes one Euler step per communication "
                         "step (DSCControllerModel.integrate), not RK4 sub-steps")
    assert sorted(paths) == sorted(tmp_path / f"{n}.fmu" for n in ("ReferenceRobot", "MobileRobot", "DSCController"))
    assert sorted(tmp_path.iterdir()) == sorted(paths)
    assert {read_model_description(str(path)).fmiVersion for path in paths} == {"2.0"}


def test_scenarios_command_lists_the_shipped_ones(capsys):
    assert main(["scenarios"]) == 0
    names = [line.split(":")[0] for line in capsys.readouterr().out.splitlines()]
    assert {"paper", "figure_eight", "ahead_start"} <= set(names)


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


def _snapshot(folder: Path) -> dict:
    """Every file of a folder: its bytes and modification time."""
    return {path.name: (path.read_bytes(), path.stat().st_mtime_ns) for path in sorted(folder.iterdir())}


def _assert_same_rows(fmi2, fmi3):
    """FMI 3.0 results equal FMI 2.0 ones to the precision test_fmi3 asserts."""
    assert fmi3.dtype == fmi2.dtype and len(fmi3) == len(fmi2)
    for column in fmi2.dtype.names:
        np.testing.assert_allclose(fmi3[column], fmi2[column], rtol=1e-12, atol=1e-12, err_msg=column)


@pytest.mark.parametrize("interface", INTERFACES)
def test_run_reads_the_fmi_version_of_its_folder(tmp_path, fmu_dir, fmu3_dir, interface):
    """``run --fmu-dir`` a folder of FMI 3.0 FMUs, no --fmi-version: it runs them, with the FMI 2.0 run's
    results, and leaves them as they were."""
    from fmpy.util import read_csv

    before = _snapshot(fmu3_dir)
    results = {}
    for version, folder in ((2, fmu_dir), (3, fmu3_dir)):
        out = tmp_path / str(version)
        assert main(["run", "--interface", interface, "--stop-time", "0.2", "--no-plots", "--quiet", "--out", str(out),
                     "--fmu-dir", str(folder)]) == 0
        results[version] = read_csv(out / "results.csv")
    assert _snapshot(fmu3_dir) == before
    assert results[3]["time"][-1] == 0.2
    _assert_same_rows(results[2], results[3])


def test_export_fmu_holds_fmi3_fmus(tmp_path, fmu_dir, fmu3_dir):
    """fmpy's container FMU (FMI 2.0 itself) around FMI 3.0 FMUs validates and runs as around FMI 2.0 ones."""
    from fmpy import simulate_fmu
    from fmpy.validation import validate_fmu

    results = {}
    for version, folder in ((2, fmu_dir), (3, fmu3_dir)):
        out = tmp_path / f"loop{version}.fmu"
        assert main(["export-fmu", "on_reference", "-o", str(out), "--stop-time", "0.5", "--fmu-dir", str(folder)]) == 0
        assert validate_fmu(str(out)) == []
        results[version] = simulate_fmu(str(out), stop_time=0.5, output_interval=0.01)
    _assert_same_rows(results[2], results[3])


_REPLACED = "fmi_version = {asked} is not allowed for {folder}, which holds FMI {held}.0 FMUs " \
    "(they would be replaced); " \
    "allowed: {held}, or another folder"
_FMI2_ONLY = "{command} with FMI 3.0 FMUs ({folder}) is not allowed: {why}; allowed: FMI 2.0 FMUs (--fmi-version 2, " \
    "a folder without FMI 3.0 FMUs)"


@pytest.mark.parametrize("arguments, held, message", [
    (["build", "--fmi-version", "2", "--out"], 3, _REPLACED.format(asked=2, held=3, folder="{folder}")),
    (["run", "--fmi-version", "2", "--fmu-dir"], 3, _REPLACED.format(asked=2, held=3, folder="{folder}")),
    (["run", "--interface", "model-exchange", "--fmi-version", "2", "--fmu-dir"], 3,
     _REPLACED.format(asked=2, held=3, folder="{folder}")),
    (["run", "--fmi-version", "3", "--fmu-dir"], 2, _REPLACED.format(asked=3, held=2, folder="{folder}")),
    (["sweep", "--fmi-version", "2", "--fmu-dir"], 3, _REPLACED.format(asked=2, held=3, folder="{folder}")),
    (["export-fmu", "-o", "{out}", "--fmi-version", "2", "--fmu-dir"], 3,
     _REPLACED.format(asked=2, held=3, folder="{folder}")),
    (["export-ssp", "-o", "{out}", "--fmu-dir"], 3, _FMI2_ONLY.format(
        command="export-ssp", folder="{folder}", why=ssp.FMI2_ONLY)),
    (["crosscheck", "-o", "{out}", "--fmu-dir"], 3, _FMI2_ONLY.format(
        command="crosscheck", folder="{folder}",
        why=crosscheck.FMI2_ONLY)),
], ids=["build", "run", "run-model-exchange", "run-fmi3-on-fmi2", "sweep", "export-fmu", "export-ssp", "crosscheck"])
def test_fmus_of_another_version_are_refused_in_one_line_and_left_untouched(tmp_path, fmu_dir, fmu3_dir, capsys,
                                                                             arguments, held, message):
    folder = fmu3_dir if held == 3 else fmu_dir
    out = tmp_path / "out"
    before = _snapshot(folder)
    arguments = [*(argument.format(out=out) for argument in arguments), str(folder)]
    assert main([*arguments, *(["--out", str(out)] if arguments[0] in ("run", "sweep") else [])]) == 1
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [f"dsc-fmu: error: {message.format(folder=folder)}"]
    assert captured.out == ""
    assert _snapshot(folder) == before
    assert not out.exists()


def test_a_folder_of_two_fmi_versions_is_refused(tmp_path, fmu_dir, fmu3_dir, capsys):
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for name, folder in (("MobileRobot", fmu_dir), ("DSCController", fmu3_dir)):
        (mixed / f"{name}.fmu").write_bytes((folder / f"{name}.fmu").read_bytes())
    before = _snapshot(mixed)
    assert main(["run", "--stop-time", "0.1", "--out", str(tmp_path / "out"), "--fmu-dir", str(mixed)]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"dsc-fmu: error: {mixed} holds FMUs of FMI 2.0 and 3.0; allowed: a folder whose FMUs share one FMI version"]
    assert _snapshot(mixed) == before


@pytest.mark.parametrize("interface, system", [("co-simulation", b"FixedStepMaster"),
                                               ("model-exchange", b"VariableStepSolver")])
def test_export_ssp_passes_the_interface(tmp_path, fmu_dir, interface, system):
    """``export-ssp --interface``: the SSD's OMSimulator system is a fixed-step master or a variable-step solver."""
    import zipfile

    from dsc_fmu.interop.ssp import validate_ssp

    out = tmp_path / "loop.ssp"
    assert main(["export-ssp", "on_reference", "-o", str(out), "--interface", interface, "--stop-time", "1",
                 "--fmu-dir", str(fmu_dir)]) == 0
    validate_ssp(out)
    with zipfile.ZipFile(out) as archive:
        assert system in archive.read("SystemStructure.ssd")


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


def _help(command: str, capsys) -> str:
    with pytest.raises(SystemExit) as exit_:
        main([command, "--help"])
    assert exit_.value.code == 0
    return capsys.readouterr().out


@pytest.fixture()
def wide(monkeypatch):
    """Help on lines as long as it needs: argparse wraps at the terminal's width (COLUMNS)."""
    monkeypatch.setenv("COLUMNS", "1000")


def test_help_names_the_owners_defaults(capsys, wide):
    from dsc_fmu.cosim.model_exchange import DEFAULT_TOLERANCE
    from dsc_fmu.fmubuild.folders import DEFAULT_FMU_DIRS
    from dsc_fmu.interop.crosscheck import DEFAULT_STOP_TIME
    from dsc_fmu.scenario import Simulation
    from dsc_fmu.study.cases import DEFAULT_TOLERANCES, default_step_sizes

    folders = f"(default: {DEFAULT_FMU_DIRS[2]} for FMI 2.0, {DEFAULT_FMU_DIRS[3]} for FMI 3.0)"
    run = _help("run", capsys)
    assert f"model exchange: {DEFAULT_TOLERANCE:g} where it sets none" in run
    assert f"smallest error-controlled step in s (default: the scenario's, {Simulation.h_min:g} where" in run
    assert f"largest error-controlled step in s (default: the scenario's, {Simulation.h_max:g} where" in run
    assert folders in run and "(default: that of the FMUs in the folder, else 2)" in run
    sweep = _help("sweep", capsys)
    steps = default_step_sizes()
    assert f"(default: {len(steps)} log-spaced from {steps[0]:g} to {steps[-1]:g})" in sweep
    assert "coupling orders, comma-separated: gauss-seidel, jacobi (default: gauss-seidel,jacobi)" in sweep
    assert "couplings, comma-separated: hold, linear (default: hold,linear)" in sweep
    assert f"(default: {','.join(f'{t:g}' for t in DEFAULT_TOLERANCES)})" in sweep
    assert "controller discretizations, comma-separated: rk4, euler (default: the scenario's)" in sweep
    assert "seed of the Monte Carlo draws (default: 0)" in sweep
    crosscheck = _help("crosscheck", capsys)
    assert f"stop time in s (default: {DEFAULT_STOP_TIME:g})" in crosscheck
    assert "FMI version of the FMUs: 2 only" in crosscheck
    for command in ("export-ssp", "export-fmu", "build"):
        assert folders in _help(command, capsys)


def test_help_reads_its_defaults_from_their_owners(monkeypatch, capsys, wide):
    """Change the owners' defaults and the help follows: nothing is copied."""
    from types import SimpleNamespace

    import dsc_fmu.cosim.model_exchange as model_exchange
    import dsc_fmu.interop.crosscheck as crosscheck
    import dsc_fmu.study.cases as cases
    from dsc_fmu.fmubuild.folders import DEFAULT_FMU_DIRS
    from dsc_fmu.scenario import Simulation

    monkeypatch.setattr(cases, "Grid", lambda: SimpleNamespace(
        step_sizes=(0.002, 0.02, 0.2), orders=("jacobi",), couplings=("linear",), discretizations=("euler",),
        tolerances=(0.5,), seed=7))
    monkeypatch.setattr(model_exchange, "DEFAULT_TOLERANCE", 3e-7)
    monkeypatch.setattr(crosscheck, "DEFAULT_STOP_TIME", 4.5)
    monkeypatch.setattr(Simulation, "h_max", 0.125)
    monkeypatch.setitem(DEFAULT_FMU_DIRS, 3, Path("elsewhere"))
    sweep = _help("sweep", capsys)
    for text in ("(default: 3 log-spaced from 0.002 to 0.2)", "jacobi (default: jacobi)", "linear (default: linear)",
                 "euler (default: euler)", "or '' for none (default: 0.5)", "draws (default: 7)",
                 "elsewhere for FMI 3.0"):
        assert text in sweep
    run = _help("run", capsys)
    assert "model exchange: 3e-07 where it sets none" in run and "(default: the scenario's, 0.125 where" in run
    assert "stop time in s (default: 4.5)" in _help("crosscheck", capsys)
