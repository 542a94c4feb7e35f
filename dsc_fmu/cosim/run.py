"""The main job: build the FMUs if needed, co-simulate a scenario, write results, metrics and figures."""

from __future__ import annotations

from pathlib import Path

from ..fmubuild.fmus import ensure_fmus
from ..scenario import Interface, Scenario, one_of
from .master import cosimulate
from .metrics import tracking_metrics
from .model_exchange import simulate_model_exchange
from .progress import Watch
from .results import format_summary, write_results

__all__ = ["run_scenario"]

_SIMULATE = {Interface.CO_SIMULATION: cosimulate, Interface.MODEL_EXCHANGE: simulate_model_exchange}


def run_scenario(scenario: Scenario, out_dir: Path | str, fmu_dir: Path | str | None = None, plots: bool = True,
                 interface: Interface | str = Interface.CO_SIMULATION, watch: Watch | None = None,
                 fmi_version: int | None = None) -> str:
    """Simulate a scenario through the FMUs and write its results, metrics and figures.

    Writes ``results.csv`` and ``summary.json`` and, with ``plots``, ``trajectory.png`` (Fig. 1) and
    ``signals.png`` (Fig. 2); an error-controlled co-simulation adds ``step_sizes.csv`` and ``step_sizes.png``.
    Nothing is written when the run fails.

    Parameters
    ----------
    scenario : Scenario
        The scenario, its settings checked.
    out_dir : pathlib.Path or str
        The folder to write into, created if missing.
    fmu_dir : pathlib.Path or str or None, optional
        Where the FMUs are, built there first if missing or out of date (``ensure_fmus``). Default None:
        ``default_fmu_dir`` of the FMI version.
    plots : bool, optional
        Draw the figures. Default True.
    interface : {"co-simulation", "model-exchange"} or Interface, optional
        Stepped by the master (``cosimulate``) or integrated as one ODE (``simulate_model_exchange``).
        Default "co-simulation".
    watch : progress.Watch, optional
        Sees the run go and may stop it: what was simulated until then is written, its metrics over that part.
    fmi_version : {2, 3} or None, optional
        The FMI version of the FMUs. Default None: that of the FMUs in ``fmu_dir``, else 2.

    Returns
    -------
    str
        The summary the command line prints and the files written.

    Raises
    ------
    ScenarioError
        If ``interface`` is not one of ``Interface``'s, or the scenario asks what the FMUs lack.
    FmiVersionError
        If ``fmu_dir`` holds FMUs of another FMI version than ``fmi_version``.
    CosimulationError
        If the run diverges or an FMU fails.
    """
    run = _SIMULATE[one_of(Interface, interface, "interface")](scenario, ensure_fmus(fmu_dir, fmi_version),
                                                              watch=watch)
    metrics = tracking_metrics(run.result, run.stopped_at or scenario.simulation.stop_time)
    out_dir = Path(out_dir)
    paths = write_results(out_dir, run, scenario, metrics)
    if plots:
        from .plots import plot_signals, plot_step_sizes, plot_trajectory  # matplotlib: only when figures are drawn

        paths["trajectory"] = plot_trajectory(run.result, out_dir / "trajectory.png")
        paths["signals"] = plot_signals(run.result, out_dir / "signals.png")
        if getattr(run, "step_sizes", None) is not None:
            paths["step_size_figure"] = plot_step_sizes(run.step_sizes, scenario.simulation.tolerance,
                                                        out_dir / "step_sizes.png")
    return f"{format_summary(run, metrics)}\n  written: {', '.join(str(p) for p in paths.values())}"
