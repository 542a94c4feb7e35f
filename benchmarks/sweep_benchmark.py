"""Benchmark of the sweep engine: parallel speed-up and the memory of one long-lived Cosimulator.

(a) A 16-run sweep of the paper scenario (8 step sizes x 2 orders, short stop time, no cache: a
    fresh output folder each time) with 1 job and with 2 jobs, and their ratio (target >= 1.7 on a
    machine with at least 2 free cores).
(b) 200 runs in one worker (one Cosimulator, reset between runs): resident memory before and after
    and its growth (target < 50 MB), and whether an extracted or temporary folder is left afterwards.

Run: ``python benchmarks/sweep_benchmark.py [--stop-time 5] [--memory-runs 200] [--memory-stop-time 0.5]``.
"""

from __future__ import annotations

import argparse
import gc
import os
import tempfile
import time
from pathlib import Path

import psutil

from dsc_fmu.fmubuild.fmus import ensure_fmus
from dsc_fmu.cosim.master import Cosimulator
from dsc_fmu.scenario import ORDERS, load_scenario
from dsc_fmu.study.cases import Case, Runner, apply, build_cases
from dsc_fmu.study.execute import execute
from dsc_fmu.study.rows import simulate

MB = 1024.0**2
STEPS = (1e-4, 2.4e-4, 5.6e-4, 1.3e-3, 3.2e-3, 7.5e-3, 1.8e-2, 5e-2)  # 8 steps x 2 orders = 16 runs


def speed_up(fmu_paths: dict, stop_time: float) -> None:
    scenario = load_scenario("paper").with_simulation(stop_time=stop_time)
    cases = build_cases(scenario, step_sizes=STEPS, orders=ORDERS)
    print(f"(a) {len(cases)}-run sweep, paper scenario, stop time {stop_time:g} s, "
          f"steps {', '.join(f'{h:g}' for h in STEPS)} s x {', '.join(ORDERS)}; "
          f"{os.cpu_count()} CPUs")
    times = {}
    for jobs in (1, 2):
        with tempfile.TemporaryDirectory(prefix="dsc_fmu_sweep_benchmark_") as out:
            started = time.perf_counter()
            rows = execute(scenario, cases, Path(out), fmu_paths, Runner(jobs=jobs, progress=False)).rows
            times[jobs] = time.perf_counter() - started
        diverged = sum(row["diverged"] for row in rows)
        print(f"    jobs = {jobs}: {times[jobs]:6.2f} s wall ({len(rows)} rows, {diverged} diverged, "
              f"sum of run wall times {sum(row['wall_time_s'] for row in rows):.2f} s)")
    print(f"    speed-up jobs 2 / jobs 1: {times[1] / times[2]:.2f} (target >= 1.7)")


def memory(fmu_paths: dict, runs: int, stop_time: float) -> None:
    scenario = load_scenario("paper").with_simulation(stop_time=stop_time)
    cases = [Case(h, order) for h in (1e-3, 2e-3, 5e-3, 0.01, 0.1) for order in ORDERS]
    failing = scenario.with_simulation(bound=1e-3)  # every 10th run diverges at once: the reset after a failure
    process = psutil.Process()
    temp = Path(tempfile.gettempdir())
    before_temp = set(temp.glob("dsc_fmu_*"))
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_memory_") as work:
        work = Path(work)
        with Cosimulator(fmu_paths, work) as simulator:
            gc.collect()
            start = process.memory_info().rss
            simulate(apply(scenario, cases[0]), simulator)
            gc.collect()
            warm = process.memory_info().rss
            started = time.perf_counter()
            diverged = 0
            for index in range(runs):
                chosen = failing if index % 10 == 9 else scenario
                outcome = simulate(apply(chosen, cases[index % len(cases)]), simulator)
                diverged += outcome.metrics is None
            elapsed = time.perf_counter() - started
            gc.collect()
            end = process.memory_info().rss
            loaded = len(list(work.iterdir()))
        left_in_work = sorted(p.name for p in work.iterdir())
    left_in_temp = sorted(p.name for p in set(temp.glob("dsc_fmu_*")) - before_temp)
    print(f"(b) {runs} runs in one Cosimulator (stop time {stop_time:g} s, {diverged} diverged), "
          f"{elapsed:.1f} s, {simulator.runs} runs on {loaded} extracted FMU folders")
    print(f"    RSS after loading {start / MB:.1f} MB, after one run {warm / MB:.1f} MB, "
          f"after {runs} more {end / MB:.1f} MB")
    print(f"    growth over the {runs} runs: {(end - warm) / MB:.1f} MB (target < 50 MB); "
          f"since loading: {(end - start) / MB:.1f} MB")
    print(f"    left in the work folder after close: {left_in_work or 'nothing'}; "
          f"new dsc_fmu_* in {temp}: {left_in_temp or 'nothing'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stop-time", type=float, default=5.0, help="stop time of the 16 runs of (a), s")
    parser.add_argument("--memory-runs", type=int, default=200, help="runs of (b)")
    parser.add_argument("--memory-stop-time", type=float, default=0.5, help="stop time of the runs of (b), s")
    parser.add_argument("--fmu-dir", type=Path, default=Path("build") / "fmus")
    args = parser.parse_args()
    fmu_paths = ensure_fmus(args.fmu_dir)
    speed_up(fmu_paths, args.stop_time)
    memory(fmu_paths, args.memory_runs, args.memory_stop_time)


if __name__ == "__main__":  # worker processes are spawned: they import this file without running it
    main()
