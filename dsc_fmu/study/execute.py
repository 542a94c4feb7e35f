"""Running a sweep's cases, cached: in this process, on a process pool or on a Dask cluster."""

from __future__ import annotations

import multiprocessing
import multiprocessing.util
import os
import re
import shutil
import signal
import sys
import tempfile
import warnings
from collections import Counter, defaultdict, deque
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from ..cosim.master import Cosimulator
from ..scenario import Scenario
from .cache import CacheEntryError, CacheWarning, SweepCache, case_key, fmu_identities, reference_key
from .cases import SCHEDULER_TIMEOUT, Case, SweepError, apply, check_scheduler, parse_scheduler
from .rows import compute_reference, lost_outcome, make_row, simulate

__all__ = ["execute", "Execution", "WorkerLostWarning", "LOST_TWICE", "prepare_sweep_folder"]

LOST_TWICE = "worker process lost twice (killed or crashed)"
_WORK_FOLDER = re.compile(r"sweep-(\d+)-")


class WorkerLostWarning(UserWarning):
    """Worker processes of a sweep were lost (killed or crashed): what was in flight was retried."""


@dataclass(frozen=True)
class Execution:
    """What ``execute`` did: the ``rows`` (in the order of the cases), how many of them came from the
    cache (``cached``) and how many were run now (``ran``), the keys of the runs that did not finish
    (``lost``: their rows carry the reason, they are not cached), the cache entries that did not
    verify and were recomputed (``unverified``, a CacheEntryError each), how many times the process
    pool lost a worker (``workers_lost``) and how many computations in flight were retried (``retried``)."""

    rows: list
    cached: int = 0
    ran: int = 0
    lost: tuple = ()
    unverified: tuple = ()
    workers_lost: int = 0
    retried: int = 0

    def __add__(self, other: Execution) -> Execution:
        """Two executions as one (a sweep's grid and its refinement): rows one after the other, counts added."""
        return Execution(self.rows + other.rows, self.cached + other.cached, self.ran + other.ran,
                         self.lost + other.lost, self.unverified + other.unverified,
                         self.workers_lost + other.workers_lost, self.retried + other.retried)

    def warn(self) -> None:
        """One CacheWarning line if cache entries did not verify, one WorkerLostWarning line if a
        worker was lost or runs did not finish."""
        if self.unverified:
            count = len(self.unverified)
            what = "1 cache entry did not verify and was recomputed:" if count == 1 else \
                f"{count} cache entries did not verify and were recomputed; the first:"
            warnings.warn(f"{what} {self.unverified[0]}", CacheWarning, stacklevel=2)
        parts = []
        if self.workers_lost:
            times = "" if self.workers_lost == 1 else f" {self.workers_lost} times"
            parts.append(f"a worker process was lost (killed or crashed){times}; {self.retried} "
                         f"{'computation' if self.retried == 1 else 'computations'} in flight retried on a new pool")
        if self.lost:
            parts.append(f"{len(self.lost)} {'run' if len(self.lost) == 1 else 'runs'} did not finish: "
                         "rows with the reason, not cached")
        if parts:
            warnings.warn("; ".join(parts), WorkerLostWarning, stacklevel=2)


def prepare_sweep_folder(out_dir: Path) -> None:
    """Create the sweep folder ``out_dir`` if needed and check that files can be written in it;
    SweepError (one line, naming ``out_dir``) otherwise."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out_dir):
            pass
    except OSError as error:
        raise _folder_error(out_dir, error) from None


def _folder_error(out_dir: Path, error: OSError) -> SweepError:
    """The SweepError of a sweep folder the system refuses: named as given, whatever file inside failed."""
    existing = next((path for path in (out_dir, *out_dir.parents) if path.exists()), None)
    if existing is not None and not existing.is_dir():
        reason = "it is not a folder" if existing == out_dir else f"{existing} is not a folder"
    else:
        text = error.strerror or type(error).__name__
        reason = text[:1].lower() + text[1:]
    return SweepError(f"{out_dir}: cannot use as the sweep folder: {reason}; "
                      "allowed: a writable folder, or a path where one can be created")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _remove_stale_work(work_root: Path) -> None:
    """Remove the work folders ``sweep-<pid>-*`` in ``work_root`` whose sweep process is gone (killed
    before it could clean up), and ``work_root`` itself if nothing else is left in it."""
    for folder in work_root.glob("sweep-*"):
        match = _WORK_FOLDER.match(folder.name)
        if match and folder.is_dir() and not _alive(int(match[1])):
            shutil.rmtree(folder, ignore_errors=True)
    try:
        work_root.rmdir()
    except OSError:
        pass


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
                yield kind, tag, compute_reference(applied, fmu_paths)
                continue
            if simulator is None:
                folder = work / str(os.getpid())
                folder.mkdir(parents=True, exist_ok=True)
                simulator = Cosimulator(fmu_paths, folder)
            yield kind, tag, simulate(applied, simulator)
    finally:
        if simulator is not None:
            simulator.close()


def _executor(fmu_paths: dict, work: Path, jobs: int) -> ProcessPoolExecutor:
    return ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_init_pool_worker, initargs=(dict(fmu_paths), str(work)))


def _pool(tasks, fmu_paths, work: Path, jobs: int, events: Counter):
    """Run the tasks on ``jobs`` worker processes (spawned), each with its own Cosimulator, handing
    out at most ``jobs`` at a time, so that the tasks in flight are those running on a worker.

    When a worker process is lost (killed or crashed: the pool breaks, and with it every task in
    flight), a new pool retries those tasks once; a run lost twice yields ``lost_outcome(LOST_TWICE)``,
    a reference solution lost twice is computed in this process. ``events`` counts the broken pools
    (``workers_lost``) and the retried tasks (``retried``).
    """
    queue, losses, in_flight, executor, finished = deque(tasks), Counter(), {}, None, False
    try:
        while queue or in_flight:
            if executor is None:
                executor = _executor(fmu_paths, work, jobs)
            broken = False
            while queue and len(in_flight) < jobs and not broken:
                kind, tag, applied = queue[0]
                try:
                    future = (executor.submit(compute_reference, applied, fmu_paths) if kind == "reference"
                              else executor.submit(_pool_run, applied))
                except BrokenProcessPool:
                    broken = True
                else:
                    in_flight[future] = queue.popleft()
            if in_flight:
                done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                if any(isinstance(future.exception(), BrokenProcessPool) for future in done):
                    broken = True
                    done, _ = wait(in_flight)  # a broken pool fails every task in flight at once
                retry = []
                for future in done:
                    kind, tag, applied = task = in_flight.pop(future)
                    if not isinstance(future.exception(), BrokenProcessPool):
                        yield kind, tag, future.result()  # a task's own error is raised here
                        continue
                    losses[kind, tag] += 1
                    if losses[kind, tag] == 1:
                        retry.append(task)
                    elif kind == "reference":
                        yield kind, tag, compute_reference(applied, fmu_paths)
                    else:
                        yield kind, tag, lost_outcome(LOST_TWICE)
                queue.extendleft(reversed(retry))
                events["retried"] += len(retry)
            if broken:
                events["workers_lost"] += 1
                executor.shutdown(wait=True, cancel_futures=True)
                executor = None
        finished = True
    finally:
        if executor is not None:
            if not finished:  # interrupted or failed: stop the workers now rather than after their current runs
                for process in list((getattr(executor, "_processes", None) or {}).values()):
                    process.terminate()
            executor.shutdown(wait=True, cancel_futures=True)


def execute(scenario: Scenario, cases: list[Case], out_dir: Path | str, fmu_paths: dict, jobs: int | None = None,
            scheduler: str | None = None, progress: bool = True, *, scheduler_timeout: float = SCHEDULER_TIMEOUT,
            warn: bool = True) -> Execution:
    """Run every case not yet cached in ``out_dir`` and return the rows of all, in the order of
    ``cases``, with what was done (``Execution``).

    Locally (no ``scheduler``), ``jobs`` worker processes (default: ``os.cpu_count()``; 1 runs in
    this process) each load the FMUs once (into ``out_dir/.work``, removed at the end whatever
    happens; the work folders of sweeps killed before they could remove theirs are removed at the
    start). A worker process lost (killed or crashed) costs the runs in flight one retry on a new
    pool; a run lost twice is a row with the reason ``LOST_TWICE``, not cached. With ``scheduler =
    "tcp://host:port"`` the runs go to that Dask cluster instead (``jobs`` does not apply;
    SweepError if the address is not one or cannot be reached within ``scheduler_timeout`` s, and
    nothing is written then). Each finished run is cached at once (``cache``), so an interrupted
    sweep resumes where it stopped; cached cases are not run again. Reference solutions are
    computed once per physical case and cached too. Cache entries that do not verify (damaged,
    edited, of an older layout) are recomputed, references included. ``progress`` shows a bar on
    stderr; ``warn`` issues ``Execution.warn`` (one line per kind of problem) before returning.
    """
    out_dir, cache = Path(out_dir), SweepCache(out_dir)
    jobs = (os.cpu_count() or 1) if jobs is None else jobs
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise SweepError(f"jobs = {jobs!r} is not allowed; allowed: a whole number >= 1")
    if scheduler is not None:
        parse_scheduler(scheduler)
    identities = fmu_identities(fmu_paths)
    plans = [(case, apply(scenario, case), case_key(scenario, case, identities),
              reference_key(scenario, case, identities)) for case in cases]
    done, todo, unverified = {}, {}, []
    for case, applied, key, ref_key in plans:
        if key in done or key in todo:
            continue
        cached, _ = _verified(cache.row, key, unverified)
        if cached is not None:
            done[key] = {**cached, "scenario": scenario.name}
        else:
            todo[key] = (case, applied, ref_key)
    from_cache = set(done)
    references, missing = _references(cache, plans, todo, unverified)
    events = Counter()
    if (todo or missing) and scheduler is not None:
        check_scheduler(scheduler, scheduler_timeout)  # before anything is written
    prepare_sweep_folder(out_dir)
    _remove_stale_work(out_dir / ".work")
    lost = []
    if todo or missing:
        tasks = [("reference", k, applied) for k, applied in missing.items()]
        runs = sorted(todo, key=lambda k: -todo[k][1].simulation.stop_time / todo[k][1].simulation.step_size)
        tasks += [("run", key, todo[key][1]) for key in runs]  # the longest first, for an even load
        with _results(tasks, out_dir, fmu_paths, jobs, scheduler, scheduler_timeout, events) as results:
            done.update(_collect(scenario, todo, references, cache, identities, results, progress, lost))
    keys = [key for _, _, key, _ in plans]
    execution = Execution([done[key] for key in keys], cached=sum(key in from_cache for key in keys),
                          ran=sum(key not in from_cache for key in keys), lost=tuple(lost),
                          unverified=tuple(unverified), workers_lost=events["workers_lost"], retried=events["retried"])
    if warn:
        execution.warn()
    return execution


def _references(cache: SweepCache, plans, todo: dict, unverified: list) -> tuple[dict, dict]:
    """The verified cached reference solutions the runs of ``todo`` need (by key), and the reference
    solutions to compute (key: applied scenario): those the runs need and are not cached, and every
    one of ``plans`` cached but not verifying (appended to ``unverified``)."""
    needed = {ref_key for _, _, ref_key in todo.values()}
    references, missing, seen = {}, {}, set()
    for _, applied, _, ref_key in plans:
        if ref_key in seen:
            continue
        seen.add(ref_key)
        reference, verified = _verified(cache.reference, ref_key, unverified)
        if reference is not None and ref_key in needed:
            references[ref_key] = reference
        elif not verified or ref_key in needed:
            missing[ref_key] = applied
    return references, missing


def _verified(read, key: str, unverified: list) -> tuple:
    """``read(key)`` from the cache (None: not cached) and whether the entry verified; one that does
    not is appended to ``unverified`` and counts as not cached."""
    try:
        return read(key), True
    except CacheEntryError as error:
        unverified.append(error)
        return None, False


@contextmanager
def _results(tasks, out_dir: Path, fmu_paths: dict, jobs: int, scheduler: str | None, timeout: float,
             events: Counter):
    """The results of ``tasks`` as they finish, from this process, a process pool or a Dask cluster;
    on leaving, stop what still runs and remove the work folder."""
    if scheduler is not None:
        from .cluster import connect, run_on_cluster

        client = connect(scheduler, timeout)
        results = run_on_cluster(client, tasks, fmu_paths)
        try:
            yield results
        finally:
            try:
                results.close()  # cancels the cluster's remaining tasks
            finally:
                client.close()
        return
    try:
        (out_dir / ".work").mkdir(exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix=f"sweep-{os.getpid()}-", dir=out_dir / ".work"))
    except OSError as error:
        raise _folder_error(out_dir, error) from None
    try:
        workers = min(jobs, sum(kind == "run" for kind, _, _ in tasks))
        if workers <= 1:
            results = _in_process(tasks, fmu_paths, work)
        else:
            results = _pool(tasks, fmu_paths, work, workers, events)
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


def _collect(scenario: Scenario, todo: dict, references: dict, cache: SweepCache, identities: dict, results,
             progress: bool, lost: list) -> dict:
    """Rows (by key) of the runs of ``todo`` (key: (case, applied scenario, reference key)) from
    ``results``, each cached as soon as both the run and its reference solution are in, except the
    runs that did not finish (their keys are appended to ``lost``) and, under the "local" stability,
    those whose reference solution failed (judged as settled runs for now)."""
    rows, waiting = {}, defaultdict(list)
    remaining = Counter(ref_key for _, _, ref_key in todo.values())
    local = scenario.simulation.stability == "local"
    with tqdm(total=len(todo), unit="run", desc=f"sweep {scenario.name}", file=sys.stderr,
              disable=None if progress else True) as bar:

        def finish(key, outcome):
            case, applied, ref_key = todo[key]
            rows[key] = make_row(applied, case, (key, ref_key), outcome, references[ref_key])
            if outcome.get("lost"):
                lost.append(key)
            elif references[ref_key] is not None or not local:  # judged without its reference: not for keeps
                cache.store_run(key, rows[key], outcome["trajectory"], identities)
            bar.update()
            remaining[ref_key] -= 1
            if not remaining[ref_key]:
                references.pop(ref_key)  # no run left that needs it

        for kind, tag, value in results:
            if kind == "reference":
                reference, why = value
                if reference is None:
                    judged = "; they are judged as settled runs and not cached" if local else ""
                    warnings.warn(f"reference solution failed ({why}): deviations are NaN for its runs{judged}",
                                  stacklevel=4)
                else:
                    cache.store_reference(tag, reference)
                if remaining[tag]:
                    references[tag] = reference
                for key, outcome in waiting.pop(tag, []):
                    finish(key, outcome)
            elif todo[tag][2] in references:
                finish(tag, value)
            else:
                waiting[todo[tag][2]].append((tag, value))
    return rows
