"""``dsc-fmu sweep`` end to end: files, refined boundaries beside the prediction, one-line errors."""

import csv
import json

import pytest

from dsc_fmu.cli import main
from dsc_fmu.cosim.master import Cosimulator
from dsc_fmu.scenario import load_scenario
from dsc_fmu.study import execute
from dsc_fmu.study.cases import Case, apply
from dsc_fmu.study.rows import compute_reference
from dsc_fmu.study.rows import run_case

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def fmu_dir(fmu_paths):
    return next(iter(fmu_paths.values())).parent


@pytest.fixture(scope="module")
def sweep(tmp_path_factory, fmu_dir):
    """The sweep, with the process pools it made counted: one, which the bisection of the boundaries reuses."""
    out, pools = tmp_path_factory.mktemp("sweep"), []

    class CountedPool(execute.ProcessPoolExecutor):
        def __init__(self, *args, **kwargs):
            pools.append(args[0])
            super().__init__(*args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(execute, "ProcessPoolExecutor", CountedPool)
        status = main(["sweep", "on_reference", "--step-sizes", "0.02,0.04,0.06", "--orders", "gauss-seidel,jacobi",
                       "--tolerances", "", "--jobs", "2", "--out", str(out), "--fmu-dir", str(fmu_dir)])
    assert status == 0
    assert pools == [2]
    return out


def test_sweep_writes_table_summary_figures_and_report(sweep):
    with open(sweep / "sweep.csv") as file:
        rows = list(csv.DictReader(file))
    assert [(float(r["step_size"]), r["order"], r["coupling"]) for r in rows] == [
        (h, order, coupling) for h in (0.02, 0.04, 0.06) for order in ("gauss-seidel", "jacobi")
        for coupling in ("hold", "linear")]
    for name in ("deviation.png", "tracking_and_cost.png", "paths.png", "spectral_radius.png"):
        assert (sweep / name).read_bytes()[:4] == b"\x89PNG"
    report = (sweep / "report.md").read_text()
    assert "](deviation.png)" in report and "## Stability boundary" in report
    assert not (sweep / ".work").exists()


def test_on_reference_boundaries_agree_with_the_linearised_prediction(sweep):
    """Both orders, both couplings: the stability of steady tracking (on_reference's "local" definition)."""
    summary = json.loads((sweep / "sweep.json").read_text())
    assert summary["settings"]["stability"] == "local"
    assert set(summary["groups"]) == {f"{order}/rk4{coupling}" for order in ("gauss-seidel", "jacobi")
                                      for coupling in ("", " linear")}
    for label, group in summary["groups"].items():
        boundary = group["stability_boundary"]
        refined = boundary["refined"]
        assert refined["h_unstable_s"] / refined["h_stable_s"] <= 1.02 + 1e-9, label
        assert group["prediction"]["agrees"] is True, group["prediction"]["statement"]
        assert 0.8 <= group["prediction"]["ratio_predicted_to_measured"] <= 1.2


def test_beyond_the_predicted_boundary_a_run_settles_but_steady_tracking_is_unstable(sweep, fmu_paths, tmp_path):
    """20 % above the linear coupling's predicted boundary the oscillation grows from the start (the
    deviation from the reference solution rises far above its start), then the adaptation damps it:
    stable as a settled run, unstable as one of steady tracking."""
    summary = json.loads((sweep / "sweep.json").read_text())
    case = Case(1.2 * summary["groups"]["gauss-seidel/rk4 linear"]["prediction"]["predicted_boundary_s"],
                coupling="linear")
    local = load_scenario("on_reference")
    settled = local.with_simulation(stability="settled")
    reference, why = compute_reference(apply(local, case))
    assert why is None
    with Cosimulator(fmu_paths, tmp_path) as simulator:
        rows = {s.simulation.stability: run_case(s, case, simulator, reference) for s in (local, settled)}
    assert (rows["settled"]["stability"], rows["settled"]["stable"]) == ("settled", True)
    assert (rows["local"]["stability"], rows["local"]["stable"]) == ("local", False)
    assert rows["local"]["max_position_deviation_m"] > 0.01  # 0.1 mm where the loop is stable


@pytest.mark.parametrize("arguments, message", [
    (["--step-sizes", "0,1e-3"], "step size 0.0 is not allowed; allowed: > 0"),
    (["--step-sizes", "fast"], None),
    (["--set", "controller.k9=1,2"], "controller.k9"),
    (["--orders", "random"], "order = 'random' is not allowed"),
    (["--jobs", "0"], "jobs = 0 is not allowed; allowed: a whole number >= 1"),
    (["--scheduler", "tcp://127.0.0.1:1"], "cannot reach the Dask scheduler"),
])
def test_bad_sweep_options_fail_in_one_line_and_write_nothing(tmp_path, fmu_dir, capsys, arguments, message):
    out = tmp_path / "out"
    try:
        status = main(["sweep", "on_reference", *arguments, "--out", str(out), "--fmu-dir", str(fmu_dir)])
    except SystemExit as exit_:  # argparse refuses what it can parse itself
        status = exit_.code
    error = capsys.readouterr().err.strip().splitlines()
    assert status in (1, 2)
    if message is not None:
        assert status == 1 and len(error) == 1 and message in error[0], error
    assert not out.exists()


def test_a_sweep_reports_the_linear_coupling_beside_the_hold_and_error_controlled_runs(tmp_path, fmu_dir, capsys):
    """Both couplings for both orders, their predictions, and the error-controlled runs in the
    work-precision figure, the report and sweep.json; the linear series converge at second order."""
    out = tmp_path / "sweep"
    assert main(["sweep", "on_reference", "--stop-time", "5", "--step-sizes", "0.005,0.01,0.02", "--no-refine",
                 "--tolerances", "1e-3,1e-4", "--jobs", "2", "--out", str(out), "--fmu-dir", str(fmu_dir)]) == 0
    summary = json.loads((out / "sweep.json").read_text())
    assert set(summary["groups"]) == {"gauss-seidel/rk4", "jacobi/rk4", "gauss-seidel/rk4 linear", "jacobi/rk4 linear"}
    for order in ("gauss-seidel", "jacobi"):
        assert summary["groups"][f"{order}/rk4 linear"]["observed_order"]["max_position_deviation_m"]["slope"] >= 1.8
        hold = summary["groups"][f"{order}/rk4"]["prediction"]["predicted_boundary_s"]
        assert 0 < summary["groups"][f"{order}/rk4 linear"]["prediction"]["predicted_boundary_s"] < hold
    controlled = summary["error_controlled"]
    assert sorted((entry["order"], entry["tolerance"]) for entry in controlled) == [
        (order, tolerance) for order in ("gauss-seidel", "jacobi") for tolerance in (1e-4, 1e-3)]
    assert all(entry["max_position_deviation_m"] <= 3 * entry["tolerance"] for entry in controlled)
    assert (out / "work_precision.png").read_bytes()[:4] == b"\x89PNG"
    report = (out / "report.md").read_text()
    assert "## Accuracy per cost" in report and "](work_precision.png)" in report
    assert "second order, as expected" in report
    printed = capsys.readouterr().out
    assert "linear error-controlled, tolerance 0.0001 m: max deviation" in printed


def test_a_sweep_reads_the_fmi_version_of_its_folder(tmp_path, fmu_dir, fmu3_paths):
    """``sweep --fmu-dir`` a folder of FMI 3.0 FMUs: its runs are the FMI 2.0 sweep's (to test_fmi3's
    precision), its FMUs left as they were."""
    fmu3_dir = next(iter(fmu3_paths.values())).parent
    files = {path: (path.read_bytes(), path.stat().st_mtime_ns) for path in fmu3_dir.iterdir()}
    rows = {}
    for version, folder in ((2, fmu_dir), (3, fmu3_dir)):
        out = tmp_path / f"sweep{version}"
        assert main(["sweep", "on_reference", "--stop-time", "1", "--step-sizes", "0.01,0.02", "--orders", "jacobi",
                     "--couplings", "hold", "--tolerances", "", "--no-refine", "--jobs", "1", "--out", str(out),
                     "--fmu-dir", str(folder)]) == 0
        with open(out / "sweep.csv") as file:
            rows[version] = list(csv.DictReader(file))
    assert {path: (path.read_bytes(), path.stat().st_mtime_ns) for path in fmu3_dir.iterdir()} == files
    assert [row["step_size"] for row in rows[3]] == ["0.01", "0.02"]
    deviations = [key for key in rows[2][0] if key.endswith("_m")]
    assert "max_position_deviation_m" in deviations
    for fmi2, fmi3 in zip(rows[2], rows[3]):
        assert fmi3["stable"] == fmi2["stable"] == "True"
        for key in deviations:
            assert float(fmi3[key]) == pytest.approx(float(fmi2[key]), rel=1e-12, abs=1e-12), key
