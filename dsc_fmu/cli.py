"""The ``dsc-fmu`` command line: a thin shell over one public function per command."""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from .fmubuild.fmus import DEFAULT_FMU_DIR, DEFAULT_FMU_DIRS, FMI_VERSIONS
from .errors import DscFmuError
from .models.parameters import DISCRETIZATIONS
from .scenario import (
    COUPLINGS, INTERFACES, ORDERS, REFERENCES, STABILITIES, Coupling, Interface, ScenarioError, load_scenario,
    scenario_names,
)

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dsc-fmu", description="The adaptive DSC of a mobile robot as FMI co-simulation FMUs: build them, "
        "co-simulate a scenario, study the communication step, export the closed loop.")
    commands = parser.add_subparsers(dest="command", required=True)

    build = commands.add_parser("build", help="build the three FMUs")
    build.add_argument("--out", type=Path, help=f"folder for the FMUs (default: {DEFAULT_FMU_DIRS[2]}, "
                       f"{DEFAULT_FMU_DIRS[3]} with --fmi-version 3)")
    build.add_argument("--fmi-version", type=int, choices=FMI_VERSIONS, default=2,
                       help="FMI version of the FMUs (default: %(default)s)")

    for command, what in (("export-ssp", "an SSP 1.0 archive of the closed loop"),
                          ("export-fmu", "one co-simulation FMU of the closed loop (fmpy's container FMU)")):
        export = commands.add_parser(command, help=f"write {what}")
        export.add_argument("scenario", nargs="?", default="paper", help="a scenario name or a TOML file (default: %(default)s)")
        export.add_argument("-o", "--out", type=Path, required=True, help="the file to write")
        export.add_argument("--step-size", type=float, help="communication step in s (default: the scenario's)")
        export.add_argument("--stop-time", type=float, help="stop time in s (default: the scenario's)")
        export.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR,
                            help="FMUs to pack if current (default: %(default)s); else they are built in a temporary folder")

    run = commands.add_parser("run", help="co-simulate a scenario and write results, metrics and figures")
    run.add_argument(
        "scenario", nargs="?", default="paper",
        help=f"a scenario name ({', '.join(scenario_names())}) or a path to a TOML file (default: %(default)s)",
    )
    run.add_argument("--step-size", type=float, help="communication step in s (default: the scenario's)")
    run.add_argument("--stop-time", type=float, help="stop time in s (default: the scenario's)")
    run.add_argument("--order", choices=ORDERS, help="coupling order (default: the scenario's)")
    run.add_argument("--coupling", choices=COUPLINGS, help="hold: inputs held over a step (zero-order hold); linear: "
                     "the plant extrapolates u, the controller interpolates or extrapolates its inputs (default: the scenario's)")
    run.add_argument("--input-derivatives", action=argparse.BooleanOptionalAction,
                     help="with --coupling linear: the master sets the slopes with fmi2SetRealInputDerivatives "
                          "(the standard route, FMI 2.0) instead of the FMUs' coupling parameters (default: the "
                          "scenario's)")
    run.add_argument("--output-interval", type=float, help="recording interval in s (default: the scenario's)")
    run.add_argument("--interface", choices=INTERFACES, default="co-simulation",
                     help="co-simulation: this project's master steps the three FMUs; model-exchange: the three FMUs "
                          "as one ODE, integrated by SciPy's DOP853 with their event indicators (default: %(default)s)")
    run.add_argument("--tolerance", type=float, metavar="TOL", help="co-simulation: error-controlled step, the "
                     "estimated position error (m) each step may add, the step varying within [--h-min, --h-max] "
                     "from --step-size, with the linear coupling unless --coupling says otherwise; model exchange: "
                     "the solver's relative tolerance (default 1e-6)")
    run.add_argument("--h-min", type=float, help="smallest error-controlled step in s (default: the scenario's, 1e-5)")
    run.add_argument("--h-max", type=float, help="largest error-controlled step in s (default: the scenario's, 0.02)")
    run.add_argument("--out", type=Path, help="output folder (default: results/<scenario name>)")
    run.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR, help="where the FMUs are built (default: %(default)s)")
    run.add_argument("--no-plots", action="store_true", help="write no figures")
    run.add_argument("--quiet", action="store_true", help="no progress line and no forecast (errors still show)")

    sweep = commands.add_parser("sweep", help="step-size sensitivity study: a grid of co-simulations and a report")
    sweep.add_argument("scenario", nargs="?", default="paper", help="a scenario name or a TOML file (default: %(default)s)")
    sweep.add_argument("--step-sizes", type=_floats, help="communication steps in s, comma-separated "
                       "(default: 12 log-spaced from 1e-4 to 5e-2)")
    sweep.add_argument("--orders", type=_names, help=f"coupling orders, comma-separated (default: {','.join(ORDERS)})")
    sweep.add_argument("--couplings", type=_names, default=list(COUPLINGS),
                       help=f"couplings, comma-separated: {', '.join(COUPLINGS)} (default: both)")
    sweep.add_argument("--tolerances", type=_optional_floats, metavar="TOL,...",
                       help="tolerances (m) of error-controlled runs, with the linear coupling if --couplings has it "
                       "(else the hold), comma-separated, or '' for none (default: 1e-2,1e-3,1e-4)")
    sweep.add_argument("--discretizations", type=_names,
                       help=f"controller discretizations, comma-separated: {', '.join(DISCRETIZATIONS)} (default: rk4)")
    sweep.add_argument("--set", action="append", default=[], metavar="TABLE.KEY=V1,V2,...",
                       help="sweep a scenario value too, e.g. controller.k4=0.5,1,2 (repeat for a grid)")
    sweep.add_argument("--perturb", action="append", default=[], metavar="plant.KEY=P%|LOW:HIGH",
                       help="draw a plant parameter at random, e.g. plant.mc=20%% (Monte Carlo, with --samples)")
    sweep.add_argument("--samples", type=int, help="number of Monte Carlo samples of the --perturb parameters")
    sweep.add_argument("--seed", type=int, default=0, help="seed of the Monte Carlo draws (default: %(default)s)")
    sweep.add_argument("--stop-time", type=float, help="stop time in s (default: the scenario's)")
    sweep.add_argument("--stability", choices=STABILITIES,
                       help="what a stable run is: settled (where it ends up) or local (it stays with the reference "
                            "solution from its start: for a scenario starting in steady tracking); "
                            "default: the scenario's")
    sweep.add_argument("--reference", choices=REFERENCES,
                       help="what the deviations are measured against: the monolithic ODE of the equations, or the "
                            "three FMUs as one ODE through model exchange (both DOP853 at 1e-10; default: the "
                            "scenario's, monolithic)")
    sweep.add_argument("--jobs", type=int, help="local worker processes (default: all cores)")
    sweep.add_argument("--scheduler", help="address of a Dask distributed scheduler, e.g. tcp://10.0.0.5:8786")
    sweep.add_argument("--no-refine", action="store_true", help="do not bisect the stability boundaries")
    sweep.add_argument("--out", type=Path, help="output folder (default: results/sweep-<scenario name>)")
    sweep.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR, help="where the FMUs are built (default: %(default)s)")

    crosscheck = commands.add_parser("crosscheck", help="write the FMI cross-check artefacts of the three FMUs")
    crosscheck.add_argument("-o", "--out", type=Path, required=True, help="the folder to write them under")
    crosscheck.add_argument("--step-size", type=float, help="communication step in s (default: 1e-3)")
    crosscheck.add_argument("--stop-time", type=float, default=2.0, help="stop time in s (default: %(default)s)")
    crosscheck.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR,
                            help="FMUs to use if current (default: %(default)s); else built in a temporary folder")

    commands.add_parser("scenarios", help="list the scenarios shipped with dsc-fmu")
    return parser


def _floats(text: str) -> list[float]:
    try:
        return [float(item) for item in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of numbers") from None


def _optional_floats(text: str) -> list[float]:
    return _floats(text) if text.strip() else []


def _option(setting: str) -> str:
    """The command-line option of a simulation setting: ``step_size`` is ``--step-size``."""
    return "--" + setting.replace("_", "-")


def _names(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


def _build(args) -> None:
    from .fmubuild.fmus import build_fmus

    for path in build_fmus(args.out, fmi_version=args.fmi_version).values():
        print(path)


def _export(args) -> None:
    from .fmubuild.fmus import current_fmus
    from .interop.container import export_fmu
    from .interop.ssp import export_ssp

    export = {"export-ssp": export_ssp, "export-fmu": export_fmu}[args.command]
    scenario = load_scenario(args.scenario).with_simulation(step_size=args.step_size, stop_time=args.stop_time)
    with current_fmus(args.fmu_dir) as fmus:
        print(export(scenario, args.out, fmus))


def _sweep(args) -> None:
    from .study.cases import DEFAULT_TOLERANCES, Grid, Runner, parse_perturb, parse_set
    from .study.sweep import run_sweep

    scenario = load_scenario(args.scenario).with_simulation(stop_time=args.stop_time, stability=args.stability,
                                                            reference=args.reference)
    grid = Grid(step_sizes=args.step_sizes, orders=args.orders or ORDERS, discretizations=args.discretizations,
                couplings=args.couplings,
                tolerances=DEFAULT_TOLERANCES if args.tolerances is None else args.tolerances,
                sets=[parse_set(text) for text in args.set],
                perturbations=[parse_perturb(text) for text in args.perturb], samples=args.samples, seed=args.seed)
    runner = Runner(jobs=args.jobs, scheduler=args.scheduler)
    print(run_sweep(scenario, args.out or Path("results") / f"sweep-{scenario.name}", grid, runner,
                    fmu_dir=args.fmu_dir, refine=not args.no_refine))


def _crosscheck(args) -> None:
    from .fmubuild.fmus import current_fmus
    from .interop.crosscheck import write_crosscheck

    with current_fmus(args.fmu_dir) as fmus:
        folders = write_crosscheck(args.out, fmus, step_size=args.step_size, stop_time=args.stop_time)
    for folder in folders.values():
        print(folder)


def _scenarios(args) -> None:
    for name in scenario_names():
        print(f"{name}: {load_scenario(name).description}")


_SETTINGS = ("step_size", "stop_time", "order", "coupling", "input_derivatives", "output_interval", "tolerance",
             "h_min", "h_max")  # the simulation settings ``run`` takes as options


_FASTER = "--coupling linear meets the same tolerance with far fewer steps"


def _error_controlled_coupling(args, interface: Interface, scenario) -> tuple[str | None, str, str]:
    """The coupling of a run with ``--tolerance``, what to tell first and how to get there faster:
    without ``--coupling``, the linear coupling (its second-order defect is the estimate the step
    control trusts) in place of the scenario's hold; with the hold, the hold and its cost. An interface
    without a coupling takes ``--tolerance`` as its solver's."""
    if args.tolerance is None or "coupling" not in interface.settings:
        return args.coupling, "", ""
    if args.coupling is None and scenario.simulation.coupling is Coupling.HOLD:
        note = ("dsc-fmu: --tolerance without --coupling: error control with the linear coupling (second order, "
                "whose error estimate the step control trusts); --coupling hold for the first-order hold, which "
                "needs far more steps")
        return Coupling.LINEAR, note, ""
    if Coupling(args.coupling or scenario.simulation.coupling) is Coupling.HOLD:
        note = ("dsc-fmu: error control with the hold coupling (first order): its steps shrink in proportion to the "
                f"tolerance, the linear coupling's with its square root; {_FASTER}")
        return args.coupling, note, _FASTER
    return args.coupling, "", ""


def _run(args) -> int:
    from .cosim.progress import TerminalWatch
    from .cosim.run import run_scenario

    interface = Interface(args.interface)
    given = [name for name in _SETTINGS if getattr(args, name) is not None and name not in interface.settings]
    if given:
        owners = " or ".join(other for other in Interface if given[0] in other.settings)
        allowed = ", ".join(_option(name) for name in interface.settings if name in _SETTINGS)
        raise ScenarioError(f"{_option(given[0])} is a {owners} setting; allowed with --interface {interface}: "
                            f"{allowed}")
    scenario = load_scenario(args.scenario)
    coupling, note, hint = _error_controlled_coupling(args, interface, scenario)
    scenario = scenario.with_simulation(
        step_size=args.step_size, stop_time=args.stop_time, order=args.order, output_interval=args.output_interval,
        coupling=coupling, tolerance=args.tolerance, h_min=args.h_min, h_max=args.h_max,
        input_derivatives=args.input_derivatives,
    )
    if note:
        print(note, file=sys.stderr)
    with TerminalWatch(scenario.simulation.stop_time, scenario.name, quiet=args.quiet, hint=hint) as watch:
        summary = run_scenario(scenario, out_dir=args.out or Path("results") / scenario.name, fmu_dir=args.fmu_dir,
                               plots=not args.no_plots, interface=interface, watch=watch)
    print(summary)  # below the progress line, which leaving the block cleared
    return 130 if watch.interrupted else 0


COMMANDS = {"build": _build, "export-ssp": _export, "export-fmu": _export, "sweep": _sweep, "crosscheck": _crosscheck,
            "scenarios": _scenarios, "run": _run}


def _warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings as one line on stderr, like the errors."""
    print(f"dsc-fmu: warning: {message}", file=sys.stderr if file is None else file)


def main(argv: list[str] | None = None) -> int:
    """Run the ``dsc-fmu`` command line.

    Each command calls one public function and imports what it needs when it runs. Errors a user
    can fix (``DscFmuError``, ``OSError``) are printed as one line on stderr.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after the program's name; None (default) takes ``sys.argv[1:]``.

    Returns
    -------
    int
        The exit status: 0 on success, 1 on an error the user can fix, 130 when interrupted.
    """
    args = _parser().parse_args(argv)
    shown = warnings.showwarning
    warnings.showwarning = _warning
    try:
        status = COMMANDS[args.command](args)
    except (DscFmuError, OSError) as error:  # OSError: a file or folder the system refuses
        print(f"dsc-fmu: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        kept = "; finished runs are kept in the cache" if args.command == "sweep" else ""
        print(f"dsc-fmu: interrupted{kept}", file=sys.stderr)
        return 130
    finally:
        warnings.showwarning = shown
    return status or 0


if __name__ == "__main__":
    sys.exit(main())
