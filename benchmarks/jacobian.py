"""Benchmark: what one Jacobian column costs against one evaluation of the model, in this process.

The slave classes of ``fmu_sources`` (FMI 2.0), initialized and stepped 1 s along the paper's
inputs, then, per FMU: a derivative evaluation (``get_derivatives``, as model exchange asks for it)
beside one column of the Jacobian of the state derivatives by the states and inputs
(``directional_derivative`` with a seed on one known; the mean over all columns), and an evaluation
of the outputs beside one column of the outputs by the inputs (co-simulation; the mean over the
inputs). Both sides are the Python of the slave alone: the FMI layer adds the same cost to each call.
``--float-only`` times the float path alone (it runs on a tree without directional derivatives too:
compare before and after a change).
Run: ``python benchmarks/jacobian.py [--calls 2000] [--repeat 5] [--float-only]``.
"""

from __future__ import annotations

import argparse
import sys
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
    vr = instance.vr
    derivatives = [vr[s.derivative.name] for s in slave.STATES]
    outputs = [vr[v.name] for v in slave.OUTPUTS]
    inputs = [vr[v.name] for v in slave.INPUTS]
    knowns = [vr[s.variable.name] for s in slave.STATES] + inputs
    derivative = _per_call(slave.get_derivatives, calls, repeat)
    output = _per_call(lambda: _outputs(slave), calls, repeat)
    if float_only:
        return derivative, None, output, None
    column = _mean_column(slave, derivatives, knowns, True, calls, repeat)
    output_column = _mean_column(slave, outputs, inputs, False, calls, repeat) if inputs else None
    return derivative, column, output, output_column


def _mean_column(slave, unknowns: list, knowns: list, model_exchange: bool, calls: int, repeat: int) -> float:
    """Seconds per column of the Jacobian of ``unknowns`` by ``knowns``, one seed per call, over all columns."""
    def jacobian():
        for known in knowns:
            slave.directional_derivative(unknowns, [known], [1.0], model_exchange)

    return _per_call(jacobian, max(1, calls // len(knowns)), repeat) / len(knowns)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=2000)
    parser.add_argument("--repeat", type=int, default=5, help="best of this many runs")
    parser.add_argument("--float-only", action="store_true", help="time the float path only")
    args = parser.parse_args()
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
