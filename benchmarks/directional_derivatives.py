"""Benchmark: what one directional derivative (a Jacobian column) costs against one evaluation of the model, in this process.

The slave classes of ``fmu_sources`` (FMI 2.0), initialized and stepped 1 s along the paper's
inputs, then, per FMU: a derivative evaluation (``get_derivatives``, as model exchange asks for it)
beside one column of the Jacobian of the state derivatives by the states and inputs
(``directional_derivative`` with a seed on one known; the mean over all columns), and an evaluation
of the outputs beside one column of the outputs by the inputs (co-simulation; the mean over the
inputs). Both sides are the Python of the slave alone: the FMI layer adds the same cost to each call.
``--float-only`` times the float path alone (it runs on a tree without directional derivatives too);
``--against REV`` times it, in one run, for this tree and for the package at git revision REV, each in a
process of its own, alternately for ``--rounds`` rounds, and prints the best of each side by side with
their ratio (the float path's cost before and after a change).
Run: ``python benchmarks/directional_derivatives.py [--calls 2000] [--repeat 5] [--float-only | --against REV [--rounds 3]]``.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
from in_process import InProcess  # noqa: E402

# Voltages that move the plant (the controller keeps the inputs of the paper's start, its defaults).
VOLTAGES = (6.0, 5.0)
STEP = 1e-3


def _slaves() -> dict:
    """The three slaves, 1 s into a run with the paper's start and constant voltages."""
    slaves = {}
    for name in ("ReferenceRobot", "MobileRobot", "DSCController"):
        instance = InProcess(name).initialize()
        if name == "MobileRobot":
            instance.set(("u1", "u2"), VOLTAGES)
        for k in range(1000):
            instance.step(k * STEP, STEP)
        slaves[name] = instance
    return slaves


def _per_call(function, calls: int, repeat: int) -> float:
    """Seconds per call of ``function``, best of ``repeat`` runs of ``calls`` calls."""
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        for _ in range(calls):
            function()
        best = min(best, (time.perf_counter() - start) / calls)
    return best


def _outputs(slave):
    """The outputs computed afresh (the cache forgotten)."""
    slave._stale()
    return slave.output_values()


def _costs(instance: InProcess, calls: int, repeat: int, float_only: bool) -> tuple:
    """Seconds per call: derivatives, one column of them, outputs, one column of them (None: none or skipped)."""
    slave = instance.slave
    derivative = _per_call(slave.get_derivatives, calls, repeat)
    output = _per_call(lambda: _outputs(slave), calls, repeat)
    if float_only:
        return derivative, None, output, None
    vr, model = instance.vr, slave.model
    derivatives = [vr[s.derivative.name] for s in model.STATES]
    outputs = [vr[v.name] for v in model.OUTPUTS]
    inputs = [vr[v.name] for v in model.INPUTS]
    knowns = [vr[s.variable.name] for s in model.STATES] + inputs
    column = _mean_column(slave, derivatives, knowns, True, calls, repeat)
    output_column = _mean_column(slave, outputs, inputs, False, calls, repeat) if inputs else None
    return derivative, column, output, output_column


def _mean_column(slave, unknowns: list, knowns: list, model_exchange: bool, calls: int, repeat: int) -> float:
    """Seconds per column of the Jacobian of ``unknowns`` by ``knowns``, one seed per call, over all columns."""
    def columns():
        for known in knowns:
            slave.directional_derivative(unknowns, [known], [1.0], model_exchange)

    return _per_call(columns, max(1, calls // len(knowns)), repeat) / len(knowns)


def _float_costs(calls: int, repeat: int) -> dict:
    """Seconds per call of the float path, by FMU: derivatives and outputs."""
    return {name: _costs(instance, calls, repeat, True)[0::2] for name, instance in _slaves().items()}


def _tree_at(revision: str, folder: Path) -> Path:
    """The package and the FMUs' sources at git ``revision``, unpacked into ``folder``."""
    root = Path(__file__).parents[1]
    archive = subprocess.run(["git", "-C", str(root), "archive", revision, "dsc_fmu", "fmu_sources"],
                             capture_output=True, check=True).stdout
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(folder)
    return folder


def _against(revision: str, calls: int, repeat: int, rounds: int) -> None:
    """The float path of this tree and of ``revision``'s, alternately in processes of their own, best of each."""
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_before_") as tmp:
        trees = {"before": _tree_at(revision, Path(tmp)), "after": Path(__file__).parents[1]}
        best = {}
        for _ in range(rounds):
            for label, tree in trees.items():
                run = subprocess.run([sys.executable, __file__, "--float-json", "--calls", str(calls), "--repeat",
                                      str(repeat)], capture_output=True, text=True, check=True, cwd=tmp,
                                     env={**os.environ, "PYTHONPATH": str(tree)})
                for name, costs in json.loads(run.stdout).items():
                    previous = best.get((label, name), costs)
                    best[label, name] = [min(a, b) for a, b in zip(previous, costs)]
    print(f"the float path in this process, before ({revision}) and after (this tree), us per call, best of "
          f"{rounds} rounds x {repeat} x {calls}")
    print(f"{'FMU':<16}{'derivatives':>24}{'ratio':>7}{'outputs':>22}{'ratio':>7}")
    for name in ("ReferenceRobot", "MobileRobot", "DSCController"):
        (d0, o0), (d1, o1) = best["before", name], best["after", name]
        print(f"{name:<16}{d0 * 1e6:>12.3f} {d1 * 1e6:>10.3f}{d1 / d0:>7.3f}{o0 * 1e6:>11.3f} {o1 * 1e6:>10.3f}"
              f"{o1 / o0:>7.3f}")
    print("(aim: after / before within 1.02)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=2000)
    parser.add_argument("--repeat", type=int, default=5, help="best of this many runs")
    parser.add_argument("--float-only", action="store_true", help="time the float path only")
    parser.add_argument("--against", metavar="REV", help="the float path against the package at git revision REV")
    parser.add_argument("--rounds", type=int, default=3, help="with --against: alternating rounds (default 3)")
    parser.add_argument("--float-json", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.float_json:
        print(json.dumps(_float_costs(args.calls, args.repeat)))
        return
    if args.against:
        _against(args.against, args.calls, args.repeat, args.rounds)
        return
    print(f"in this process, FMI 2.0 slaves 1 s into a run (us per call, best of {args.repeat} x {args.calls})")
    print(f"{'FMU':<16}{'derivatives':>13}{'column (ME)':>13}{'ratio':>7}{'outputs':>10}{'column (CS)':>13}"
          f"{'ratio':>7}")
    for name, instance in _slaves().items():
        derivative, column, output, output_column = _costs(instance, args.calls, args.repeat, args.float_only)
        cells = [f"{name:<16}{derivative * 1e6:>13.2f}"]
        cells.append(f"{column * 1e6:>13.2f}{column / derivative:>7.2f}" if column else f"{'-':>13}{'-':>7}")
        cells.append(f"{output * 1e6:>10.2f}")
        cells.append(f"{output_column * 1e6:>13.2f}{output_column / output:>7.2f}" if output_column else
                     f"{'-':>13}{'-':>7}")
        print("".join(cells))
    if not args.float_only:
        print("(target: one column <= 5 x one evaluation)")


if __name__ == "__main__":
    main()
