"""Benchmark: the paper scenario through the FMUs under fmpy and under a C master, beside the reference
solution and beside a floor.

The C master (``tests/c_master.c``, compiled with Zig's C compiler) drives the same three FMUs from
a process without Python, with the same calls in the same order as the fmpy master, as a C importer
does. The floor is the fmpy master driving three trivial pythonfmu FMUs (pythonfmu's own binary)
with the same interfaces and no model math: what FMI and pythonfmu cost per step by themselves.
Then the cost of one model evaluation through each interface, per FMU: a model-exchange derivative
evaluation (fmi2SetTime, fmi2SetContinuousStates, fmi2GetDerivatives, as a solver calls them) beside a
co-simulation step that evaluates the model once (fmi2DoStep with one explicit Euler step: the
controller's ``discretization = euler``; the plant and the reference with ``max_step`` = the step, whose
RK4 step evaluates four times) and beside the same step with the default RK4 at 1 ms; and one column of
the Jacobian of the state derivatives
(fmi2GetDirectionalDerivative with one known, the mean over the states and inputs) against one
derivative evaluation (``benchmarks/directional_derivatives.py`` measures the same in this process).
The FMUs step in the C traced from their models (docs/traced-c.md); the same FMUs built with ``--no-traced`` run
them in Python, side by side in each table; the C master's step beyond its start-up is the difference of a run of
twice the steps, and model exchange is timed in-process too, from ``tests/c_model_exchange.c``.
Run: ``python benchmarks/benchmark.py [--stop-time 30] [--step-size 1e-3] [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from pythonfmu import FmuBuilder

from dsc_fmu.fmubuild.fmus import build_fmus, ensure_fmus
from dsc_fmu.fmubuild.traced_models import FMU_MODELS, MODELS
from dsc_fmu.registry import FMUS
from dsc_fmu.cosim.master import cosimulate
from dsc_fmu.cosim.reference_solution import reference_solution
from dsc_fmu.scenario import load_scenario

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
from c_hosts import compile_c, run_c, write_plan  # noqa: E402

TRIVIAL_SLAVE = '''
from pythonfmu import Fmi2Slave, Real, Integer, Boolean, Fmi2Causality, Fmi2Variability, Fmi2Initial


class {name}(Fmi2Slave):
    """Same interface as {name}.fmu, no model: outputs stay at zero."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        for name, integer, tunable in {parameters!r}:
            setattr(self, name, 1 if integer else 1.0)
            variability = Fmi2Variability.tunable if tunable else Fmi2Variability.fixed
            kind = Integer if integer else Real
            self.register_variable(kind(name, causality=Fmi2Causality.parameter, variability=variability))
        for name in {inputs!r}:
            setattr(self, name, 1.0)
            self.register_variable(Real(name, causality=Fmi2Causality.input))
        for name in {outputs!r}:
            setattr(self, name, 1.0)
            self.register_variable(Real(name, causality=Fmi2Causality.output, initial=Fmi2Initial.exact))
        for name, boolean in {discrete_outputs!r}:
            setattr(self, name, False if boolean else 0)
            self.register_variable((Boolean if boolean else Integer)(
                name, causality=Fmi2Causality.output, variability=Fmi2Variability.discrete, initial=Fmi2Initial.exact,
            ))

    def do_step(self, current_time, step_size):
        return True
'''


def build_trivial_fmus(out_dir: Path) -> dict[str, Path]:
    """Build FMUs with the interfaces of ours and no model behind them."""
    paths = {}
    for name, spec in FMUS.items():
        script = out_dir / f"trivial_{name.lower()}.py"
        script.write_text(TRIVIAL_SLAVE.format(
            name=name,
            parameters=[(v.name, v.integer, v.tunable) for v in spec.parameters],
            inputs=[v.name for v in spec.inputs],
            outputs=[v.name for v in spec.outputs],
            discrete_outputs=[(output, boolean) for output, _, boolean, _ in MODELS[FMU_MODELS[name]]().discrete_outputs(None)],
        ))
        paths[name] = FmuBuilder.build_FMU(script, dest=out_dir / f"{name}.fmu")
    return paths


def _c_master_run(tmp: Path, fmus: dict[str, Path], steps: int, step_size: float) -> None:
    """One paper run of the C master over freshly extracted FMUs, as ``cosimulate`` extracts its own."""
    from fmpy import extract

    master = tmp / "c_master"
    if not master.exists():
        compile_c("c_master.c", master)
    run_dir = Path(tempfile.mkdtemp(dir=tmp))
    unzipped = {name: Path(extract(str(path), unzipdir=run_dir / name)) for name, path in fmus.items()}
    plan = write_plan(run_dir / "plan.txt", unzipped, steps, step_size, "gauss-seidel", False, steps, {})
    run = run_c([master, plan], run_dir)
    if run.returncode != 0:
        raise RuntimeError(f"the C master failed: {run.stderr[-500:]}")


def _c_master_step(tmp: Path, fmus: dict[str, Path], steps: int, step_size: float, repeat: int) -> float:
    """Seconds per step of the C master beyond its start-up (CPython's and the FMUs'): the best run of ``2 steps``
    less the best of ``steps``, over ``steps``."""
    once = _best(lambda: _c_master_run(tmp, fmus, steps, step_size), repeat)
    twice = _best(lambda: _c_master_run(tmp, fmus, 2 * steps, step_size), repeat)
    return (twice - once) / steps


def _in_process_costs(fmus: dict[str, Path], tmp: Path, calls: int = 20000) -> dict[str, tuple]:
    """Per FMU, the processor seconds of a derivative evaluation and of a Jacobian column (all state derivatives
    by the first input, or the first state without inputs), FMI 2.0 model exchange from ``tests/c_model_exchange.c``:
    a C importer with no Python in its loop, after 100 RK4 steps of 1 ms."""
    from fmpy import extract, read_model_description

    host = tmp / "c_model_exchange"
    if not host.exists():
        compile_c("c_model_exchange.c", host)
    costs = {}
    for name, path in fmus.items():
        md = read_model_description(str(path))
        folder = extract(str(path), unzipdir=tmp / f"in_process_{path.parent.name}_{name}")
        inputs = [v.valueReference for v in md.modelVariables if v.causality == "input"]
        known = inputs[0] if inputs else md.derivatives[0].variable.derivative.valueReference
        unknowns = ",".join(str(d.variable.valueReference) for d in md.derivatives)
        run = run_c([host, 2, folder, name, md.guid, len(md.derivatives), md.numberOfEventIndicators, 100, 1e-3,
                     md.derivatives[0].variable.valueReference],
                    tmp, env={"PATH": "/usr/bin:/bin", "TIMING": str(calls), "JACOBIAN": f"{known}:{unknowns}"})
        if run.returncode != 0:
            raise RuntimeError(f"c_model_exchange failed on {name}: {run.stderr[-500:]}")
        timing = next(line for line in run.stdout.splitlines() if line.startswith("timing,"))
        costs[name] = tuple(float(value) for value in timing.split(",")[1:])
    return costs


def _column_cost(model, md, calls: int) -> float:
    """Seconds per Jacobian column of the state derivatives through fmi2GetDirectionalDerivative, one known
    per call, the mean over the states and inputs."""
    unknowns = [d.variable.valueReference for d in md.derivatives]
    knowns = [d.variable.derivative.valueReference for d in md.derivatives]
    knowns += [v.valueReference for v in md.modelVariables if v.causality == "input" and v.type == "Real"]
    rounds = max(1, calls // len(knowns))
    start = time.perf_counter()
    for _ in range(rounds):
        for known in knowns:
            model.getDirectionalDerivative(unknowns, [known], [1.0])
    return (time.perf_counter() - start) / (rounds * len(knowns))


def _evaluation_costs(fmus: dict[str, Path], tmp: Path, calls: int = 2000) -> dict[str, tuple]:
    """Per FMU, the seconds per call of: a derivative evaluation (model exchange), a co-simulation step
    with one evaluation of the model (the controller's Euler; None for the RK4-only plant and reference),
    a co-simulation step of 1 ms (RK4: four evaluations) and a Jacobian column (``_column_cost``)."""
    import ctypes

    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Model, FMU2Slave

    from dsc_fmu.platforms import library_path

    costs = {}
    for name, path in fmus.items():
        md = read_model_description(str(path))
        folder = extract(str(path), unzipdir=tmp / f"eval_{name}")
        library = library_path(folder, 2, name)
        model = FMU2Model(guid=md.guid, unzipDirectory=folder, modelIdentifier=name, instanceName=name,
                          libraryPath=library)
        model.instantiate()
        model.setupExperiment(startTime=0.0)
        model.enterInitializationMode()
        model.exitInitializationMode()
        model.newDiscreteStates()
        model.enterContinuousTimeMode()
        n = len(md.derivatives)
        x, dx = (ctypes.c_double * n)(), (ctypes.c_double * n)()
        model.getContinuousStates(x, n)
        start = time.perf_counter()
        for k in range(calls):
            model.setTime(k * 1e-4)
            model.setContinuousStates(x, n)
            model.getDerivatives(dx, n)
        derivative = (time.perf_counter() - start) / calls
        column = _column_cost(model, md, calls)
        model.terminate()
        model.freeInstance()
        steps = []
        for euler in (True, False):
            if euler and name != "DSCController":
                steps.append(None)
                continue
            slave = FMU2Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=name, instanceName=name,
                              libraryPath=library)
            slave.instantiate()
            slave.setupExperiment(startTime=0.0)
            slave.enterInitializationMode()
            if euler:
                refs = {v.name: v.valueReference for v in md.modelVariables}
                slave.setInteger([refs["discretization"]], [1])
            slave.exitInitializationMode()
            start = time.perf_counter()
            for k in range(calls):
                slave.doStep(k * 1e-3, 1e-3)
            steps.append((time.perf_counter() - start) / calls)
            slave.terminate()
            slave.freeInstance()
        costs[name] = (derivative, *steps, column)
    return costs


def _best(function, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stop-time", type=float, default=30.0)
    parser.add_argument("--step-size", type=float, default=1e-3)
    parser.add_argument("--repeat", type=int, default=3, help="best of this many runs")
    args = parser.parse_args()
    scenario = load_scenario("paper").with_simulation(stop_time=args.stop_time, step_size=args.step_size)
    steps = round(args.stop_time / args.step_size)
    with tempfile.TemporaryDirectory(prefix="dsc_fmu_bench_") as tmp:
        tmp = Path(tmp)
        ours = ensure_fmus(tmp / "fmus")
        python = build_fmus(tmp / "python", traced=False)
        trivial = build_trivial_fmus(tmp)
        fmus = _best(lambda: cosimulate(scenario, ours), args.repeat)
        fmus_python = _best(lambda: cosimulate(scenario, python), args.repeat)
        c_master = _best(lambda: _c_master_run(tmp, ours, steps, args.step_size), args.repeat)
        c_master_python = _best(lambda: _c_master_run(tmp, python, steps, args.step_size), args.repeat)
        c_step = _c_master_step(tmp, ours, steps, args.step_size, args.repeat)
        floor = _best(lambda: cosimulate(scenario, trivial), args.repeat)
        costs = _evaluation_costs(ours, tmp)
        in_process = {"traced": _in_process_costs(ours, tmp), "python": _in_process_costs(python, tmp)}
    monolithic = _best(lambda: reference_solution(scenario), args.repeat)
    print(f"paper scenario, {args.stop_time:g} s at a {args.step_size:g} s step ({steps} steps), best of {args.repeat}")
    print("(the FMUs step in the C traced from their models; 'Python': built with --no-traced, docs/traced-c.md)")
    print(f"{'route':<50}{'wall time (s)':>15}{'per step (us)':>15}{'ratio':>8}")
    rows = (
        ("three FMUs under the fmpy master", fmus),
        ("three FMUs under the fmpy master, Python", fmus_python),
        ("three FMUs under a C master (no Python)", c_master),
        ("three FMUs under a C master, Python", c_master_python),
        ("reference solution (one ODE, scipy)", monolithic),
        ("floor: same master, three trivial FMUs", floor),
    )
    for label, seconds in rows:
        print(f"{label:<50}{seconds:>15.3f}{seconds / steps * 1e6:>15.1f}{seconds / fmus:>8.2f}")
    print(f"{'C master, one step beyond start-up':<50}{'':>15}{c_step * 1e6:>15.2f}")
    print(f"FMUs / reference solution: {fmus / monolithic:.2f}   FMUs / floor: {fmus / floor:.2f} (target <= 1.0)   "
          f"C master / fmpy master: {c_master / fmus:.2f}   Python / traced: fmpy {fmus_python / fmus:.1f}, "
          f"C master {c_master_python / c_master:.1f}")
    print()
    print("one model evaluation per call, FMI 2.0 through fmpy (us per call; ratio: derivative evaluation / step)")
    print(f"{'FMU':<16}{'derivatives (ME)':>18}{'Euler step (CS)':>17}{'RK4 step (CS)':>15}{'ratio Euler':>13}"
          f"{'ratio RK4':>11}")
    for name, (derivative, euler, rk4, _) in costs.items():
        euler_text = f"{euler * 1e6:>17.1f}" if euler else f"{'-':>17}"
        ratio = f"{derivative / euler:>13.2f}" if euler else f"{'-':>13}"
        print(f"{name:<16}{derivative * 1e6:>18.1f}{euler_text}{rk4 * 1e6:>15.1f}{ratio}{derivative / rk4:>11.2f}")
    print("(target: derivative evaluation <= the co-simulation step that evaluates the model once)")
    print()
    print("one Jacobian column of the state derivatives, FMI 2.0 model exchange through fmpy (us per call)")
    print(f"{'FMU':<16}{'derivatives':>13}{'column':>10}{'ratio':>8}")
    for name, (derivative, _, _, column) in costs.items():
        print(f"{name:<16}{derivative * 1e6:>13.1f}{column * 1e6:>10.1f}{column / derivative:>8.2f}")
    print("(target: one column <= 5 x one derivative evaluation)")
    print()
    print("model exchange in-process: a C importer without Python in its loop (tests/c_model_exchange.c), FMI 2.0,")
    print("processor us per call: a derivative evaluation (set time, set states, get derivatives) and a Jacobian column")
    print(f"{'FMU':<16}{'derivatives':>13}{'Python':>9}{'ratio':>8}{'column':>10}{'Python':>9}{'ratio':>8}")
    for name, (derivative, column) in in_process["traced"].items():
        derivative_python, column_python = in_process["python"][name]
        print(f"{name:<16}{derivative * 1e6:>13.2f}{derivative_python * 1e6:>9.2f}{derivative_python / derivative:>8.1f}"
              f"{column * 1e6:>10.2f}{column_python * 1e6:>9.2f}{column_python / column:>8.1f}")
    print("(target: each under 1 us with the traced C)")


if __name__ == "__main__":
    main()
