"""Benchmark: what reaching a given accuracy costs with each coupling and step control, in one run.

For the paper's scenario (30 s), each scheme runs a ladder of settings, from the cheapest, until the
largest position deviation from the reference solution (scipy's DOP853 at 1e-10, on a 1 ms grid,
interpolated at each run's times) is at most the target. The cheapest run that meets it is the
scheme's cost; the ratio is the hold with Gauss-Seidel (today's default) over each scheme. The last
schemes are no co-simulation: the three FMUs as one ODE through model exchange with the FMUs' event
indicators, integrated by SciPy's DOP853 (explicit) or Radau and BDF (implicit, with the loop's Jacobian
from the FMUs' directional derivatives), each ladder the solver's relative tolerance.
Run: ``python benchmarks/work_precision.py [--target 1e-3] [--fmu-dir build/fmus]``.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from dsc_fmu.fmubuild.fmus import ensure_fmus
from dsc_fmu.cosim.master import Cosimulator
from dsc_fmu.cosim.model_exchange import simulate_model_exchange
from dsc_fmu.cosim.reference_solution import output_times, reference_solution
from dsc_fmu.scenario import load_scenario

# (label, order, coupling, ladder of (step size, tolerance)), each ladder from the cheapest setting.
SCHEMES = (
    ("hold, Gauss-Seidel", "gauss-seidel", "hold", [(h, None) for h in (1e-4, 7e-5, 5e-5, 3e-5)]),
    ("hold, Jacobi", "jacobi", "hold", [(h, None) for h in (1e-4, 7e-5, 5e-5, 3e-5)]),
    ("linear, Gauss-Seidel", "gauss-seidel", "linear", [(h, None) for h in (1e-3, 8e-4, 6e-4, 4e-4)]),
    ("linear, Jacobi", "jacobi", "linear", [(h, None) for h in (1e-3, 8e-4, 6e-4, 4e-4)]),
    ("linear, Gauss-Seidel, error-controlled", "gauss-seidel", "linear", [(1e-3, t) for t in (1e-3, 5e-4, 2e-4)]),
    ("linear, Jacobi, error-controlled", "jacobi", "linear", [(1e-3, t) for t in (1e-3, 5e-4, 2e-4)]),
)
MODEL_EXCHANGE = [(f"model exchange, one ODE ({method})", method, (1e-3, 1e-4, 1e-5, 1e-6))
                  for method in ("DOP853", "Radau", "BDF")]


def deviation(result: np.ndarray, reference: np.ndarray) -> float:
    t = result["time"]
    return float(np.hypot(result["x"] - np.interp(t, reference["time"], reference["x"]),
                          result["y"] - np.interp(t, reference["time"], reference["y"])).max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--target", type=float, default=1e-3, help="largest position deviation in m (default 1e-3)")
    parser.add_argument("--fmu-dir", default="build/fmus")
    args = parser.parse_args()
    scenario = load_scenario("paper")
    reference = reference_solution(scenario, times=output_times(scenario.simulation.stop_time, 1e-3),
                                   rtol=1e-10, atol=1e-10, method="DOP853")
    costs = {}
    print(f"paper scenario, 30 s, target: max position deviation <= {args.target * 1e3:g} mm")
    print(f"{'scheme':42s} {'setting':>16s} {'deviation':>12s} {'steps':>8s} {'doSteps':>9s} {'wall':>9s}  "
          "(model exchange: steps = derivative evaluations)")
    fmus = ensure_fmus(args.fmu_dir)
    with Cosimulator(fmus) as simulator:
        for label, order, coupling, ladder in SCHEMES:
            for step_size, tolerance in ladder:
                settings = dataclasses.replace(scenario.simulation, step_size=step_size, order=order,
                                               coupling=coupling, tolerance=tolerance, output_interval=1e-2)
                run = simulator.run(dataclasses.replace(scenario, simulation=settings))
                error = deviation(run.result, reference)
                setting = f"h = {step_size:g} s" if tolerance is None else f"tol = {tolerance:g} m"
                print(f"{label:42s} {setting:>16s} {error * 1e3:9.3f} mm {run.steps:8d} {run.fmu_steps:9d} "
                      f"{run.wall_time:7.2f} s", flush=True)
                if error <= args.target:
                    costs[label] = run.wall_time
                    break
    for label, method, ladder in MODEL_EXCHANGE:
        for tolerance in ladder:
            run = simulate_model_exchange(scenario, fmus, tolerance=tolerance, output_interval=1e-2, method=method)
            error = deviation(run.result, reference)
            print(f"{label:42s} {f'rtol = {tolerance:g}':>16s} {error * 1e3:9.3f} mm {run.evaluations:8d} {'-':>9s} "
                  f"{run.wall_time:7.2f} s  {run.settings['jacobian_evaluations']} Jacobians", flush=True)
            if error <= args.target:
                costs[label] = run.wall_time
                break
    base = costs.get(SCHEMES[0][0])
    print(f"\nwall time to reach {args.target * 1e3:g} mm, against hold with Gauss-Seidel:")
    for label in [scheme[0] for scheme in SCHEMES] + [scheme[0] for scheme in MODEL_EXCHANGE]:
        if label not in costs:
            print(f"  {label:42s} not reached on its ladder")
        elif base is not None:
            print(f"  {label:42s} {costs[label]:7.2f} s   {base / costs[label]:6.1f} x less")


if __name__ == "__main__":
    main()
