"""Sweeps: cases and grids, the reusable master, rows, the cache, local and Dask execution, cleanup."""

import dataclasses
import json
import math
import re
import threading
import time
import types
from pathlib import Path

import numpy as np
import pytest

from dsc_fmu.study import cache as sweep_cache
from dsc_fmu.study import cluster as sweep_dask
from dsc_fmu.study import execute as sweep_execute
from dsc_fmu.study import rows as sweep_rows
from dsc_fmu.cosim.master import CosimulationError, Cosimulator, cosimulate
from dsc_fmu.files import atomic_write
from dsc_fmu.models.parameters import DISCRETIZATIONS, PLANT_PARAMETERS
from dsc_fmu.scenario import REFERENCES, Coupling, Order, ScenarioError, load_scenario
from dsc_fmu.study.cache import TRAJECTORY, load_reference, load_trajectory
from dsc_fmu.study.cases import (
    Case, Perturbation, Runner, SweepError, apply, build_cases, default_step_sizes, parse_perturb, parse_set,
)
from dsc_fmu.study.execute import execute
from dsc_fmu.study.rows import ROW_KEYS, SETTLED_DEFINITION, STABLE_POSITION_ERROR, Plan, row_keys, run_case

ORDERS = ("gauss-seidel", "jacobi")
MASS = next(v for v in PLANT_PARAMETERS if v.name == "mc")


@pytest.fixture(scope="module")
def short():
    """The paper scenario cut to 1 s, recorded every 10 ms."""
    return load_scenario("paper").with_simulation(stop_time=1.0)


def without_wall_time(rows):
    """Rows as JSON text without their wall times: equal text means equal values, bit for bit (NaN too)."""
    return [json.dumps({k: v for k, v in row.items() if k != "wall_time_s"}) for row in rows]


@pytest.fixture
def counted(monkeypatch):
    """Counts of the runs and reference solutions computed in this process (jobs = 1)."""
    counts = {"run": 0, "reference": 0}
    simulate, reference = sweep_rows.simulate, sweep_rows.compute_reference

    def counting_simulate(*args):
        counts["run"] += 1
        return simulate(*args)

    def counting_reference(*args):
        counts["reference"] += 1
        return reference(*args)

    monkeypatch.setattr(sweep_execute, "simulate", counting_simulate)
    monkeypatch.setattr(sweep_execute, "compute_reference", counting_reference)
    return counts


def leftovers(out_dir):
    """What is left in ``out_dir/.work`` (nothing, or the folder is gone)."""
    work = out_dir / ".work"
    return sorted(p.name for p in work.rglob("*")) if work.exists() else []


# --- parsing --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("text", "key", "values"), [
    ("controller.k4=0.5,1,2", "controller.k4", (0.5, 1.0, 2.0)),
    (" plant.mc = 27.31 ", "plant.mc", (27.31,)),
    ("reference.profile=figure_eight,constant", "reference.profile", ("figure_eight", "constant")),
    ("controller.tau2=0.01,1e-2,0.02", "controller.tau2", (0.01, 0.02)),  # repeated values kept once
])
def test_parse_set(text, key, values):
    assert parse_set(text) == (key, values)


@pytest.mark.parametrize(("text", "match"), [
    ("controller.k4", "expected TABLE.NAME=VALUE"),
    ("controller.k4=", "expected TABLE.NAME=VALUE"),
    ("k4=1", r"k4: unknown parameter; allowed: TABLE\.NAME with TABLE one of plant, controller, reference"),
    ("controller.k9=1", r"controller\.k9: unknown parameter; allowed: controller\.k1, controller\.k2"),
    ("simulation.step_size=0.1", "step size and the coupling order have their own options"),
    ("controller.discretization=euler", "discretizations option"),
    ("controller.k4=fast", r"controller\.k4 = 'fast' is not a number; allowed: > 0"),
    ("controller.k4=1,-2", r"k4 = -2.0 is not allowed: it must be > 0; allowed: > 0"),
    ("plant.mc=nan", "not finite"),
    ("reference.profile=square", "allowed: constant, figure_eight"),
])
def test_parse_set_rejects_with_one_line(text, match):
    with pytest.raises(ScenarioError, match=match) as info:
        parse_set(text)
    assert "\n" not in str(info.value)


def test_parse_perturb():
    assert parse_perturb("plant.mc=20%") == Perturbation("plant.mc", relative=0.2)
    assert parse_perturb("plant.mc=25:35") == Perturbation("plant.mc", low=25.0, high=35.0)
    assert parse_perturb("plant.mc=20%").bounds(30.0) == pytest.approx((24.0, 36.0))


@pytest.mark.parametrize(("text", "match"), [
    ("controller.k4=20%", "only plant parameters can be perturbed"),
    ("reference.vr0=20%", "only plant parameters"),
    ("plant.max_step=20%", "solver setting"),
    ("plant.mass=20%", r"plant\.mass: unknown parameter; allowed: plant\.R, plant\.d"),
    ("plant.mc=20", "not a bound; allowed: P% with P > 0"),
    ("plant.mc=-5%", "not a bound"),
    ("plant.mc=35:25", "LOW < HIGH"),
    ("plant.mc=-5:35", r"range \[-5, 35\] allows mc = -5.0 is not allowed: it must be > 0"),
])
def test_parse_perturb_rejects_with_one_line(text, match):
    with pytest.raises(ScenarioError, match=match) as info:
        parse_perturb(text)
    assert "\n" not in str(info.value)


# --- grids ----------------------------------------------------------------------------------------------------


def test_default_step_sizes_are_log_spaced_and_print_nicely():
    steps = default_step_sizes()
    assert len(steps) == 12 and steps[0] == 1e-4 and steps[-1] == 0.05
    assert 1e-3 in steps and 1e-2 in steps
    assert all(float(f"{h:.3g}") == h for h in steps)
    ratios = np.diff(np.log(steps[:-1]))
    np.testing.assert_allclose(ratios, np.log(10) / 4, rtol=0.01)
    assert steps[-2] < 0.05


def test_build_cases_is_the_full_grid_with_the_step_outermost(short):
    cases = build_cases(short, step_sizes=[1e-3, 2e-3, 5e-3], orders=ORDERS, discretizations=DISCRETIZATIONS,
                        sets=[parse_set("controller.k4=0.5,1"), parse_set("plant.mc=27.31,30,33")])
    assert len(cases) == 3 * 2 * 2 * 2 * 3
    assert len(set(cases)) == len(cases)
    assert [c.step_size for c in cases[:24]] == [1e-3] * 24
    assert cases[0] == Case(1e-3, "gauss-seidel", "rk4", (("controller.k4", 0.5), ("plant.mc", 27.31)))
    assert cases[1].overrides == (("controller.k4", 0.5), ("plant.mc", 30.0))
    assert cases[-1] == Case(5e-3, "jacobi", "euler", (("controller.k4", 1.0), ("plant.mc", 33.0)))


def test_build_cases_defaults_to_the_scenarios_order_and_discretization(short):
    cases = build_cases(short)
    assert [c.step_size for c in cases] == default_step_sizes()
    assert {(c.order, c.discretization, c.overrides, c.sample) for c in cases} == {("gauss-seidel", "rk4", (), None)}


@pytest.mark.parametrize("couplings, controlled", [(["hold", "linear"], "linear"), (["hold"], "hold"),
                                                    (["linear"], "linear")])
def test_error_controlled_cases_take_the_highest_order_coupling_chosen(short, couplings, controlled):
    cases = build_cases(short, step_sizes=[1e-3], orders=ORDERS, couplings=couplings, tolerances=[1e-3, 1e-4])
    assert [c.coupling for c in cases if c.tolerance is None] == [
        coupling for order in ORDERS for coupling in couplings]
    assert [(c.order, c.coupling, c.tolerance) for c in cases if c.tolerance is not None] == [
        (order, controlled, tolerance) for tolerance in (1e-3, 1e-4) for order in ORDERS]


def test_perturbation_is_reproducible_within_bounds_and_one_plant_per_sample(short):
    def grid(seed):
        return build_cases(short, step_sizes=[1e-3, 1e-2], orders=ORDERS, samples=20, seed=seed,
                           perturbations=[parse_perturb("plant.mc=20%"), parse_perturb("plant.Ra1=1.5:1.7")])

    cases = grid(7)
    assert len(cases) == 2 * 2 * 20 and cases == grid(7) and cases != grid(8)
    draws = {}
    for case in cases:
        values = dict(case.overrides)
        assert 24.0 <= values["plant.mc"] <= 36.0 and 1.5 <= values["plant.Ra1"] <= 1.7
        assert draws.setdefault(case.sample, values) == values  # the same plant at every step and order
    assert sorted(draws) == list(range(20))
    assert len({v["plant.mc"] for v in draws.values()}) == 20


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"perturbations": [Perturbation("plant.mc", relative=1.5)], "samples": 3}, r"range \[-15, 75\] allows mc"),
    ({"perturbations": [Perturbation("plant.mc", relative=0.2)]}, "--samples None is not allowed with --perturb"),
    ({"samples": 5}, "needs at least one perturbation"),
    ({"sets": [parse_set("plant.mc=30")], "perturbations": [parse_perturb("plant.mc=20%")], "samples": 2},
     "also given with --set"),
    ({"step_sizes": [1e-3, 0.0]}, "step size 0.0 is not allowed"),
    ({"step_sizes": [100, 3, 0.5]}, r"step size 100 s is not allowed: larger than the stop time 1 s; allowed: 0 < h"),
    ({"orders": ["backwards"]}, "order = 'backwards' is not allowed"),
    ({"discretizations": ["trapezoidal"]}, "allowed: rk4, euler"),
    ({"sets": [("reference.vr0", (1.0, -1.0))]}, r"vr0 = -1.0 is not allowed"),
])
def test_build_cases_rejects_up_front(short, kwargs, match):
    with pytest.raises(ScenarioError, match=match):
        build_cases(short, **kwargs)


def test_apply_sets_overrides_discretization_step_and_order(short):
    overrides = (("controller.k4", 0.5), ("plant.mc", 27.31), ("reference.profile", "figure_eight"))
    case = Case(2e-3, "jacobi", "euler", overrides)
    applied = apply(short, case)
    assert applied.controller["k4"] == 0.5 and applied.plant["mc"] == 27.31
    assert applied.reference["profile"] == 1 and applied.controller["discretization"] == DISCRETIZATIONS.index("euler")
    assert (applied.simulation.step_size, applied.simulation.order) == (2e-3, "jacobi")
    assert short.controller["k4"] == 1.0  # the scenario itself is unchanged
    with pytest.raises(ScenarioError, match="k4 = -1.0 is not allowed"):
        apply(short, Case(1e-3, overrides=(("controller.k4", -1),)))


# --- the reusable master ---------------------------------------------------------------------------------------


def test_a_reused_cosimulator_is_bit_for_bit_a_fresh_one(short, fmu_paths, tmp_path):
    with Cosimulator(fmu_paths, tmp_path) as simulator:
        assert len(list(tmp_path.iterdir())) == 3
        for order in (*ORDERS, *ORDERS):
            reused = simulator.run(short, order=order, step_size=2e-3).result
            fresh = cosimulate(short, fmu_paths, order=order, step_size=2e-3).result
            assert reused.tobytes() == fresh.tobytes(), order
        for bound, h in ((1e6, 0.2), (1e300, 0.1)):  # diverged, then an FMU's doStep failed
            with pytest.raises(CosimulationError):
                simulator.run(short.with_simulation(bound=bound), step_size=h, stop_time=10.0)
            for order in ORDERS:
                assert simulator.run(short, order=order).result.tobytes() == \
                    cosimulate(short, fmu_paths, order=order).result.tobytes()
        assert simulator.runs == 10
    assert list(tmp_path.iterdir()) == []


def test_an_instance_that_cannot_be_reset_is_instantiated_again(short, fmu_paths, tmp_path, monkeypatch):
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import FMU2Slave

    resets = []

    def failing_reset(self):
        resets.append(self.instanceName)
        raise FMICallException(function="fmi2Reset", status=3)

    with Cosimulator(fmu_paths, tmp_path) as simulator:
        first = simulator.run(short).result
        monkeypatch.setattr(FMU2Slave, "reset", failing_reset)
        again = simulator.run(short).result
    assert sorted(resets) == ["DSCController", "MobileRobot", "ReferenceRobot"]
    assert again.tobytes() == first.tobytes()
    assert list(tmp_path.iterdir()) == []


# --- rows -------------------------------------------------------------------------------------------------------


def test_a_row_has_every_key_and_zero_deviation_from_itself(short, fmu_paths, tmp_path):
    case = Case(2e-3, "jacobi", "euler", (("controller.k4", 0.5),))
    own = cosimulate(apply(short, case), fmu_paths).result
    with Cosimulator(fmu_paths, tmp_path) as simulator:
        row = run_case(short, case, simulator, own)
    assert list(row) == list(row_keys(case))
    at = ROW_KEYS.index("sample") + 1
    assert ROW_KEYS[at] == "key" and row_keys(case) == (*ROW_KEYS[:at], "controller.k4", *ROW_KEYS[at:])
    assert json.dumps(json.loads(json.dumps(row))) == json.dumps(row)
    assert row["controller.k4"] == 0.5 and row["steps"] == 500 and row["diverged"] is False
    for name in ("position", "heading", "u"):
        unit = {"position": "m", "heading": "rad", "u": "V"}[name]
        assert row[f"max_{name}_deviation_{unit}"] == 0.0 and row[f"rms_{name}_deviation_{unit}"] == 0.0
    assert row["key"] == sweep_cache.case_key(short, case, sweep_cache.fmu_identities(fmu_paths))
    assert row["reference_key"] == sweep_cache.reference_key(short, dataclasses.replace(case, step_size=0.1),
                                                             sweep_cache.fmu_identities(fmu_paths))


@pytest.mark.parametrize("order", ORDERS)
def test_the_deviation_from_the_reference_solution_is_first_order_in_the_step(short, fmu_paths, tmp_path, order):
    scenario = short.with_simulation(stop_time=2.0)
    reference, why = sweep_rows.compute_reference(apply(scenario, Case(1e-3)))
    assert why is None and reference["time"][-1] == 2.0 and np.all(np.diff(reference["time"]) > 0)
    with Cosimulator(fmu_paths, tmp_path) as simulator:
        rows = [run_case(scenario, Case(h, order), simulator, reference) for h in (1e-3, 2e-3)]
    for name in ("max_position_deviation_m", "rms_heading_deviation_rad", "rms_u_deviation_V"):
        assert 1.6 < rows[1][name] / rows[0][name] < 2.4, name


@pytest.mark.slow
def test_stability_over_the_papers_run(fmu_paths, tmp_path):
    """The paper's 30 s: settled by the last third at h = 10 ms; Jacobi diverges at 20 ms, Gauss-Seidel not."""
    paper = load_scenario("paper")
    cases = [Case(0.01), Case(0.02, "jacobi"), Case(0.02)]
    rows = execute(paper, cases, tmp_path, fmu_paths, Runner(jobs=1, progress=False)).rows
    assert [row["stable"] for row in rows] == [True, False, True]
    assert rows[0]["max_position_error_m"] < STABLE_POSITION_ERROR and rows[1]["diverged"]
    assert "0.5 m over the last third of the run" in SETTLED_DEFINITION


@pytest.mark.parametrize(("bound", "h", "signal"), [(1e6, 0.2, None), (1e-3, 1e-3, "MobileRobot.x")],
                         ids=["destabilising-step", "tiny-bound"])
def test_a_diverging_run_is_a_row_with_its_reason(short, fmu_paths, tmp_path, bound, h, signal):
    scenario = short.with_simulation(stop_time=10.0, bound=bound)
    with Cosimulator(fmu_paths, tmp_path) as simulator:
        row = run_case(scenario, Case(h), simulator, None)
    assert row["diverged"] is True and row["stable"] is False
    assert row["diverged_signal"] == (signal or row["diverged_signal"]) and row["diverged_signal"]
    assert row["diverged_time"] == (0.0 if signal else row["diverged_time"]) and row["diverged_time"] < 10.0
    assert "diverged at t = " in row["diverged_reason"] or "failed at t = " in row["diverged_reason"]
    assert math.isnan(row["max_position_deviation_m"]) and math.isnan(row["final_position_error_m"])
    if signal is None:  # found after the step that reached diverged_time, or at the exchange there
        assert row["diverged_time"] > 0 and row["steps"] in (round(row["diverged_time"] / h) - 1,
                                                             round(row["diverged_time"] / h))


# --- the cache ---------------------------------------------------------------------------------------------------


def test_second_execute_runs_nothing_and_a_new_step_only_itself(short, fmu_paths, tmp_path, counted):
    cases = build_cases(short, step_sizes=[2e-3, 0.01], orders=ORDERS)
    done = execute(short, cases, tmp_path, fmu_paths, Runner(jobs=1, progress=False))
    first = done.rows
    assert counted == {"run": 4, "reference": 1} and (done.cached, done.ran) == (0, 4)
    files = {p: p.stat().st_mtime_ns for p in (tmp_path / "cache").rglob("*")}
    assert len(files) == 2 + 4 * 2 + 2  # two folders, a record and a trajectory per run, one reference and its record
    again = execute(short, cases, tmp_path, fmu_paths, Runner(jobs=1, progress=False))
    assert counted == {"run": 4, "reference": 1} and (again.cached, again.ran, again.unverified) == (4, 0, ())
    assert json.dumps(again.rows) == json.dumps(first)  # wall times too: they come from the cache
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "cache").rglob("*")} == files
    done = execute(short, build_cases(short, step_sizes=[2e-3, 5e-3, 0.01], orders=ORDERS), tmp_path, fmu_paths,
                   Runner(jobs=1, progress=False))
    more = done.rows
    assert counted == {"run": 6, "reference": 1}  # the reference of the physical case is cached too
    assert (done.cached, done.ran) == (4, 2)
    assert json.dumps([more[0], more[1], more[4], more[5]]) == json.dumps(first)
    trajectory = load_trajectory(tmp_path, first[0])
    assert trajectory.dtype.names == TRAJECTORY and len(trajectory) == 101 and trajectory["time"][-1] == 1.0
    reference = load_reference(tmp_path, first[0])
    assert len(reference) == 1001 and reference["time"][-1] == 1.0 and reference["x"][0] == short.plant["x0"]
    assert len({row["reference_key"] for row in more}) == 1
    assert leftovers(tmp_path) == []


def test_a_changed_scenario_value_or_fmu_build_invalidates(short, fmu_paths, tmp_path, counted, monkeypatch):
    cases = [Case(0.01), Case(0.01, "jacobi")]
    execute(short, cases, tmp_path, fmu_paths, Runner(jobs=1, progress=False))
    renamed = dataclasses.replace(short, name="renamed", source="elsewhere.toml")
    rows = execute(renamed, cases, tmp_path, fmu_paths, Runner(jobs=1, progress=False)).rows
    assert counted["run"] == 2 and {row["scenario"] for row in rows} == {"renamed"}  # name and file do not count
    changed = dataclasses.replace(short, controller={**short.controller, "k5": 1.5})
    execute(changed, cases, tmp_path, fmu_paths, Runner(jobs=1, progress=False))
    assert counted == {"run": 4, "reference": 2}
    monkeypatch.setattr(sweep_cache, "fmu_build_id", lambda path: f"rebuilt {path.name}")
    rows = execute(short, cases, tmp_path, fmu_paths, Runner(jobs=1, progress=False)).rows
    assert counted == {"run": 6, "reference": 2}  # same physics: the reference solution is still valid
    assert rows[0]["key"] == sweep_cache.case_key(short, cases[0], sweep_cache.fmu_identities(fmu_paths))


def test_a_partial_cache_entry_is_a_miss(short, fmu_paths, tmp_path, counted):
    """A trajectory without its record (a write interrupted between the two) is a plain miss."""
    [row] = execute(short, [Case(0.01)], tmp_path, fmu_paths, Runner(jobs=1, progress=False)).rows
    (tmp_path / "cache" / "runs" / f"{row['key']}.json").unlink()
    again = execute(short, [Case(0.01)], tmp_path, fmu_paths, Runner(jobs=1, progress=False))
    assert again.rows[0]["key"] == row["key"] and again.unverified == ()
    assert counted["run"] == 2
    assert not list((tmp_path / "cache").rglob("*.partial"))


# --- execution and cleanup --------------------------------------------------------------------------------------


def test_diverging_cases_are_rows_in_a_sweep(short, fmu_paths, tmp_path):
    rows = execute(short.with_simulation(stop_time=5.0), [Case(0.01), Case(0.25)], tmp_path, fmu_paths,
                   Runner(jobs=1, progress=False)).rows
    assert [row["diverged"] for row in rows] == [False, True]
    assert rows[1]["diverged_time"] > 0 and rows[1]["diverged_signal"]


def test_an_interrupted_sweep_cleans_up_and_resumes(short, fmu_paths, tmp_path, monkeypatch):
    calls = []
    simulate = sweep_rows.simulate

    def interrupted(*args):
        calls.append(args)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return simulate(*args)

    monkeypatch.setattr(sweep_execute, "simulate", interrupted)
    cases = [Case(0.01), Case(0.02), Case(0.05)]
    with pytest.raises(KeyboardInterrupt):
        execute(short, cases, tmp_path, fmu_paths, Runner(jobs=1, progress=False))
    assert leftovers(tmp_path) == []
    assert len(list((tmp_path / "cache" / "runs").glob("*.json"))) == 1
    calls.clear()
    monkeypatch.setattr(sweep_execute, "simulate", lambda *args: calls.append(args) or simulate(*args))
    rows = execute(short, cases, tmp_path, fmu_paths, Runner(jobs=1, progress=False)).rows
    assert len(calls) == 2 and [row["step_size"] for row in rows] == [0.01, 0.02, 0.05]
    assert leftovers(tmp_path) == []


def test_a_failing_sweep_cleans_up(short, fmu_paths, tmp_path, monkeypatch):
    def failing(*args):
        raise RuntimeError("boom")

    monkeypatch.setattr(sweep_execute, "simulate", failing)
    with pytest.raises(RuntimeError, match="boom"):
        execute(short, [Case(0.01), Case(0.02)], tmp_path, fmu_paths, Runner(jobs=1, progress=False))
    assert leftovers(tmp_path) == []


@pytest.mark.slow
def test_two_jobs_give_the_rows_of_one(short, fmu_paths, tmp_path):
    scenario = short.with_simulation(stop_time=5.0)  # long enough for h = 0.25 s to diverge
    cases = build_cases(scenario, step_sizes=[4e-3, 0.02, 0.25], orders=ORDERS, sets=[parse_set("controller.k4=0.5,1")])
    one = execute(scenario, cases, tmp_path / "one", fmu_paths, Runner(jobs=1, progress=False)).rows
    two = execute(scenario, cases, tmp_path / "two", fmu_paths, Runner(jobs=2, progress=False)).rows
    assert without_wall_time(two) == without_wall_time(one)
    assert any(row["diverged"] for row in one) and not all(row["diverged"] for row in one)
    assert leftovers(tmp_path / "two") == []


@pytest.mark.slow
def test_a_failing_worker_is_reported_and_cleaned_up(short, fmu_paths, tmp_path):
    broken = tmp_path / "broken.fmu"
    broken.write_text("not an FMU")
    paths = {**fmu_paths, "DSCController": broken}
    with pytest.raises(CosimulationError, match=r"broken\.fmu: not a valid FMU for DSCController"):
        execute(short, [Case(0.01), Case(0.02)], tmp_path / "out", paths, Runner(jobs=2, progress=False))
    assert leftovers(tmp_path / "out") == []


@pytest.mark.slow
def test_an_interrupt_stops_the_pool_and_cleans_up(short, fmu_paths, tmp_path, monkeypatch):
    """Ctrl-C in the parent while the workers run: they are stopped, .work is removed, and the
    rows cached before the interrupt (here: the first one) are kept; the next sweep resumes."""
    psutil = pytest.importorskip("psutil")
    store_run = sweep_cache.SweepCache.store_run
    stored = []

    def interrupted(self, key, row, trajectory, fmus):
        if stored:
            raise KeyboardInterrupt
        stored.append(key)
        store_run(self, key, row, trajectory, fmus)

    monkeypatch.setattr(sweep_cache.SweepCache, "store_run", interrupted)
    cases = [Case(h, order) for h in (1e-3, 2e-3, 5e-3) for order in ORDERS]
    with pytest.raises(KeyboardInterrupt):
        execute(short, cases, tmp_path, fmu_paths, Runner(jobs=2, progress=False))
    workers = [p for p in psutil.Process().children(recursive=True) if "spawn_main" in " ".join(p.cmdline())]
    assert workers == [] and leftovers(tmp_path) == []
    assert [p.stem for p in (tmp_path / "cache" / "runs").glob("*.json")] == stored
    monkeypatch.setattr(sweep_cache.SweepCache, "store_run", store_run)
    rows = execute(short, cases, tmp_path, fmu_paths, Runner(jobs=2, progress=False)).rows
    assert len({row["key"] for row in rows}) == 6 and stored[0] in {row["key"] for row in rows}


def test_an_unreachable_scheduler_fails_fast_and_writes_nothing(short, fmu_paths, tmp_path):
    started = time.perf_counter()
    with pytest.raises(SweepError, match=r"cannot reach the Dask scheduler at tcp://127\.0\.0\.1:1 within 1 s") as info:
        execute(short, [Case(0.01)], tmp_path / "out", fmu_paths,
                Runner(scheduler="tcp://127.0.0.1:1", scheduler_timeout=1, progress=False))
    assert time.perf_counter() - started < 10
    assert "\n" not in str(info.value)
    assert not (tmp_path / "out").exists()


def test_a_sweep_checks_its_folder_and_scheduler_once_for_all_its_executions(short, fmu_paths, tmp_path, monkeypatch):
    from dsc_fmu.study.cases import Grid
    from dsc_fmu.study.sweep import run_sweep
    prepared, prepare = [], sweep_execute.prepare_sweep
    monkeypatch.setattr(sweep_execute, "prepare_sweep", lambda *args: prepared.append(args) or prepare(*args))
    runner, out = Runner(jobs=1, progress=False), tmp_path / "out"
    run_sweep(short, out, Grid(step_sizes=[0.01, 0.02], orders=["jacobi"], couplings=["hold"], tolerances=[]), runner,
              fmu_dir=next(iter(fmu_paths.values())).parent, refine=False)
    assert prepared == [(out, runner)]
    execute(short, [Case(0.01, "jacobi")], out, fmu_paths, runner)  # alone, execute checks for itself
    assert prepared == [(out, runner)] * 2


def test_a_case_holds_its_order_and_coupling_as_their_types():
    case = Case(1e-3, "jacobi", coupling="linear")
    assert (case.order, case.coupling) == (Order.JACOBI, Coupling.LINEAR) and not case.order.sequential
    assert dataclasses.replace(case, step_size=2e-3).coupling.order == 2
    refused = {"order": ("backwards", "gauss-seidel, jacobi"), "coupling": ("cubic", "hold, linear"),
               "discretization": ("tustin", "rk4, euler")}
    for key, (value, allowed) in refused.items():
        message = f"{key} = {value!r} is not allowed; allowed: {allowed}"
        with pytest.raises(ScenarioError, match=f"^{re.escape(message)}$"):
            Case(1e-3, **{key: value})


def test_the_dask_plugin_loads_the_fmus_once_per_worker_and_removes_them(short, fmu_paths, tmp_path, monkeypatch):
    """On a worker, the plugin writes the FMUs into its local directory; every run there uses one
    Cosimulator; its teardown (the sweep's end, or the worker's) removes the folder."""
    plugin = sweep_dask.FmusOnWorkers(fmu_paths, sweep_execute._Fmus)
    worker = types.SimpleNamespace(local_directory=str(tmp_path), plugins={plugin.name: plugin})
    monkeypatch.setattr(sweep_dask.distributed, "get_worker", lambda: worker)
    plugin.setup(worker)
    folder = plugin.fmus.folder
    assert folder.parent == tmp_path
    assert sorted(p.name for p in folder.iterdir()) == sorted(f"{name}.fmu" for name in fmu_paths)
    outcomes = [sweep_dask.on_worker(plugin.name, sweep_execute._Fmus.simulate, apply(short, Case(h)))
                for h in (0.01, 0.02)]
    assert all(outcome.metrics is not None for outcome in outcomes)
    assert plugin.fmus._cosimulator.runs == 2  # the same Cosimulator, reused
    plugin.teardown(worker)
    assert not folder.exists()


def test_two_sweeps_of_the_same_fmus_get_a_plugin_each(fmu_paths):
    """A Dask worker replaces (and tears down) a plugin registered under a name it holds: two sweeps of the
    same FMUs on one cluster must not share a name, or the second would free the first's FMUs."""
    names = {sweep_dask.FmusOnWorkers(fmu_paths, sweep_execute._Fmus).name for _ in range(2)}
    assert len(names) == 2


def test_closing_a_worker_fmus_waits_for_the_run_in_progress(fmu_paths, tmp_path):
    """A plugin's teardown (Ctrl-C, the sweep's end) while a run goes on frees the FMUs only after it."""
    fmus = sweep_execute._Fmus(fmu_paths, tmp_path / "work")
    running, finish, seen = threading.Event(), threading.Event(), []

    def run(place, applied):
        running.set()
        finish.wait(10)
        seen.append(place.folder.exists())

    (tmp_path / "work").mkdir()
    computing = threading.Thread(target=fmus.compute, args=(run, None))
    computing.start()
    running.wait(10)
    closing = threading.Thread(target=fmus.close)
    closing.start()
    closing.join(0.2)
    assert closing.is_alive()  # waiting for the run
    finish.set()
    computing.join(10)
    closing.join(10)
    assert seen == [True] and not (tmp_path / "work").exists()


@pytest.mark.slow
def test_a_dask_cluster_gives_the_rows_of_a_local_run(short, fmu_paths, tmp_path):
    distributed = pytest.importorskip("distributed")
    scenario = short.with_simulation(stop_time=5.0)  # long enough for h = 0.25 s to diverge
    cases = build_cases(scenario, step_sizes=[4e-3, 0.02, 0.25], orders=ORDERS, sets=[parse_set("controller.k4=0.5,1")])
    local = execute(scenario, cases, tmp_path / "local", fmu_paths, Runner(jobs=1, progress=False)).rows
    scratch = tmp_path / "dask"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  host="127.0.0.1", local_directory=str(scratch)) as cluster:
        remote = execute(scenario, cases, tmp_path / "remote", fmu_paths,
                         Runner(scheduler=cluster.scheduler_address, progress=False)).rows
        assert not any(scratch.rglob("dsc_fmu_sweep_*"))  # removed from the workers when the sweep ends
    assert without_wall_time(remote) == without_wall_time(local)
    assert any(row["diverged"] for row in local) and not all(row["diverged"] for row in local)
    assert not (tmp_path / "remote" / ".work").exists()


def test_cache_files_are_complete_or_absent(tmp_path):
    target = tmp_path / "a" / "row.json"
    atomic_write(target, b"{}")
    with pytest.raises(TypeError):  # a write that fails midway leaves no file behind
        atomic_write(tmp_path / "a" / "other.json", object())
    assert target.read_bytes() == b"{}" and [p.name for p in target.parent.iterdir()] == ["row.json"]


def _trajectory_with_error(error):
    t = np.linspace(0.0, 30.0, len(error))
    out = np.zeros(len(t), dtype=[(n, float) for n in ("time", "x", "y", "x_r", "y_r")])
    out["time"], out["x_r"], out["x"] = t, error, 0.0
    return out


@pytest.mark.parametrize("shape, grows", [
    (lambda t: 0.5 * np.exp(-t / 5.0), False),                       # converging
    (lambda t: 0.01 + 0.002 * np.sin(7.0 * t), False),              # steady small oscillation
    (lambda t: 0.005 * np.exp(t / 8.0) * np.abs(np.sin(3.0 * t)), True),  # slow exponential growth
    (lambda t: 0.001 * (t > 28.0), False),                          # a step within the 1 mm slack
])
def test_error_growth_criterion(shape, grows):
    from dsc_fmu.study.rows import error_grows
    t = np.linspace(0.0, 30.0, 3001)
    assert error_grows(_trajectory_with_error(shape(t))) is grows


@pytest.mark.parametrize("shape, grows", [
    (lambda t: 1e-4 * np.exp(-t / 5.0), False),                                   # the start's seed decays
    (lambda t: 1e-4 * (1.0 + 0.5 * np.sin(2.0 * t)), False),                       # stays at the seed's level
    (lambda t: 1e-4 * np.exp(np.minimum(t, 8.0)) * np.exp(-np.maximum(t - 8.0, 0.0) / 3.0), True),  # grows, then damped
    (lambda t: 1e-6 * np.exp(t / 15.0), False),                                    # grows within the 0.01 mm slack
])
def test_local_stability_criterion(shape, grows):
    """The deviation from the reference solution against its level over the first twentieth of the run."""
    from dsc_fmu.study.rows import deviation_grows, position_deviation
    t = np.linspace(0.0, 30.0, 3001)
    reference = np.zeros(len(t), dtype=[(n, float) for n in ("time", "x", "y")])
    reference["time"], reference["x"], reference["y"] = t, np.cos(0.2 * t), np.sin(0.2 * t)
    run = reference.copy()
    run["y"] += shape(t)
    np.testing.assert_allclose(position_deviation(run, reference), shape(t), rtol=1e-12, atol=1e-15)
    assert deviation_grows(run, reference) is grows


def test_the_scenario_chooses_the_stability_definition(short):
    from dsc_fmu.study.rows import LOCAL_DEFINITION, SETTLED_DEFINITION, stability_definition
    assert load_scenario("on_reference").simulation.stability == "local"
    assert stability_definition(short.simulation.stability) == SETTLED_DEFINITION != LOCAL_DEFINITION
    with pytest.raises(ScenarioError, match=r"\[simulation\] stability = 'loose' is not allowed; allowed: settled, local"):
        short.with_simulation(stability="loose")


@pytest.mark.parametrize("times", [np.linspace(0.0, 0.5, 51), np.arange(0.0, 30.0 + 1e-9, 2.5), np.array([0.0, 0.3, 0.6])],
                         ids=["shorter-than-the-window", "steps-longer-than-the-window", "three-rows"])
def test_local_stability_needs_a_seed_window_with_rows_after_the_start(times):
    """The deviation is 0 at t = 0: the seed window holds the first second and at least three rows after
    it, and a run that ends within it is not judged at all."""
    from dsc_fmu.study.rows import deviation_grows
    reference = np.zeros(len(times), dtype=[(n, float) for n in ("time", "x", "y")])
    reference["time"] = times
    run = reference.copy()
    run["y"] = 1e-4 * np.minimum(times, 0.2) / 0.2  # reaches its level within 0.2 s, then stays
    assert deviation_grows(run, reference) is False
    run["y"][-1] *= 10.0
    assert deviation_grows(run, reference) is bool(len(times) > 4 and times[-1] > max(1.0, times[3]))


def test_a_row_says_which_definition_judged_it(fmu_paths):
    """on_reference ("local"): a fixed-step run whose deviation grows is unstable; without a reference
    solution, or error-controlled, the same run is judged as a settled one (and stable)."""
    from dsc_fmu.study.rows import METRIC_KEYS, TRAJECTORY, Outcome, make_row
    scenario = load_scenario("on_reference")
    t = np.linspace(0.0, 30.0, 3001)
    trajectory = np.zeros(len(t), dtype=[(n, float) for n in TRAJECTORY])
    grown_then_damped = 1e-4 * np.exp(np.minimum(t, 8.0)) * np.exp(-np.maximum(t - 8.0, 0.0) / 3.0)
    trajectory["time"], trajectory["x"], trajectory["x_r"] = t, grown_then_damped, 0.0
    reference = np.zeros(len(t), dtype=[(n, float) for n in sweep_rows.REFERENCE_COLUMNS])
    reference["time"] = t
    outcome = Outcome(trajectory, dict.fromkeys(METRIC_KEYS, 0.01), steps=1500, steps_rejected=0, fmu_steps=4500,
                      wall_time_s=1.0)
    judged = {}
    for name, case, with_reference in (("local", Case(0.02), True), ("no reference", Case(0.02), False),
                                       ("error-controlled", Case(0.02, coupling="linear", tolerance=1e-3), True)):
        row = make_row(Plan(case, apply(scenario, case), "k", "r"), outcome, reference if with_reference else None)
        judged[name] = (row["stability"], row["stable"])
    assert judged == {"local": ("local", False), "no reference": ("settled", True),
                      "error-controlled": ("settled", True)}


def test_a_scenario_with_input_derivatives_sweeps_both_couplings(short):
    """The standard route carries over to the linear fixed-step cases; the others run on the parameters."""
    routed = short.with_simulation(coupling="linear", input_derivatives=True)
    cases = build_cases(routed, step_sizes=[1e-3], orders=ORDERS, couplings=["hold", "linear"], tolerances=[1e-3])
    assert {(c.coupling, c.tolerance, apply(routed, c).simulation.input_derivatives) for c in cases} == {
        ("hold", None, False), ("linear", None, True), ("linear", 1e-3, False)}


def test_an_error_controlled_run_that_cannot_meet_its_tolerance_is_reported_with_why(short, fmu_paths, tmp_path):
    from dsc_fmu.study.cases import Grid
    from dsc_fmu.study.sweep import run_sweep
    text = run_sweep(short.with_simulation(stop_time=1.0), tmp_path / "out",
                     Grid(step_sizes=[0.01], couplings=["hold"], tolerances=[1e-9]), Runner(jobs=1, progress=False),
                     fmu_dir=next(iter(fmu_paths.values())).parent, refine=False)
    why = "the error-controlled step cannot meet the tolerance 1e-09 m at t = 0 s"
    assert f"  gauss-seidel/rk4 error-controlled, tolerance 1e-09 m: failed: {why}" in text
    report = (tmp_path / "out" / "report.md").read_text()
    assert f"- gauss-seidel/rk4 error-controlled, tolerance 1e-09 m, failed: {why}" in report


def test_boundary_notes_say_why_a_prediction_is_off():
    from dsc_fmu.study.analysis import Boundary
    from dsc_fmu.study.sweep import RECOVERY_NOTE, TRANSIENT_NOTE, boundary_notes
    measured = {"a": Boundary(0.01, 0.0102, ()), "b": Boundary(0.04, 0.0408, ())}
    assert boundary_notes({"a": 0.0115, "b": 0.033, "c": 0.5}, measured, "settled") == []  # within 20 %, unmeasured
    assert boundary_notes({"a": 0.013}, measured, "settled") == [TRANSIENT_NOTE]  # predicted above the measured
    assert boundary_notes({"b": 0.03}, measured, "settled") == [RECOVERY_NOTE]  # predicted below the measured
    assert boundary_notes({"b": 0.03}, measured, "local") == []
    assert boundary_notes({"a": 0.013, "b": 0.03}, measured, "settled") == [TRANSIENT_NOTE, RECOVERY_NOTE]
    assert boundary_notes({"a": math.nan, "b": 0.0}, measured, "settled") == []


def test_a_local_run_without_its_reference_is_judged_as_settled_and_not_cached(fmu_paths, tmp_path, monkeypatch):
    scenario = load_scenario("on_reference").with_simulation(stop_time=2.0)
    monkeypatch.setattr(sweep_execute, "compute_reference",
                        lambda applied, fmu_paths: sweep_rows.ReferenceOutcome(None, "solver gave up"))
    with pytest.warns(UserWarning, match=r"reference solution failed \(solver gave up\): deviations are NaN for its "
                                         r"runs; they are judged as settled runs and not cached"):
        row, = execute(scenario, [Case(0.01)], tmp_path, fmu_paths, Runner(jobs=1, progress=False)).rows
    assert row["stability"] == "settled" and math.isnan(row["max_position_deviation_m"])
    assert not list((tmp_path / "cache" / "runs").glob("*.json"))
    monkeypatch.undo()
    row, = execute(scenario, [Case(0.01)], tmp_path, fmu_paths, Runner(jobs=1, progress=False)).rows
    assert row["stability"] == "local" and row["max_position_deviation_m"] < 1e-3


def test_a_local_run_shorter_than_its_seed_window_is_judged_as_settled(fmu_paths, tmp_path):
    scenario = load_scenario("on_reference").with_simulation(stop_time=0.5)
    case = Case(0.01)
    reference, why = sweep_rows.compute_reference(apply(scenario, case))
    with Cosimulator(fmu_paths, tmp_path) as simulator:
        row = run_case(scenario, case, simulator, reference)
    assert why is None and (row["stability"], row["stable"]) == ("settled", True)


def test_the_reference_through_model_exchange_measures_the_same_deviations(fmu_paths, tmp_path):
    """reference = "model-exchange": the three FMUs as one ODE at 1e-10 in place of the monolithic ODE;
    the same equations, so the same deviations to far below the coupling error, under a key of its own
    that names the FMUs."""
    scenario = load_scenario("paper").with_simulation(stop_time=2.0)
    rows = {}
    for reference in REFERENCES:
        applied = scenario.with_simulation(reference=reference)
        rows[reference], = execute(applied, [Case(0.01)], tmp_path / reference, fmu_paths, Runner(jobs=1, progress=False)).rows
    monolithic, through_fmus = rows["monolithic"], rows["model-exchange"]
    assert monolithic["reference_key"] != through_fmus["reference_key"]
    for key in ("max_position_deviation_m", "rms_position_deviation_m", "max_u_deviation_V"):
        assert through_fmus[key] == pytest.approx(monolithic[key], rel=1e-4, abs=1e-7), key
    assert monolithic["max_position_deviation_m"] > 1e-3  # the coupling error the two references agree on
