"""The ``dsc-fmu`` command line: a thin shell over one public function per command.

Every option is declared once, in ``_OPTIONS``; an option left out is not passed on, so its default is its
owner's (the scenario, ``Grid``, the builder), which its help reads. Only the command run gets its options,
so that it imports only the owners it needs.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from .errors import DscFmuError, FmiVersionError
from .fmubuild.folders import DEFAULT_FMI_VERSION, DEFAULT_FMU_DIRS, FMI_VERSIONS, resolve_fmu_dir
from .models.parameters import DISCRETIZATIONS
from .scenario import (
    COUPLINGS, INTERFACES, METHODS, ORDERS, REFERENCES, STABILITIES, Coupling, Interface, ScenarioError, Simulation,
    load_scenario, scenario_names,
)

__all__ = ["main"]


def _floats(text: str) -> list[float]:
    try:
        return [float(item) for item in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of numbers") from None


def _optional_floats(text: str) -> list[float]:
    return _floats(text) if text.strip() else []


def _names(text: str) -> list[str]:
    names = [item.strip() for item in text.split(",") if item.strip()]
    if not names:
        raise argparse.ArgumentTypeError(f"{text!r} names none; allowed: one or more names, comma-separated")
    return names


@dataclass(frozen=True)
class _Option:
    """A command-line option: its flags, its help (``{fields}`` filled from the values' owners), ``add_argument``'s keywords."""

    flags: tuple
    help: str
    keywords: dict


def _option(*flags: str, help: str, **keywords) -> _Option:
    return _Option(flags, help, keywords)


_SCENARIOS = "the scenario's"
_OPTIONS = {
    "scenario": _option("scenario", nargs="?", help="a scenario name ({names}) or a TOML file (default: %(default)s)"),
    "step_size": _option("--step-size", type=float, help="communication step in s (default: {default})"),
    "stop_time": _option("--stop-time", type=float, help="stop time in s (default: {default})"),
    "fmu_dir": _option("--fmu-dir", type=Path, help="folder of the three FMUs, {use} (default: {default})"),
    "fmi_version": _option("--fmi-version", type=int, choices=FMI_VERSIONS, help="FMI version of the FMUs{only} "
                           "(default: that of the FMUs in the folder, else {default}); FMUs of another version are "
                           "never replaced"),
    "bundle_python": _option("--bundle-python", nargs="?", const=True, default=False, metavar="3.X", help="each FMU "
                             "carries a CPython for Linux and Windows, so the importing machine needs none: "
                             "Linux's is the building CPython's, Windows' the official embeddable CPython 3.X "
                             f"(default: the building CPython's minor, {sys.version_info.major}."
                             f"{sys.version_info.minor}); without it the FMUs use the "
                             "importing machine's CPython 3.9 or newer"),
    "traced": _option("--no-traced", action="store_false", help="build FMUs that run their models in Python only, "
                      "without the C traced from them (docs/traced-c.md; per instance, the parameter traced = off)"),
    "interface": _option("--interface", choices=INTERFACES, help="co-simulation: the FMUs stepped at the "
                         "communication step{stepped}; model-exchange: the three FMUs as one ODE{integrated} "
                         "(default: {default})"),
    "order": _option("--order", choices=ORDERS, help="coupling order (default: {default})"),
    "coupling": _option("--coupling", choices=COUPLINGS, help="hold: inputs held over a step (zero-order hold); "
                        "linear: the plant extrapolates u, the controller interpolates or extrapolates its inputs "
                        "(default: {default})"),
    "input_derivatives": _option("--input-derivatives", action=argparse.BooleanOptionalAction, help="with "
                                 "--coupling linear: the master sets the slopes with fmi2SetRealInputDerivatives (the "
                                 "standard route, FMI 2.0) instead of the FMUs' coupling parameters "
                                 "(default: {default})"),
    "output_interval": _option("--output-interval", type=float, help="recording interval in s (default: {default})"),
    "method": _option("--method", choices=METHODS, help="model exchange's integrator: SciPy's DOP853 (explicit), or "
                      "Radau and BDF (implicit, with the loop's Jacobian from the FMUs' directional derivatives) "
                      "(default: {default})"),
    "tolerance": _option("--tolerance", type=float, metavar="TOL", help="co-simulation: error-controlled step, the "
                         "estimated position error (m) each step may add, the step varying within [--h-min, --h-max] "
                         "from --step-size, with the linear coupling unless --coupling says otherwise; model exchange: "
                         "the solver's relative tolerance (default: {default}; model exchange: {solver} where it "
                         "sets none)"),
    "h_min": _option("--h-min", type=float, help="smallest error-controlled step in s (default: {default}, {unset} "
                     "where it sets none)"),
    "h_max": _option("--h-max", type=float, help="largest error-controlled step in s (default: {default}, {unset} "
                     "where it sets none)"),
    "no_plots": _option("--no-plots", action="store_true", help="write no figures"),
    "quiet": _option("--quiet", action="store_true", help="no progress line{forecast} (errors still show)"),
    "step_sizes": _option("--step-sizes", type=_floats, help="communication steps in s, comma-separated "
                          "(default: {default})"),
    "orders": _option("--orders", type=_names, help=f"coupling orders, comma-separated: {', '.join(ORDERS)} "
                      "(default: {default})"),
    "couplings": _option("--couplings", type=_names, help=f"couplings, comma-separated: {', '.join(COUPLINGS)} "
                         "(default: {default})"),
    "discretizations": _option("--discretizations", type=_names, help="controller discretizations, "
                               f"comma-separated: {', '.join(DISCRETIZATIONS)} (default: {{default}})"),
    "tolerances": _option("--tolerances", type=_optional_floats, metavar="TOL,...", help="tolerances (m) of "
                          "error-controlled runs, with the linear coupling if --couplings has it (else the hold), "
                          "comma-separated, or '' for none (default: {default})"),
    "set": _option("--set", action="append", metavar="TABLE.KEY=V1,V2,...", help="sweep a scenario value too, e.g. "
                   "controller.k4=0.5,1,2 (repeat for a grid)"),
    "perturb": _option("--perturb", action="append", metavar="plant.KEY=P%|LOW:HIGH", help="draw a plant parameter "
                       "at random, e.g. plant.mc=20%% (Monte Carlo, with --samples)"),
    "samples": _option("--samples", type=int, help="number of Monte Carlo samples of the --perturb parameters"),
    "seed": _option("--seed", type=int, help="seed of the Monte Carlo draws (default: {default})"),
    "stability": _option("--stability", choices=STABILITIES, help="what a stable run is: settled (where it ends up) "
                         "or local (it stays with the reference solution from its start: for a scenario starting in "
                         "steady tracking) (default: {default})"),
    "reference": _option("--reference", choices=REFERENCES, help="what the deviations are measured against: the "
                         "monolithic ODE of the equations, or the three FMUs as one ODE through model exchange "
                         "(default: {default})"),
    "jobs": _option("--jobs", type=int, help="local worker processes (default: all cores)"),
    "scheduler": _option("--scheduler", help="address of a Dask distributed scheduler, e.g. tcp://10.0.0.5:8786"),
    "no_refine": _option("--no-refine", action="store_true", help="do not bisect the stability boundaries"),
}


def _add(parser: argparse.ArgumentParser, *names: str, flags: tuple = (), **fields) -> None:
    """Add the options ``names`` of ``_OPTIONS`` (under ``flags`` if given), their help's fields filled in
    (``default``: the scenario's unless given)."""
    for name in names:
        option = _OPTIONS[name]
        keywords = {"dest": name, **option.keywords} if option.flags[0].startswith("-") else option.keywords
        help = option.help.format(**{"default": _SCENARIOS, **fields})
        parser.add_argument(*(flags or option.flags), help=help, **keywords)


def _add_fmus(parser: argparse.ArgumentParser, use: str, command: str = "", flags: tuple = ()) -> None:
    """The FMU folder and FMI version options of ``command``, their defaults those of ``fmubuild.folders``."""
    folders = ", ".join(f"{folder} for FMI {version}.0" for version, folder in DEFAULT_FMU_DIRS.items())
    _add(parser, "fmu_dir", flags=flags, use=use, default=folders)
    only = f": 2 only, since {_fmi2_only(command)}" if command in _FMI2_ONLY else ""
    _add(parser, "fmi_version", only=only, default=DEFAULT_FMI_VERSION)


def _add_scenario(parser: argparse.ArgumentParser) -> None:
    _add(parser, "scenario", names=", ".join(scenario_names()))
    parser.set_defaults(scenario=_default(load_scenario, "name_or_path"))


def _default(function, parameter: str):
    return inspect.signature(function).parameters[parameter].default


_BUILT_THERE = "built there if missing or out of date"
_USED_IF_CURRENT = "used if current, else built in a temporary folder"
# The commands that take FMI 2.0 FMUs only, and why.
_FMI2_ONLY = {"export-ssp": "dsc_fmu.interop.ssp", "crosscheck": "dsc_fmu.interop.crosscheck"}


def _fmi2_only(command: str) -> str:
    """Why ``command`` takes FMI 2.0 FMUs only (its module's ``FMI2_ONLY``), or "" if it takes both."""
    return importlib.import_module(_FMI2_ONLY[command]).FMI2_ONLY if command in _FMI2_ONLY else ""


def _build_options(parser: argparse.ArgumentParser) -> None:
    _add_fmus(parser, "built there", flags=("--out", "--fmu-dir"))
    _add(parser, "bundle_python", "traced")


def _run_options(parser: argparse.ArgumentParser) -> None:
    from .cosim.model_exchange import DEFAULT_TOLERANCE, METHOD
    from .cosim.run import run_scenario

    _add_scenario(parser)
    _add(parser, "step_size", "stop_time", "order", "coupling", "input_derivatives", "output_interval")
    _add(parser, "interface", stepped=" by this project's master",
         integrated=f", integrated by SciPy's {METHOD} with their event indicators", default=_default(run_scenario, "interface"))
    _add(parser, "tolerance", solver=f"{DEFAULT_TOLERANCE:g}")
    _add(parser, "method", default=METHOD)
    for name in ("h_min", "h_max"):
        _add(parser, name, unset=f"{getattr(Simulation, name):g}")
    parser.add_argument("--out", type=Path, help="output folder (default: results/<scenario name>)")
    _add_fmus(parser, _BUILT_THERE)
    _add(parser, "no_plots")
    _add(parser, "quiet", forecast=" and no forecast")


def _sweep_options(parser: argparse.ArgumentParser) -> None:
    from .study.cases import Grid

    grid = Grid()
    _add_scenario(parser)
    steps = grid.step_sizes
    _add(parser, "step_sizes", default=f"{len(steps)} log-spaced from {min(steps):g} to {max(steps):g}")
    for name in ("orders", "couplings", "discretizations"):
        _add(parser, name, **({} if getattr(grid, name) is None else {"default": ",".join(getattr(grid, name))}))
    _add(parser, "tolerances", default=",".join(f"{t:g}" for t in grid.tolerances))
    _add(parser, "set", "perturb", "samples")
    _add(parser, "seed", default=grid.seed)
    _add(parser, "stop_time", "stability", "reference", "jobs", "scheduler", "no_refine")
    _add(parser, "quiet", forecast="")
    parser.add_argument("--out", type=Path, help="output folder (default: results/sweep-<scenario name>)")
    _add_fmus(parser, _BUILT_THERE)


def _export_options(parser: argparse.ArgumentParser, command: str) -> None:
    _add_scenario(parser)
    parser.add_argument("-o", "--out", type=Path, required=True, help="the file to write")
    _add(parser, "step_size", "stop_time")
    if command == "export-ssp":
        from .interop.ssp import export_ssp

        _add(parser, "interface", stepped=" by the importing tool's master", integrated=", integrated by the "
             "importing tool", default=_default(export_ssp, "interface"))
    _add_fmus(parser, _USED_IF_CURRENT, command)
    _add(parser, "bundle_python")


def _crosscheck_options(parser: argparse.ArgumentParser) -> None:
    from .interop.crosscheck import DEFAULT_STOP_TIME

    parser.add_argument("-o", "--out", type=Path, required=True, help="the folder to write them under")
    _add(parser, "step_size")
    _add(parser, "stop_time", default=f"{DEFAULT_STOP_TIME:g}")
    _add_fmus(parser, _USED_IF_CURRENT, "crosscheck")


def _laws_options(parser: argparse.ArgumentParser) -> None:
    from .models.parameters import ADAPTATIONS
    from .study.laws import DEFAULT_SCENARIOS

    parser.add_argument("scenarios", nargs="*", metavar="scenario", help="scenario names "
                        f"({', '.join(scenario_names())}) or TOML files (default: {' '.join(DEFAULT_SCENARIOS)})")
    parser.add_argument("--laws", type=_names, help=f"adaptation laws, comma-separated: {', '.join(ADAPTATIONS)} "
                        "(default: all)")
    _add(parser, "step_size", "stop_time")
    parser.add_argument("--out", type=Path, help="output folder (default: results/laws)")
    _add_fmus(parser, _BUILT_THERE)


def _given(args: argparse.Namespace, *names: str) -> dict:
    """The options among ``names`` the user gave, by name: the others keep their owners' defaults."""
    return {name: getattr(args, name) for name in names if getattr(args, name, None) is not None}


def _fmus(args: argparse.Namespace) -> tuple[Path, int]:
    """The FMU folder and FMI version of a command (``resolve_fmu_dir``), refused in one line if the
    command does not take FMUs of that version."""
    folder, version = resolve_fmu_dir(args.fmu_dir, args.fmi_version)
    if version != 2 and args.command in _FMI2_ONLY:
        raise FmiVersionError(f"{args.command} with FMI {version}.0 FMUs ({folder}) is not allowed: "
                              f"{_fmi2_only(args.command)}; allowed: FMI 2.0 FMUs (--fmi-version 2, a folder without "
                              f"FMI {version}.0 FMUs)")
    return folder, version


def _build(args) -> None:
    from .fmubuild.fmus import build_fmus
    from .identity import BUILD_ID_FILE, fmu_untraced

    folder, version = _fmus(args)
    for path in build_fmus(folder, fmi_version=version, bundle_python=args.bundle_python, traced=args.traced).values():
        untraced = fmu_untraced(path)
        reasons = sorted({reason.split(": ", 1)[-1] for reason in (untraced or {}).values()})
        print(path if not untraced else f"{path}: {len(untraced)} functions run in Python, not traced to C (listed in "
              f"its {BUILD_ID_FILE}): {'; '.join(reasons)}")


def _export(args) -> None:
    from .fmubuild.fmus import current_fmus
    from .interop.container import export_fmu
    from .interop.ssp import export_ssp

    export = {"export-ssp": export_ssp, "export-fmu": export_fmu}[args.command]
    scenario = load_scenario(args.scenario).with_simulation(step_size=args.step_size, stop_time=args.stop_time)
    interface = {"interface": Interface(args.interface)} if getattr(args, "interface", None) else {}  # export-ssp
    folder, version = _fmus(args)
    with current_fmus(folder, version, args.bundle_python) as fmus:
        print(export(scenario, args.out, fmus, **interface))


def _sweep(args) -> None:
    from .study.cases import Grid, Runner, parse_perturb, parse_set
    from .study.sweep import run_sweep

    scenario = load_scenario(args.scenario).with_simulation(stop_time=args.stop_time, stability=args.stability,
                                                            reference=args.reference)
    grid = Grid(**_given(args, "step_sizes", "orders", "discretizations", "couplings", "tolerances", "samples", "seed"),
                sets=[parse_set(text) for text in args.set or ()],
                perturbations=[parse_perturb(text) for text in args.perturb or ()])
    folder, version = _fmus(args)
    print(run_sweep(scenario, args.out or Path("results") / f"sweep-{scenario.name}", grid,
                    Runner(**_given(args, "jobs", "scheduler"), progress=not args.quiet), fmu_dir=folder, fmi_version=version,
                    refine=not args.no_refine))


def _crosscheck(args) -> None:
    from .fmubuild.fmus import current_fmus
    from .interop.crosscheck import write_crosscheck

    folder, version = _fmus(args)
    with current_fmus(folder, version) as fmus:
        folders = write_crosscheck(args.out, fmus, **_given(args, "step_size", "stop_time"))
    for folder in folders.values():
        print(folder)


def _laws(args) -> None:
    from .study.laws import DEFAULT_SCENARIOS, compare_adaptation_laws

    scenarios = [load_scenario(name).with_simulation(step_size=args.step_size, stop_time=args.stop_time)
                 for name in args.scenarios or DEFAULT_SCENARIOS]
    folder, version = _fmus(args)
    print(compare_adaptation_laws(scenarios, args.out or Path("results") / "laws", **_given(args, "laws"),
                                  fmu_dir=folder, fmi_version=version))


def _scenarios(args) -> None:
    for name in scenario_names():
        print(f"{name}: {load_scenario(name).description}")


_SETTINGS = ("step_size", "stop_time", "order", "coupling", "input_derivatives", "output_interval", "tolerance",
             "method", "h_min", "h_max")  # the simulation settings ``run`` takes as options


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


def _flag(name: str) -> str:
    return _OPTIONS[name].flags[0]


def _run(args) -> int:
    from .cosim.progress import TerminalWatch
    from .cosim.run import run_scenario

    interface = Interface(args.interface or Interface.CO_SIMULATION)
    given = [name for name in _SETTINGS if getattr(args, name) is not None and name not in interface.settings]
    if given:
        owners = " or ".join(other for other in Interface if given[0] in other.settings)
        allowed = ", ".join(_flag(name) for name in interface.settings if name in _SETTINGS)
        raise ScenarioError(f"{_flag(given[0])} is a {owners} setting; allowed with --interface {interface}: {allowed}")
    scenario = load_scenario(args.scenario)
    coupling, note, hint = _error_controlled_coupling(args, interface, scenario)
    scenario = scenario.with_simulation(**{**{name: getattr(args, name) for name in _SETTINGS}, "coupling": coupling})
    folder, version = _fmus(args)
    if note:
        print(note, file=sys.stderr)
    with TerminalWatch(scenario.simulation.stop_time, scenario.name, quiet=args.quiet, hint=hint) as watch:
        summary = run_scenario(scenario, out_dir=args.out or Path("results") / scenario.name, fmu_dir=folder,
                               fmi_version=version, plots=not args.no_plots, interface=interface, watch=watch)
    print(summary)  # below the progress line, which leaving the block cleared
    return 130 if watch.interrupted else 0


@dataclass(frozen=True)
class _Command:
    """A command: its help, the function that runs it and the one that adds its options."""

    help: str
    run: Callable
    options: Callable


COMMANDS = {
    "build": _Command("build the three FMUs", _build, _build_options),
    "run": _Command("co-simulate a scenario and write results, metrics and figures", _run, _run_options),
    "sweep": _Command("step-size sensitivity study: a grid of co-simulations and a report", _sweep, _sweep_options),
    "export-ssp": _Command("write an SSP 1.0 archive of the closed loop", _export,
                           lambda parser: _export_options(parser, "export-ssp")),
    "export-fmu": _Command("write one co-simulation FMU of the closed loop (fmpy's container FMU)", _export,
                           lambda parser: _export_options(parser, "export-fmu")),
    "crosscheck": _Command("write the FMI cross-check artefacts of the three FMUs (a closed-loop run of the paper "
                           "scenario)", _crosscheck, _crosscheck_options),
    "compare-laws": _Command("compare the adaptation laws (sigma, e, projection, none) on scenarios: tracking, the "
                             "estimates' norms, the voltages and the driver's limit", _laws, _laws_options),
    "scenarios": _Command("list the scenarios shipped with dsc-fmu", _scenarios, lambda parser: None),
}


def _parser(command: str | None) -> argparse.ArgumentParser:
    """The parser, with the options of ``command`` only (the others' help would import their owners)."""
    parser = argparse.ArgumentParser(
        prog="dsc-fmu", description="The adaptive DSC of a mobile robot as FMI co-simulation FMUs: build them, "
        "co-simulate a scenario, study the communication step, export the closed loop.")
    commands = parser.add_subparsers(dest="command", required=True)
    for name, spec in COMMANDS.items():
        subparser = commands.add_parser(name, help=spec.help, description=spec.help)
        if name == command:
            spec.options(subparser)
    return parser


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
    argv = sys.argv[1:] if argv is None else argv
    args = _parser(argv[0] if argv else None).parse_args(argv)
    shown = warnings.showwarning
    warnings.showwarning = _warning
    try:
        status = COMMANDS[args.command].run(args)
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
