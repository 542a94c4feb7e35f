"""Running a sweep: one case to one row, cached, in this process, on a process pool or on a Dask cluster."""

from __future__ import annotations

import json
import math
import multiprocessing
import multiprocessing.util
import os
import shutil
import signal
import sys
import tempfile
import time as clock
import warnings
from collections import Counter, defaultdict
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from tqdm import tqdm

from .master import CosimulationError, Cosimulator
from .metrics import tracking_metrics
from .scenario import Scenario
from .sweep import Case, SweepError, apply
from .sweep_cache import REFERENCE_GRID, REFERENCE_SETTINGS, SweepCache, case_key, fmu_identities, reference_key

__all__ = [
    "STABLE_POSITION_ERROR", "STABILITY_DEFINITION", "error_grows", "TRAJECTORY", "REFERENCE_COLUMNS", "ROW_KEYS", "simulate",
    "compute_reference", "make_row", "deviations", "run_case", "execute", "load_trajectory", "load_reference",
]

STABLE_POSITION_ERROR = 0.5  # m
GROWTH_FACTOR, GROWTH_SLACK = 1.25, 1e-3  # 1, m
STABILITY_DEFINITION = (
    "A run is stable if it did not diverge (every exchanged signal stayed finite and within the scenario's "
    f"bound, and no FMU failed), its position error sqrt(xe^2 + ye^2) stayed below {STABLE_POSITION_ERROR:g} m "
    "over the last third of the run, and it did not grow there: its maximum over the last sixth of the run is "
    f"at most {GROWTH_FACTOR:g} times its maximum over the sixth before, plus {GROWTH_SLACK * 1e3:g} mm (a slowly "
    "growing oscillation, a spectral radius just above 1, is unstable even if it has not diverged yet). The "
    "criterion assumes a run long enough for the start-up transient to have decayed by its last third "
    "(30 s for the paper's scenario)."
)
TRAJECTORY = ("time", "x", "y", "theta", "x_r", "y_r", "theta_r", "u1", "u2")
REFERENCE_COLUMNS = ("time", "x", "y", "theta", "u1", "u2")
METRIC_KEYS = ("final_position_error_m", "rms_position_error_m", "max_position_error_m", "max_abs_thetae_rad",
               "settling_time_0p1_s", "max_abs_u_V", "beta_guard_count")
DEVIATION_KEYS = ("max_position_deviation_m", "rms_position_deviation_m", "max_heading_deviation_rad",
                  "rms_heading_deviation_rad", "max_u_deviation_V", "rms_u_deviation_V")
ROW_KEYS = ("scenario", "step_size", "order", "discretization", "sample", "<table.name of each override>", "key",
            "reference_key", "diverged", "diverged_time", "diverged_signal", "diverged_reason", "stable",
            *DEVIATION_KEYS, *METRIC_KEYS, "wall_time_s", "steps")


def _columns(result: np.ndarray, names) -> np.ndarray:
    """The columns ``names`` of a structured array, as a new compact array."""
    out = np.zeros(len(result), dtype=[(name, np.float64) for name in names])
    for name in names:
        out[name] = result[name]
    return out


def simulate(applied: Scenario, cosimulator: Cosimulator) -> dict:
    """Run ``applied`` (a case applied to its scenario) and return what the row needs: the trajectory,
    the tracking metrics (None if it diverged), the divergence, the steps and the wall time (s)."""
    started = clock.perf_counter()
    try:
        run = cosimulator.run(applied)
    except CosimulationError as error:
        return {"trajectory": _columns(error.result, TRAJECTORY), "metrics": None, "diverged_time": float(error.time),
                "diverged_signal": error.signal or error.fmu, "diverged_reason": " ".join(str(error).split()),
                "steps": error.steps, "wall_time_s": clock.perf_counter() - started}
    metrics = tracking_metrics(run.result, applied.simulation.stop_time)
    return {"trajectory": _columns(run.result, TRAJECTORY), "metrics": {k: metrics[k] for k in METRIC_KEYS},
            "diverged_time": math.nan, "diverged_signal": None, "diverged_reason": None, "steps": run.steps,
            "wall_time_s": clock.perf_counter() - started}


def compute_reference(applied: Scenario) -> tuple[np.ndarray | None, str | None]:
    """The reference solution of ``applied`` on a ``REFERENCE_GRID`` grid up to its stop time
    (``REFERENCE_COLUMNS``), or None and why the solver failed."""
    from .reference_solution import output_times, reference_solution  # scipy: only where references are computed

    times = output_times(applied.simulation.stop_time, REFERENCE_GRID)
    try:
        solution = reference_solution(applied, times=times, **REFERENCE_SETTINGS)
    except (RuntimeError, ArithmeticError, ValueError) as error:
        return None, " ".join(str(error).split())
    return _columns(solution, REFERENCE_COLUMNS), None


def error_grows(trajectory: np.ndarray) -> bool:
    """Whether the position error grows over the last third of the run (``STABILITY_DEFINITION``)."""
    t = trajectory["time"]
    error = np.hypot(trajectory["x_r"] - trajectory["x"], trajectory["y_r"] - trajectory["y"])
    end = t[-1]
    earlier = error[(t >= 2.0 * end / 3.0) & (t < 5.0 * end / 6.0)]
    later = error[t >= 5.0 * end / 6.0]
    if not len(earlier) or not len(later):
        return False
    return bool(later.max() > GROWTH_FACTOR * earlier.max() + GROWTH_SLACK)


def deviations(trajectory: np.ndarray, reference: np.ndarray) -> dict:
    """Largest and RMS deviation of a run from the reference solution (interpolated linearly at the
    run's times) over all its rows: position (m), wrapped heading (rad), voltage of both wheels (V)."""
    t = trajectory["time"]
    at = {name: np.interp(t, reference["time"], reference[name]) for name in REFERENCE_COLUMNS[1:]}
    position = np.hypot(trajectory["x"] - at["x"], trajectory["y"] - at["y"])
    heading = np.abs(np.remainder(trajectory["theta"] - at["theta"] + np.pi, 2.0 * np.pi) - np.pi)
    voltage = np.abs(np.concatenate([trajectory["u1"] - at["u1"], trajectory["u2"] - at["u2"]]))
    values = {}
    for name, error, unit in (("position", position, "m"), ("heading", heading, "rad"), ("u", voltage, "V")):
        values[f"max_{name}_deviation_{unit}"] = float(np.max(error))
        values[f"rms_{name}_deviation_{unit}"] = float(np.sqrt(np.mean(error**2)))
    return values


def make_row(scenario_name: str, case: Case, keys: tuple[str, str], outcome: dict,
             reference: np.ndarray | None) -> dict:
    """The row (``ROW_KEYS``; JSON-serialisable, NaN where a value does not apply) of a simulated case;
    ``keys`` are its cache key and that of its reference solution."""
    diverged = outcome["metrics"] is None
    metrics = dict.fromkeys(METRIC_KEYS, math.nan) if diverged else outcome["metrics"]
    row = {"scenario": scenario_name, "step_size": case.step_size, "order": case.order,
           "discretization": case.discretization, "sample": case.sample, **dict(case.overrides), "key": keys[0],
           "reference_key": keys[1],
           "diverged": diverged, "diverged_time": outcome["diverged_time"],
           "diverged_signal": outcome["diverged_signal"], "diverged_reason": outcome["diverged_reason"],
           "stable": not diverged and metrics["max_position_error_m"] < STABLE_POSITION_ERROR
           and not error_grows(outcome["trajectory"])}
    usable = not diverged and reference is not None and len(outcome["trajectory"])
    row.update(deviations(outcome["trajectory"], reference) if usable else dict.fromkeys(DEVIATION_KEYS, math.nan))
    row.update({name: math.nan if value is None else value for name, value in metrics.items()})
    row.update(wall_time_s=outcome["wall_time_s"], steps=outcome["steps"])
    return json.loads(json.dumps(row))  # exactly what the cache gives back


def run_case(scenario: Scenario, case: Case, cosimulator: Cosimulator, reference: np.ndarray | None) -> dict:
    """Run one case with ``cosimulator`` and return its row; ``reference`` is the reference solution
    of the case's physical scenario (``reference_solution(apply(scenario, case), times=...)``,
    at least the ``REFERENCE_COLUMNS``), or None to leave the deviations NaN."""
    keys = case_key(scenario, case, fmu_identities(cosimulator.paths)), reference_key(scenario, case)
    return make_row(scenario.name, case, keys, simulate(apply(scenario, case), cosimulator), reference)


def load_trajectory(out_dir: Path | str, row_or_key: dict | str) -> np.ndarray:
    """The trajectory (``TRAJECTORY`` columns, as recorded; up to the failure for a diverged run)
    of a run cached in the sweep folder ``out_dir``, given its row or its key."""
    key = row_or_key["key"] if isinstance(row_or_key, dict) else row_or_key
    return SweepCache(out_dir).trajectory(key)


def load_reference(out_dir: Path | str, row_or_key: dict | str) -> np.ndarray | None:
    """The reference solution (``REFERENCE_COLUMNS`` every ``REFERENCE_GRID`` s) of a row cached in
    the sweep folder ``out_dir``, given the row or its ``reference_key``; None if the solver failed."""
    key = row_or_key["reference_key"] if isinstance(row_or_key, dict) else row_or_key
    return SweepCache(out_dir).reference(key)


# --- where the tasks run: this process, a process pool (one Cosimulator per worker), a Dask cluster ---

_WORKER: dict = {}


def _init_pool_worker(fmu_paths: dict, work: str) -> None:
    """Pool initializer: this worker's one Cosimulator, extracted into ``work/<pid>``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle: it stops the pool
    try:
        folder = Path(work) / str(os.getpid())
        folder.mkdir(parents=True, exist_ok=True)
        simulator = Cosimulator(fmu_paths, folder)
    except Exception as error:  # noqa: BLE001 - reported by the first run, not as a broken pool
        _WORKER["error"] = error
        return
    _WORKER["simulator"] = simulator
    multiprocessing.util.Finalize(None, simulator.close, exitpriority=10)  # workers exit without atexit


def _pool_run(applied: Scenario) -> dict:
    if "error" in _WORKER:
        raise _WORKER["error"]
    return simulate(applied, _WORKER["simulator"])


def _in_process(tasks, fmu_paths, work: Path):
    """Run the tasks here, one after the other, with one Cosimulator."""
    simulator = None
    try:
        for kind, tag, applied in tasks:
            if kind == "reference":
                yield kind, tag, compute_reference(applied)
                continue
            if simulator is None:
                folder = work / str(os.getpid())
                folder.mkdir(parents=True, exist_ok=True)
                simulator = Cosimulator(fmu_paths, folder)
            yield kind, tag, simulate(applied, simulator)
    finally:
        if simulator is not None:
            simulator.close()


def _pool(tasks, fmu_paths, work: Path, jobs: int):
    """Run the tasks on ``jobs`` worker processes (spawned), each with its own Cosimulator."""
    executor = ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_init_pool_worker, initargs=(dict(fmu_paths), str(work)))
    finished = False
    try:
        pending = {executor.submit(compute_reference if kind == "reference" else _pool_run, applied): (kind, tag)
                   for kind, tag, applied in tasks}
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                kind, tag = pending.pop(future)
                yield kind, tag, future.result()
        finished = True
    finally:
        if not finished:  # interrupted or failed: stop the workers now rather than after their current runs
            for process in list((getattr(executor, "_processes", None) or {}).values()):
                process.terminate()
        executor.shutdown(wait=True, cancel_futures=True)


def execute(scenario: Scenario, cases: list[Case], out_dir: Path | str, fmu_paths: dict, jobs: int | None = None,
            scheduler: str | None = None, progress: bool = True, *, scheduler_timeout: float = 10.0) -> list[dict]:
    """Run every case not yet cached in ``out_dir`` and return all rows, in the order of ``cases``.

    Locally (no ``scheduler``), ``jobs`` worker processes (default: ``os.cpu_count()``; 1 runs in
    this process) each load the FMUs once (into ``out_dir/.work``, removed at the end whatever
    happens). With ``scheduler = "tcp://host:port"`` the runs go to that Dask cluster instead
    (``jobs`` does not apply; SweepError if it cannot be reached within ``scheduler_timeout`` s, and
    nothing is written then). Each finished run is cached at once (``sweep_cache``), so an
    interrupted sweep resumes where it stopped; cached cases are not run again. Reference solutions
    are computed once per physical case and cached too. ``progress`` shows a bar on stderr.
    """
    out_dir, cache = Path(out_dir), SweepCache(out_dir)
    identities = fmu_identities(fmu_paths)
    plans = [(case, apply(scenario, case), case_key(scenario, case, identities), reference_key(scenario, case))
             for case in cases]
    done, todo, needed = {}, {}, {}
    for case, applied, key, ref_key in plans:
        if key in done or key in todo:
            continue
        cached = cache.row(key)
        if cached is not None:
            done[key] = {**cached, "scenario": scenario.name}
        else:
            todo[key] = (case, applied, ref_key)
            needed.setdefault(ref_key, applied)
    if todo:
        jobs = (os.cpu_count() or 1) if jobs is None else jobs
        if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
            raise SweepError(f"jobs = {jobs!r} is not allowed; allowed: a whole number >= 1")
        references = {k: r for k in needed if (r := cache.reference(k)) is not None}
        tasks = [("reference", k, applied) for k, applied in needed.items() if k not in references]
        runs = sorted(todo, key=lambda k: -todo[k][1].simulation.stop_time / todo[k][1].simulation.step_size)
        tasks += [("run", key, todo[key][1]) for key in runs]  # the longest first, for an even load
        with _results(tasks, out_dir, fmu_paths, jobs, scheduler, scheduler_timeout) as results:
            done.update(_collect(scenario, todo, references, cache, results, progress))
    return [done[key] for _, _, key, _ in plans]


@contextmanager
def _results(tasks, out_dir: Path, fmu_paths: dict, jobs: int, scheduler: str | None, timeout: float):
    """The results of ``tasks`` as they finish, from this process, a process pool or a Dask cluster;
    on leaving, stop what still runs and remove the work folder."""
    if scheduler is not None:
        from .sweep_dask import connect, run_on_cluster

        client = connect(scheduler, timeout)  # before anything is written
        results = run_on_cluster(client, tasks, fmu_paths)
        try:
            yield results
        finally:
            try:
                results.close()  # cancels the cluster's remaining tasks
            finally:
                client.close()
        return
    (out_dir / ".work").mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f"sweep-{os.getpid()}-", dir=out_dir / ".work"))
    try:
        workers = min(jobs, sum(kind == "run" for kind, _, _ in tasks))
        results = _in_process(tasks, fmu_paths, work) if workers <= 1 else _pool(tasks, fmu_paths, work, workers)
        try:
            yield results
        finally:
            results.close()  # stops the pool (at once if it did not finish) or frees this process's Cosimulator
    finally:
        shutil.rmtree(work, ignore_errors=True)
        try:
            work.parent.rmdir()  # .work itself, unless another sweep is using it
        except OSError:
            pass


def _collect(scenario: Scenario, todo: dict, references: dict, cache: SweepCache, results, progress: bool) -> dict:
    """Rows (by key) of the runs of ``todo`` (key: (case, applied scenario, reference key)) from
    ``results``, each cached as soon as both the run and its reference solution are in."""
    rows, waiting = {}, defaultdict(list)
    remaining = Counter(ref_key for _, _, ref_key in todo.values())
    with tqdm(total=len(todo), unit="run", desc=f"sweep {scenario.name}", file=sys.stderr,
              disable=None if progress else True) as bar:

        def finish(key, outcome):
            case, _, ref_key = todo[key]
            rows[key] = make_row(scenario.name, case, (key, ref_key), outcome, references[ref_key])
            cache.store_run(key, rows[key], outcome["trajectory"])
            bar.update()
            remaining[ref_key] -= 1
            if not remaining[ref_key]:
                references.pop(ref_key)  # no run left that needs it

        for kind, tag, value in results:
            if kind == "reference":
                reference, why = value
                if reference is None:
                    warnings.warn(f"reference solution failed ({why}): deviations are NaN for its runs", stacklevel=4)
                else:
                    cache.store_reference(tag, reference)
                references[tag] = reference
                for key, outcome in waiting.pop(tag, []):
                    finish(key, outcome)
            elif todo[tag][2] in references:
                finish(tag, value)
            else:
                waiting[todo[tag][2]].append((tag, value))
    return rows
