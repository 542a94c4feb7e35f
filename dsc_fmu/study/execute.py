"""Running a sweep's cases, cached: in this process, on a process pool or on a Dask cluster."""

from __future__ import annotations

import multiprocessing
import multiprocessing.util
import os
import shutil
import signal
import sys
import tempfile
import warnings
from collections import Counter, defaultdict
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from contextlib import contextmanager
from pathlib import Path

from tqdm import tqdm

from ..cosim.master import Cosimulator
from ..scenario import Scenario
from .cache import SweepCache, case_key, fmu_identities, reference_key
from .cases import Case, SweepError, apply
from .rows import compute_reference, make_row, simulate

__all__ = ["execute"]

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
    nothing is written then). Each finished run is cached at once (``cache``), so an
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
        from .cluster import connect, run_on_cluster

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
