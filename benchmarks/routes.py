"""Every route to co-simulate the paper's scenario, side by side with its deviation from the reference solution.

Run: ``python benchmarks/routes.py [--step-size 1e-3] [--stop-time 30]``. Each route runs the same
closed loop at the same communication step (model exchange has none: the FMUs are one ODE, solved to
the tolerance given); the deviation is the largest distance between its robot position and the
reference solution's, over the points where both are recorded. Without libcosimpy (the extra
``libcosim``) the two libcosim routes are left out, with one line saying why.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from fmpy import simulate_fmu

from dsc_fmu.fmubuild.fmus import ensure_fmus
from dsc_fmu.interop.container import export_fmu
from dsc_fmu.interop.libcosim import run_libcosim, run_libcosim_fmu_in_own_process
from dsc_fmu.interop.libcosim_install import LibcosimUnavailableError, require_libcosimpy
from dsc_fmu.cosim.master import cosimulate
from dsc_fmu.cosim.model_exchange import simulate_model_exchange
from dsc_fmu.cosim.reference_solution import reference_solution
from dsc_fmu.scenario import load_scenario
from dsc_fmu.interop.ssp import export_ssp, run_simulate_ssp


def deviation(result, reference) -> float:
    x = np.interp(result["time"], reference["time"], reference["x"])
    y = np.interp(result["time"], reference["time"], reference["y"])
    return float(np.max(np.hypot(result["x"] - x, result["y"] - y)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step-size", type=float, default=1e-3)
    parser.add_argument("--stop-time", type=float, default=30.0)
    args = parser.parse_args()
    h, stop = args.step_size, args.stop_time
    try:
        require_libcosimpy("each libcosim route")
        libcosim = True
    except LibcosimUnavailableError as error:
        print(f"routes.py: the libcosim routes are left out: {error}")
        libcosim = False
    scenario = load_scenario("paper").with_simulation(step_size=h, stop_time=stop)
    reference = reference_solution(scenario, times=np.linspace(0.0, stop, round(stop / 1e-3) + 1))
    rows = []
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_routes_") as tmp:
        tmp = Path(tmp)
        fmi2, fmi3 = ensure_fmus(tmp / "fmus", fmi_version=2), ensure_fmus(tmp / "fmus3", fmi_version=3)
        for label, fmus, order, command in (
            ("three FMI 2.0 FMUs, our master, Gauss-Seidel", fmi2, "gauss-seidel", "dsc-fmu run"),
            ("three FMI 2.0 FMUs, our master, Jacobi", fmi2, "jacobi", "dsc-fmu run --order jacobi"),
            ("three FMI 3.0 FMUs, our master, Gauss-Seidel", fmi3, "gauss-seidel", "cosimulate(scenario, ensure_fmus(fmi_version=3))"),
            ("three FMI 3.0 FMUs, our master, Jacobi", fmi3, "jacobi", "cosimulate(..., order='jacobi')"),
        ):
            start = time.perf_counter()
            result = cosimulate(scenario, fmus, order=order).result
            rows.append((label, command, deviation(result, reference), time.perf_counter() - start))
        for label, fmus, tolerance, command in (
            ("three FMI 2.0 FMUs, model exchange, 1e-6", fmi2, 1e-6, "dsc-fmu run --interface model-exchange"),
            ("three FMI 2.0 FMUs, model exchange, 1e-9", fmi2, 1e-9, "... --interface model-exchange --tolerance 1e-9"),
            ("three FMI 3.0 FMUs, model exchange, 1e-6", fmi3, 1e-6, "simulate_model_exchange(scenario, fmus)"),
        ):
            start = time.perf_counter()
            result = simulate_model_exchange(scenario, fmus, tolerance=tolerance).result
            rows.append((label, command, deviation(result, reference), time.perf_counter() - start))
        ssp = export_ssp(scenario, tmp / "paper.ssp", fmi2)
        if libcosim:
            start = time.perf_counter()
            result = run_libcosim(ssp, h, stop)
            rows.append(("SSP archive in libcosim (libcosimpy)", "dsc-fmu export-ssp -o paper.ssp; run_libcosim(...)",
                         deviation(result, reference), time.perf_counter() - start))
        start = time.perf_counter()
        result = run_simulate_ssp(ssp, h, stop)
        result["time"] += h  # simulate_ssp stamps each row with the start of the step that produced it
        rows.append(("SSP archive in fmpy.ssp.simulate_ssp", "dsc-fmu export-ssp -o paper.ssp; run_simulate_ssp(...)",
                     deviation(result, reference), time.perf_counter() - start))
        container = export_fmu(scenario, tmp / "loop.fmu", fmi2)
        start = time.perf_counter()
        result = simulate_fmu(str(container), stop_time=stop, step_size=h, output_interval=0.01, output=["x", "y"])
        rows.append(("closed-loop container FMU in fmpy", "dsc-fmu export-fmu -o loop.fmu; fmpy simulate loop.fmu",
                     deviation(result, reference), time.perf_counter() - start))
        if libcosim:
            start = time.perf_counter()
            result = run_libcosim_fmu_in_own_process(container, h, stop, ["x", "y"])
            rows.append(("closed-loop container FMU in libcosim", "run_libcosim_fmu('loop.fmu', ...)",
                         deviation(result, reference), time.perf_counter() - start))
    print(f"paper scenario, {stop:g} s at a {h:g} s communication step")
    print(f"{'route':<48}{'max deviation (mm)':>20}{'wall time (s)':>15}  command")
    for label, command, value, seconds in rows:
        print(f"{label:<48}{value * 1e3:>20.3g}{seconds:>15.2f}  {command}")


if __name__ == "__main__":
    main()
