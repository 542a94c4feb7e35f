"""The main job: build the FMUs if needed, co-simulate a scenario, write results, metrics and figures."""

from __future__ import annotations

from pathlib import Path

from ..build.fmus import DEFAULT_FMU_DIR, ensure_fmus
from ..scenario import Scenario
from .master import cosimulate
from .metrics import tracking_metrics
from .results import format_summary, write_results

__all__ = ["run_scenario"]


def run_scenario(scenario: Scenario, out_dir: Path | str, fmu_dir: Path | str = DEFAULT_FMU_DIR,
                 plots: bool = True) -> str:
    """Co-simulate ``scenario`` through the FMUs and write ``results.csv``, ``summary.json`` and,
    with ``plots``, ``trajectory.png`` (Fig. 1) and ``signals.png`` (Fig. 2) into ``out_dir``; an
    error-controlled run (``scenario.simulation.tolerance``) adds ``step_sizes.csv`` and ``step_sizes.png``.

    Returns the printed summary. Nothing is written when the run fails.
    """
    run = cosimulate(scenario, ensure_fmus(fmu_dir))
    metrics = tracking_metrics(run.result, scenario.simulation.stop_time)
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
