"""Benchmark: one RK4 sub-step of each model in Python against the same sub-step traced to C (docs/traced-c.md).

Python: the FMU model's ``integrate`` (``models.rk4.rk4_integrate`` over its ``rates``; the controller's records the
beta guard as in a co-simulation step and, under the projection, moves the estimates onto their sets; the plant's
with the limit counts the evaluations that limited) over one step of ``--substeps`` sub-steps, per sub-step. C: the
generated RK4 loop (``traced_models.trace_models``, compiled here with Zig) over as many sub-steps in one ctypes
call, so that the call's cost is spread over them. Both start from the paper's parameters (changed per row: the law,
the limit, the loads) and the same state and inputs, and their results are checked equal bit for bit before timing.
Prints both and their ratio.
Run: ``python benchmarks/trace_speed.py [--substeps 10000] [--repeat 5]``.
"""

from __future__ import annotations

import argparse
import ctypes
import struct
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[1]))
from dsc_fmu.fmu.controller_model import DSCControllerModel  # noqa: E402
from dsc_fmu.fmu.robot_models import MobileRobotModel, ReferenceRobotModel  # noqa: E402
from dsc_fmu.fmubuild.traced_models import compile_library, trace_models  # noqa: E402

# A state and inputs away from every switch: the plant moving, the controller tracking, the reference on the eight;
# each row: the model, its state and inputs, the parameters changed from the defaults.
_CONTROLLER = ([0.1, 0.2, 1.0, 0.9, *[0.01] * 8, 0.5, 0.4, *[0.02] * 6],
               [0.1, -0.2, 0.3, 0.2, 5.0, 4.0, 1.0, 0.8, 0.5, 0.4, 0.6, 1.0, 0.2, 0.0])
CASES = {
    "controller (sigma)": ("controller", DSCControllerModel, *_CONTROLLER, {}),
    "controller (projection)": ("controller", DSCControllerModel, *_CONTROLLER, {"adaptation": 2}),
    "plant": ("plant", MobileRobotModel, [0.1, 0.2, 0.3, 5.0, 4.0, 1.0, 0.8], [6.0, 5.0], {}),
    "plant (limit, loads)": ("plant", MobileRobotModel, [0.1, 0.2, 0.3, 5.0, 4.0, 1.0, 0.8], [6.0, 5.0],
                             {"voltage_limit": 1, "u_max1": 5.5, "tau_dc1": 1.0, "tau_da2": 1.0, "f_d2": 0.5}),
    "reference (eight)": ("reference", ReferenceRobotModel, [0.0, 0.0, 0.5], None, {"profile": 1}),
}


def _python(model, x: list, u, substeps: int, step: float) -> tuple:
    """Seconds per sub-step of ``model.integrate`` over one step of ``substeps`` sub-steps, and its result."""
    start = time.perf_counter()
    result = model.integrate(0.0, x, step, lambda t: u)
    return (time.perf_counter() - start) / substeps, result


def _c(library, kind: str, model, x: list, u, substeps: int, step: float) -> tuple:
    """Seconds per sub-step of the generated loop over ``substeps`` sub-steps in one call, and its result."""
    double = ctypes.c_double
    state = (double * len(x))(*x)
    arguments = [(double * len(model.p))(*model.p.values())] + ([] if u is None else [(double * len(u))(*u)])
    arguments += [double(0.0), double(step), ctypes.c_long(substeps), state]
    arguments += [(double * 3)()] if kind != "reference" else []
    function = getattr(library, f"dsc_{kind}_rk4")
    start = time.perf_counter()
    fault = function(*arguments)
    elapsed = time.perf_counter() - start
    if fault:
        raise RuntimeError(f"dsc_{kind}_rk4: Python would raise here")
    return elapsed / substeps, list(state)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--substeps", type=int, default=10000)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        library = ctypes.CDLL(str(compile_library(trace_models().source, Path(folder))))
        print(f"per RK4 sub-step, best of {args.repeat} steps of {args.substeps} sub-steps")
        print(f"{'model':<26}{'Python (us)':>12}{'C (us)':>10}{'Python / C':>12}")
        for label, (kind, cls, x, u, changed) in CASES.items():
            model = cls()
            model.p.update(max_step=1e-4, **changed)
            step = 1e-4 * args.substeps
            python = [_python(model, x, u, args.substeps, step) for _ in range(args.repeat)]
            c = [_c(library, kind, model, x, u, args.substeps, step) for _ in range(args.repeat)]
            if [struct.pack("<d", v) for v in python[0][1]] != [struct.pack("<d", v) for v in c[0][1]]:
                raise RuntimeError(f"{label}: the C loop's state differs from Python's")
            best_python, best_c = min(t for t, _ in python), min(t for t, _ in c)
            print(f"{label:<26}{best_python * 1e6:>12.2f}{best_c * 1e6:>10.3f}{best_python / best_c:>12.0f}")


if __name__ == "__main__":
    main()
