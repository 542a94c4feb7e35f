"""Writing a run to disk (results.csv, summary.json) and summarising it in a few lines of text."""

from __future__ import annotations

import json
from pathlib import Path

from fmpy.util import write_csv

from . import signals
from .master import CosimulationResult
from .model_exchange import ModelExchangeResult
from ..scenario import Interface, Scenario

__all__: list[str] = []  # the package's own: write_results, summary, format_summary


def summary(run: CosimulationResult | ModelExchangeResult, scenario: Scenario, metrics: dict) -> dict:
    """What ``summary.json`` holds: the scenario's name and source, the settings (the interface first, the run's
    cost, ``stopped_at`` in s or None), the metrics, the CSV columns' units and the FMUs' build ids."""
    return {
        "scenario": scenario.name,
        "scenario_source": scenario.source,
        "settings": {
            **{key: value for key, value in run.settings.items() if key != "scenario"},
            **_counts(run),
            "wall_time_s": run.wall_time,
            "stopped_at": run.stopped_at,
        },
        "metrics": metrics,
        "units": dict(signals.UNITS),
        "fmus": {name: fmu["build_id"] for name, fmu in run.fmus.items()},
    }


def _counts(run: CosimulationResult | ModelExchangeResult) -> dict:
    """The run's cost: steps for co-simulation, derivative evaluations for model exchange."""
    if isinstance(run, ModelExchangeResult):
        return {"evaluations": run.evaluations}
    return {"steps": run.steps, "steps_rejected": run.rejected, "fmu_steps": run.fmu_steps}


def write_results(out_dir: Path | str, run: CosimulationResult | ModelExchangeResult, scenario: Scenario,
                  metrics: dict) -> dict[str, Path]:
    """Write ``results.csv`` (fmpy's CSV layout, SI units as in ``signals.UNITS``), ``summary.json`` and, if
    error-controlled, ``step_sizes.csv`` (each accepted step's start and size in s, estimated error in m) into
    ``out_dir``; the paths written by kind (``csv``, ``summary``, ``step_sizes``)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"csv": out_dir / "results.csv", "summary": out_dir / "summary.json"}
    write_csv(paths["csv"], run.result)
    if getattr(run, "step_sizes", None) is not None:
        paths["step_sizes"] = out_dir / "step_sizes.csv"
        write_csv(paths["step_sizes"], run.step_sizes)
    paths["summary"].write_text(json.dumps(summary(run, scenario, metrics), indent=2) + "\n")
    return paths


def _number(value, unit: str) -> str:
    return "never" if value is None else f"{value:.4g} {unit}"


def _cosimulation(run: CosimulationResult, guarded: int) -> tuple[list[str], str]:
    """The lines on how a co-simulation ran, and what its beta guard did in ``guarded`` steps."""
    s = run.settings
    controlled = "" if s["tolerance"] is None else (
        f" (error-controlled to {s['tolerance']:g} m, coupling of order {s['coupling_order']}: {run.rejected} "
        f"steps taken again, step {s['step_min']:.3g} s to {s['step_max']:.3g} s within [{s['h_min']:g}, "
        f"{s['h_max']:g}] s)")
    how = [f"scenario {s['scenario']}: {s['order']}, {s['coupling']} coupling"
           f"{' (input derivatives)' if s['input_derivatives'] else ''}, step {s['step_size']:g} s, "
           f"stop {s['stop_time']:g} s, output every {s['output_interval']:g} s",
           f"  {run.steps} steps in {run.wall_time:.2f} s wall time{controlled}"]
    return how, f"acted in {guarded} steps"


def _model_exchange(run: ModelExchangeResult, guarded: int) -> tuple[list[str], str]:
    """The lines on how a model-exchange run went, and what its beta guard did (``guarded`` times)."""
    s = run.settings
    how = [f"scenario {s['scenario']}: model exchange, {s['method']} at relative tolerance {s['tolerance']:g}, "
           f"stop {s['stop_time']:g} s, output every {s['output_interval']:g} s",
           f"  {run.evaluations} derivative evaluations{_jacobians(s)} and {s['events']} events in {run.wall_time:.2f} s "
           "wall time"]
    return how, f"engaged {guarded} times"


def _jacobians(settings: dict) -> str:
    """", N Jacobians from the FMUs' directional derivatives" where an implicit method asked for some."""
    count = settings.get("jacobian_evaluations", 0)
    return f", {count} Jacobians from the FMUs' directional derivatives" if count else ""


_HOW = {Interface.CO_SIMULATION: _cosimulation, Interface.MODEL_EXCHANGE: _model_exchange}


def format_summary(run: CosimulationResult | ModelExchangeResult, metrics: dict) -> str:
    """A few lines (no trailing newline) of the run's settings, cost and metrics, for the command line."""
    s = run.settings
    how, guard = _HOW[s["interface"]](run, metrics["beta_guard_count"])
    if run.stopped_at is not None:
        how.insert(0, f"stopped at t = {run.stopped_at:g} s of {s['stop_time']:g} s (interrupted): the results up to "
                      "then are written, the metrics are over that part")
    return "\n".join([
        *how,
        f"  position error over [{metrics['window_start_s']:g}, {metrics['window_end_s']:g}] s: "
        f"final {_number(metrics['final_position_error_m'], 'm')}, "
        f"RMS {_number(metrics['rms_position_error_m'], 'm')}, max {_number(metrics['max_position_error_m'], 'm')}",
        f"  max |thetae| over the same window: {_number(metrics['max_abs_thetae_rad'], 'rad')}",
        f"  position error below 0.1 m from: {_number(metrics['settling_time_0p1_s'], 's')}",
        f"  max |u|: {_number(metrics['max_abs_u_V'], 'V')}; beta guard {guard}",
    ])
