"""Benchmark: what threads and processes give a host that steps several instances at once.

All instances of one process share one CPython and its interpreter lock (GIL): a host that steps two
instances on two threads gets no more done than one that steps them one after another; two
processes do. Each route steps N MobileRobot instances (FMI 2.0) for STEPS steps of 1 ms from a C
host without Python (``tests/c_threads.c``), on this machine's cores. The threads' routes time the
steps only; the processes' route times whole processes (starting each, its Python and its
instance too), so it errs against processes.
Run: ``python benchmarks/threads.py [--instances 2] [--steps 20000] [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from fmpy import extract, read_model_description

from dsc_fmu.fmubuild.fmus import ensure_fmus

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
from c_hosts import EMPTY_ENVIRONMENT, compile_c  # noqa: E402


def _seconds(host: Path, folder: Path, guid: str, instances: int, steps: int, threaded: bool) -> float:
    """The wall time one process reports for stepping ``instances`` instances."""
    run = subprocess.run([str(host), "steps", "2", str(folder), "MobileRobot", guid, str(instances), str(steps),
                          str(int(threaded))], env=EMPTY_ENVIRONMENT, capture_output=True, text=True, check=True)
    return float(run.stdout.strip().partition("=")[2])


def _processes(host: Path, folder: Path, guid: str, instances: int, steps: int) -> float:
    """The wall time of ``instances`` processes at once, each stepping one instance."""
    command = [str(host), "steps", "2", str(folder), "MobileRobot", guid, "1", str(steps), "0"]
    started = time.perf_counter()
    running = [subprocess.Popen(command, env=EMPTY_ENVIRONMENT, stdout=subprocess.DEVNULL) for _ in range(instances)]
    if any(process.wait() != 0 for process in running):
        raise RuntimeError("a stepping process failed")
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--instances", type=int, default=2)
    parser.add_argument("--steps", type=int, default=20000)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_threads_") as tmp:
        tmp = Path(tmp)
        fmu = ensure_fmus()["MobileRobot"]
        folder = Path(extract(str(fmu), unzipdir=tmp / "plant"))
        guid = read_model_description(str(fmu)).guid
        host = compile_c("c_threads.c", tmp / "c_threads")
        n, steps = args.instances, args.steps
        routes = {
            f"{n} instances, one after another, one thread": lambda: _seconds(host, folder, guid, n, steps, False),
            f"{n} instances, one thread each, one process": lambda: _seconds(host, folder, guid, n, steps, True),
            f"{n} processes at once, one instance each": lambda: _processes(host, folder, guid, n, steps),
        }
        best = {label: min(route() for _ in range(args.repeat)) for label, route in routes.items()}
    first = next(iter(best.values()))
    print(f"{n} MobileRobot instances x {steps} steps of 1 ms, C host, {os.cpu_count()} cores, best of {args.repeat}")
    print(f"{'route':<50}{'wall time (s)':>15}{'ratio':>8}")
    for label, seconds in best.items():
        print(f"{label:<50}{seconds:>15.3f}{seconds / first:>8.2f}")


if __name__ == "__main__":
    main()
