"""Instructions per co-simulation step through the C master, for this tree beside another revision, counted by
valgrind's callgrind: repeatable to a few instructions whatever else the machine does, where wall times vary
by several per cent.

Each tree builds its three FMUs (FMI 2.0) and runs ``tests/c_master.c`` (compiled by Zig for baseline x86-64,
which valgrind decodes) over the paper's loop for ``--steps`` and for twice as many steps; the difference of
the two totals over the difference of the steps is the cost of one step, start-up excluded.
Run: ``python benchmarks/instructions.py --against REV [--steps 500]`` (needs git and valgrind).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def measure(root: Path, steps: int) -> float:
    """Instructions per step of the C master on the FMUs that the tree ``root`` (on sys.path) builds."""
    sys.path[:0] = [str(root), str(root / "tests")]
    import fmpy
    from c_hosts import write_plan
    from fmpy import extract

    from dsc_fmu.fmubuild.fmus import build_fmus

    with tempfile.TemporaryDirectory(prefix="dsc_fmu_instructions_") as folder:
        tmp = Path(folder)
        fmus = build_fmus(tmp / "fmus")
        unzipped = {name: Path(extract(str(path), unzipdir=tmp / name)) for name, path in fmus.items()}
        master = tmp / "c_master"
        subprocess.run([sys.executable, "-m", "ziglang", "cc", "-target", "x86_64-linux-gnu", "-O2", "-std=gnu11",
                        f"-I{Path(fmpy.__file__).parent / 'c-code'}", "-o", str(master), str(root / "tests" / "c_master.c"),
                        "-D_GNU_SOURCE", "-ldl", "-lpthread"], check=True, capture_output=True, timeout=600)
        totals = {}
        for count in (steps, 2 * steps):
            plan = write_plan(tmp / f"plan{count}.txt", unzipped, count, 1e-3, "gauss-seidel", False, count, {})
            run = subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={tmp / 'callgrind.out'}",
                                  str(master), str(plan)], capture_output=True, text=True, cwd=tmp,
                                 env={"PATH": os.environ.get("PATH", "/usr/bin:/bin")}, timeout=3600)
            if run.returncode != 0:
                raise SystemExit(f"the C master failed under valgrind: {run.stderr[-500:]}")
            totals[count] = int(re.search(r"Collected : (\d+)", run.stderr)[1])
    return (totals[2 * steps] - totals[steps]) / steps


def in_subprocess(root: Path, steps: int) -> float:
    """``measure`` of ``root`` in a fresh interpreter, so that each tree imports its own dsc_fmu."""
    run = subprocess.run([sys.executable, __file__, "--measure", str(root), "--steps", str(steps)],
                         capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(root)})
    if run.returncode != 0:
        raise SystemExit(f"measuring {root} failed: {run.stderr.strip()[-1000:]}")
    return float(run.stdout.split()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", help="the git revision to compare with (a worktree of it is made)")
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--measure", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        print(measure(args.measure, args.steps))
        return
    if not args.against:
        parser.error("--against REV is required: the revision to compare with")
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_against_") as folder:
        other = Path(folder) / "tree"
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(other), args.against], check=True,
                       capture_output=True)
        try:
            before = in_subprocess(other, args.steps)
        finally:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(other)], capture_output=True)
    after = in_subprocess(REPO, args.steps)
    print(f"{'tree':<24}{'instructions per step':>24}{'ratio':>8}")
    print(f"{args.against:<24}{before:>24,.0f}{1:>8.4f}")
    print(f"{'this tree':<24}{after:>24,.0f}{after / before:>8.4f}")


if __name__ == "__main__":
    main()
