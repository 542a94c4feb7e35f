"""The ``dsc-fmu`` command line: a thin shell over ``build_fmus`` and ``run_scenario``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .build import DEFAULT_FMU_DIR, build_fmus
from .master import CosimulationError
from .run import run_scenario
from .scenario import ORDERS, ScenarioError, load_scenario, scenario_names

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="dsc-fmu", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)

    build = commands.add_parser("build", help="build the three FMUs")
    build.add_argument("--out", type=Path, default=DEFAULT_FMU_DIR, help="folder for the FMUs (default: %(default)s)")

    run = commands.add_parser("run", help="co-simulate a scenario and write results, metrics and figures")
    run.add_argument(
        "scenario", nargs="?", default="paper",
        help=f"a scenario name ({', '.join(scenario_names())}) or a path to a TOML file (default: %(default)s)",
    )
    run.add_argument("--step-size", type=float, help="communication step in s (default: the scenario's)")
    run.add_argument("--stop-time", type=float, help="stop time in s (default: the scenario's)")
    run.add_argument("--order", choices=ORDERS, help="coupling order (default: the scenario's)")
    run.add_argument("--output-interval", type=float, help="recording interval in s (default: the scenario's)")
    run.add_argument("--out", type=Path, help="output folder (default: results/<scenario name>)")
    run.add_argument("--fmu-dir", type=Path, default=DEFAULT_FMU_DIR, help="where the FMUs are built (default: %(default)s)")
    run.add_argument("--no-plots", action="store_true", help="write no figures")

    commands.add_parser("scenarios", help="list the scenarios shipped with dsc-fmu")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command line; return the exit status (0 on success, 1 on a user error)."""
    args = _parser().parse_args(argv)
    try:
        if args.command == "build":
            for path in build_fmus(args.out).values():
                print(path)
        elif args.command == "scenarios":
            for name in scenario_names():
                print(f"{name}: {load_scenario(name).description}")
        else:
            scenario = load_scenario(args.scenario).with_simulation(
                step_size=args.step_size, stop_time=args.stop_time, order=args.order,
                output_interval=args.output_interval,
            )
            report = run_scenario(
                scenario, out_dir=args.out or Path("results") / scenario.name, fmu_dir=args.fmu_dir,
                plots=not args.no_plots,
            )
            print(report)
    except (ScenarioError, CosimulationError, OSError) as error:
        print(f"dsc-fmu: error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
