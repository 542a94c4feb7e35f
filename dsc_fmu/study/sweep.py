"""The step-size study behind ``dsc-fmu sweep``: run the grid, refine the boundaries, predict, report."""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import numpy as np

from ..fmubuild.fmus import ensure_fmus, resolve_fmu_dir
from .report import write_report
from ..scenario import Scenario, Stability
from .analysis import fit_orders, grid_brackets, group_label, refine_boundary, summarise, write_summary_json
from .cases import Grid, Runner, SweepError, apply
from .cache import load_trajectory

__all__ = ["run_sweep", "TRANSIENT_NOTE", "RECOVERY_NOTE", "CONTROLLED_KEYS"]

# What sweep.json keeps of each error-controlled run.
CONTROLLED_KEYS = ("order", "discretization", "coupling", "tolerance", "max_position_deviation_m", "steps",
                   "steps_rejected", "fmu_steps", "wall_time_s", "diverged", "diverged_reason")

TRANSIENT_NOTE = (
    "The prediction linearises the loop about steady tracking of the constant-velocity reference, with the "
    "parameter estimates frozen where the continuous run has them at its stop time. A run that starts far "
    "from steady tracking (as the paper's robot does, 1.1 m off with a 90 degree heading error) first passes "
    "through a start-up transient in which the estimates overshoot (the estimate of Ra rises above Ra + k5 "
    "around t = 2 s, a negative resistance in the current loop): the sampled loop can diverge there at steps "
    "that steady tracking tolerates, so the measured boundary is lower than the predicted one."
)
RECOVERY_NOTE = (
    "Where the measured boundary lies above the prediction: at a step beyond the predicted boundary the sampled "
    "loop about steady tracking is unstable and an oscillation grows, but it moves the parameter estimates and "
    "the adaptation damps it, so the run settles and counts as stable under the \"settled\" definition. "
    "[simulation] stability = \"local\" (dsc-fmu sweep --stability local) judges the stability of steady "
    "tracking itself, the one the prediction predicts, for a scenario that starts in steady tracking."
)


def boundary_notes(predictions: dict, boundaries: dict, stability: str) -> list[str]:
    """Why refined boundaries lie more than 20 % from their predictions: ``TRANSIENT_NOTE`` if one lies below
    (the start-up transient), ``RECOVERY_NOTE`` if one lies above under the "settled" definition."""
    ratios = [predicted / boundaries[label].h_stable for label, predicted in predictions.items()
              if label in boundaries and math.isfinite(predicted) and predicted > 0]
    return ([TRANSIENT_NOTE] if any(ratio > 1.2 for ratio in ratios) else []) + (
        [RECOVERY_NOTE] if not Stability(stability).from_start and any(ratio < 0.8 for ratio in ratios) else [])


def write_rows_csv(path: Path, rows: list[dict]) -> Path:
    """Write ``sweep.csv``: one line per run, the keys of the rows as columns in their order; cells empty
    where a row has no value, ``nan`` where a value does not apply."""
    names = list(dict.fromkeys(name for row in rows for name in row))
    with open(path, "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=names, restval="")
        writer.writeheader()
        for row in rows:
            writer.writerow({name: "" if value is None else value for name, value in row.items()})
    return path


def _predictions(scenario: Scenario, rows: list[dict], steps: np.ndarray):
    """Predicted boundaries and spectral-radius curves of the nominal series, or a note why there are none."""
    if scenario.reference["profile"] != 0:
        return {}, {}, ["No linearised prediction: it needs a constant-velocity reference (profile constant)."]
    from .stability import (  # python-control: slow to import, needed only here
        OperatingPointError, linearise, predicted_boundary, spectral_radius_curve,
    )

    nominal = {group_label(row): (row["order"], row["discretization"], row.get("coupling", "hold")) for row in rows
               if row.get("sample") is None and not any("." in name for name in row)}
    try:
        loop = linearise(scenario)
    except OperatingPointError as error:
        return {}, {}, [f"No linearised prediction: {error}"]
    predictions, curves = {}, {}
    for label, (order, discretization, coupling) in nominal.items():
        predictions[label] = predicted_boundary(loop, order, discretization, coupling=coupling)
        curves[label] = (steps, spectral_radius_curve(loop, steps, order, discretization, coupling))
    return predictions, curves, []


def _path_figure(out_dir: Path, rows: list[dict]) -> Path | None:
    """Paths of a few steps of the first nominal series: smallest, a middle one, largest stable, first unstable."""
    from .figures import plot_paths

    series = sorted((r for r in rows if r.get("sample") is None and not any("." in n for n in r)),
                    key=lambda r: (r["order"], r["discretization"], r["step_size"]))
    if not series:
        return None
    first = [r for r in series if (r["order"], r["discretization"]) == (series[0]["order"], series[0]["discretization"])]
    stable = [r for r in first if r["stable"]]
    chosen = [first[0], first[len(first) // 2]] + stable[-1:] + [r for r in first if not r["stable"]][:1]
    trajectories = {f"{group_label(r)}, h = {r['step_size']:g} s": load_trajectory(out_dir, r)
                    for r in {id(r): r for r in chosen}.values()}
    return plot_paths(trajectories, load_trajectory(out_dir, first[0]), out_dir / "paths.png")


def run_sweep(scenario: Scenario, out_dir: Path | str, grid: Grid = Grid(), runner: Runner = Runner(), *,
              fmu_dir: Path | str | None = None, fmi_version: int | None = None, refine: bool = True) -> str:
    """Run a step-size study of a scenario and write its results, figures and report.

    Every case of ``grid`` runs (``execute.Workers``); each fixed-step series' stability boundary is refined
    by bisection between its last stable and first unstable grid step to 2 % (with ``refine``); the
    linearised prediction (of each series' coupling) is added for the nominal series of a
    constant-velocity scenario. Every run, fixed-step and error-controlled, is a point of the
    work-precision figure. "Stable" is judged by ``scenario.simulation.stability``
    (``rows.stability_definition``). Cache entries that did not verify, and worker processes lost,
    are reported in one warning line each for the whole sweep (``Execution.warn``).

    Parameters
    ----------
    scenario : Scenario
        The scenario to study.
    out_dir : pathlib.Path or str
        The sweep folder: ``sweep.csv``, ``sweep.json``, the figures, ``report.md`` and the cache.
    grid : Grid, optional
        What the study varies. Default ``Grid()``: 12 steps from 1e-4 to 5e-2 s, both orders, both
        couplings and error-controlled runs at ``DEFAULT_TOLERANCES``.
    runner : Runner, optional
        Where the runs go. Default ``Runner()``: all cores, a progress line on a terminal.
    fmu_dir : pathlib.Path or str or None, optional
        Where the FMUs are built (``ensure_fmus``). Default None: ``default_fmu_dir`` of the FMI version.
    fmi_version : {2, 3} or None, optional
        The FMI version of the FMUs. Default None: that of the FMUs in ``fmu_dir``, else 2.
    refine : bool, optional
        Bisect the stability boundaries. Default True.

    Returns
    -------
    str
        A short text summary, with how many runs came from the cache.

    Raises
    ------
    ScenarioError
        One line, if the grid does not fit the scenario; before anything runs.
    FmiVersionError
        One line, if ``fmu_dir`` holds FMUs of another FMI version than ``fmi_version``; before anything runs.
    SweepError
        One line, if the scheduler cannot be reached or ``out_dir`` cannot be a folder (before anything
        runs), or if runs did not finish (their worker process lost twice): then everything is
        written, their rows carry the reason and are not cached, and the next sweep runs them again.
    """
    out_dir = Path(out_dir)
    cases = grid.cases(scenario)
    fmu_dir, fmi_version = resolve_fmu_dir(fmu_dir, fmi_version)
    from .execute import Workers, prepare_sweep
    from .rows import stability_definition

    prepare_sweep(out_dir, runner)  # before the FMUs are built
    fmu_paths = ensure_fmus(fmu_dir, fmi_version)
    with Workers(out_dir, fmu_paths, runner) as workers:
        on_grid = workers.execute(scenario, cases)
        all_rows = on_grid.rows
        write_rows_csv(out_dir / "sweep.csv", all_rows)
        rows = _fixed_step(all_rows)
        boundaries, refining = _refined_boundaries(scenario, cases, all_rows, workers) if refine else ({}, [])
    done = sum(refining, on_grid)
    done.warn()

    steps = np.geomspace(1e-4, 0.2, 300)
    predictions, curves, notes = _predictions(apply(scenario, cases[0]) if cases else scenario, rows, steps)
    settings = _settings(scenario, grid, cases)
    notes += boundary_notes(predictions, boundaries, scenario.simulation.stability)
    summary = summarise(rows, stability_definition=stability_definition(scenario.simulation.stability),
                        settings=settings, boundaries=boundaries, fits=fit_orders(rows), predictions=predictions,
                        notes=notes)
    summary["error_controlled"] = [{key: row.get(key) for key in CONTROLLED_KEYS} | {"series": group_label(row)}
                                   for row in all_rows if row.get("tolerance") is not None]
    write_summary_json(out_dir, summary)

    finished = [row for row in all_rows if row["key"] not in done.lost]  # the runs that did not finish have no data
    figures = _figures(out_dir, finished, curves, boundaries, predictions)
    report = write_report(out_dir, summary, all_rows, figures)
    if done.lost:
        raise SweepError(f"{len(done.lost)} of {len(done.rows)} runs did not finish (their worker process was lost, "
                         f"killed or crashed): their rows carry the reason and are not cached; everything else is "
                         f"written to {out_dir}; run the sweep again to retry them")
    return "\n".join([
        f"sweep of {scenario.name}: {len(all_rows)} runs, {sum(not r['stable'] for r in all_rows)} not stable",
        f"  runs: {_counts(on_grid, refining, done)}",
        *_summary_lines(summary),
        f"  written: {out_dir / 'sweep.csv'}, {out_dir / 'sweep.json'}, {report}",
    ])


def _refined_boundaries(scenario: Scenario, cases: list, all_rows: list[dict], workers) -> tuple[dict, list]:
    """The stability boundary of each fixed-step series, bisected one run at a time between its last stable
    and first unstable grid step (``analysis.refine_boundary``) on the sweep's ``workers``, and the
    ``Execution`` of each bisection."""
    template = {group_label(row): case for row, case in zip(all_rows, cases) if case.tolerance is None}
    boundaries, executions = {}, []
    for label, bracket in grid_brackets(_fixed_step(all_rows)).items():
        if bracket is not None:
            def is_stable(h, case=template[label]):
                executions.append(workers.execute(scenario, [dataclasses.replace(case, step_size=h)], progress=False))
                return executions[-1].rows[0]["stable"]
            boundaries[label] = refine_boundary(is_stable, *bracket)
    return boundaries, executions


def _figures(out_dir: Path, finished: list[dict], curves: dict, boundaries: dict, predictions: dict) -> dict:
    """The sweep's figures, by name: of the ``finished`` runs (the work-precision figure of all of them, the
    others of the fixed-step series) and, with prediction ``curves``, the spectral radius."""
    from .figures import (  # matplotlib: slow to import
        plot_deviation, plot_spectral_radius, plot_tracking_and_cost, plot_work_precision,
    )

    fixed = _fixed_step(finished)
    figures = {} if not fixed else {
        "deviation": plot_deviation(fixed, fit_orders(fixed), out_dir / "deviation.png"),
        "tracking_and_cost": plot_tracking_and_cost(fixed, out_dir / "tracking_and_cost.png"),
        "work_precision": plot_work_precision(finished, out_dir / "work_precision.png"),
    }
    paths = _path_figure(out_dir, fixed)
    if paths is not None:
        figures["paths"] = paths
    if curves:
        measured = {label: b.h_stable for label, b in boundaries.items()}
        figures["spectral_radius"] = plot_spectral_radius(curves, measured, out_dir / "spectral_radius.png",
                                                          predicted=predictions)
    return figures


def _fixed_step(rows: list[dict]) -> list[dict]:
    """The rows of the fixed-step series (no tolerance)."""
    return [row for row in rows if row.get("tolerance") is None]


def _settings(scenario: Scenario, grid: Grid, cases: list) -> dict:
    """What the sweep varied and how its runs were simulated, for ``sweep.json``."""
    return {"scenario": scenario.name, "scenario_source": scenario.source, "cases": len(cases),
            "step_sizes": sorted({c.step_size for c in cases}), "orders": sorted({c.order for c in cases}),
            "discretizations": sorted({c.discretization for c in cases}),
            "couplings": sorted({c.coupling for c in cases if c.tolerance is None}),
            "tolerances": sorted({c.tolerance for c in cases if c.tolerance is not None}),
            "sets": [list(s) for s in grid.sets], "perturbations": [str(p) for p in grid.perturbations],
            "samples": grid.samples, "seed": grid.seed,
            "stop_time": scenario.simulation.stop_time, "output_interval": scenario.simulation.output_interval,
            "stability": scenario.simulation.stability, "reference": scenario.simulation.reference}


def _summary_lines(summary: dict) -> list[str]:
    """One line per fixed-step series (observed order, boundary, prediction) and per error-controlled run."""
    lines = []
    for label, group in summary["groups"].items():
        fit = group["observed_order"].get("max_position_deviation_m", {})
        order = f"{fit['slope']:.2f}" if "slope" in fit else "n/a"
        lines.append(f"  {label}: observed order {order}; {group['stability_boundary']['message']}; "
                     f"{group['prediction']['statement']}")
    for entry in summary["error_controlled"]:
        outcome = (f"failed: {entry['diverged_reason']}" if entry["diverged"] else
                   f"max deviation {entry['max_position_deviation_m']:.3g} m, {entry['steps']} steps "
                   f"({entry['steps_rejected']} taken again), {entry['wall_time_s']:.2f} s")
        lines.append(f"  {entry['series']}, tolerance {entry['tolerance']:g} m: {outcome}")
    return lines


def _counts(on_grid, refining: list, done) -> str:
    """``24 (24 from the cache, 0 run now)``, or ``24 + 6 refining the boundaries (...)``."""
    refined = f" + {len(refining)} refining the boundaries" if refining else ""
    return f"{len(on_grid.rows)}{refined} ({done.cached} from the cache, {done.ran} run now)"
