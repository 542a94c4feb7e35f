"""The main job: build the FMUs if needed, co-simulate a scenario, write results, metrics and figures."""

from __future__ import annotations

from pathlib import Path

from ..fmubuild.fmus import DEFAULT_FMU_DIR, ensure_fmus
from ..scenario import INTERFACES, Scenario, ScenarioError
from .master import cosimulate
from .metrics import tracking_metrics
from .model_exchange import simulate_model_exchange
from .progress import Watch
from .results import format_summary, write_results

__all__ = ["run_scenario"]

_SIMULATE = dict(zip(INTERFACES, (cosimulate, simulate_model_exchange)))


def run_scenario(scenario: Scenario, out_dir: Path | str, fmu_dir: Path | str = DEFAULT_FMU_DIR,
                 plots: bool = True, interface: str = "co-simulation", watch: Watch | None = None) -> str:
    """Simulate ``scenario`` through the FMUs and write ``results.csv``, ``summary.json`` and,
    with ``plots``, ``trajectory.png`` (Fig. 1) and ``signals.png`` (Fig. 2) into ``out_dir``; an
    error-controlled co-simulation (``scenario.simulation.tolerance``) adds ``step_sizes.csv`` and
    ``step_sizes.png``. ``interface`` is one of ``INTERFACES``; ``watch`` (``progress.Watch``) sees
    the run go and may stop it: what was simulated until then is written, its metrics over that part.

    Returns the printed summary. Nothing is written when the run fails.
    """
    if interface not in INTERFACES:
        raise ScenarioError(f"interface {interface!r} is not allowed; allowed: {', '.join(INTERFACES)}")
    run = _SIMULATE[interface](scenario, ensure_fmus(fmu_dir), watch=watch)
    metrics = tracking_metrics(run.result, run.stopped_at or scenario.simulation.stop_time)
    out_dir = Path(out_dir)
    paths = write_results(out_dir, run, scenario, metrics)
    if plots:
        from .plots import plot_signals, plot_step_sizes, plot_trajectory  # matplotlib: only when figures are drawn

        paths["trajectory"] = plot_trajectory(run.result, out_dir / "trajectory.png")
        paths["signals"] = plot_signals(run.result, out_dir / "signals.png")
        if run.step_sizes is not None:
            paths["step_size_figure"] = plot_step_sizes(run.step_sizes, scenario.simulation.tolerance,
                                                        out_dir / "step_sizes.png")
    return f"{format_summary(run, metrics)}\n  written: {', '.join(str(p) for p in paths.values())}"
