"""The report of a step-size sweep: report.md with settings, observed orders, boundaries, figures, runs."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from .analysis import group_label, group_rows, overrides

__all__ = ["FIGURE_CAPTIONS", "write_report"]

FIGURE_CAPTIONS = {
    "deviation": "Deviation from the continuous reference solution against the communication step, "
                 "with the fitted slopes (dashed) and diverged runs (x at the top edge).",
    "tracking_and_cost": "Tracking error over the last third of the run, and wall time, "
                         "against the communication step.",
    "paths": "Paths in the plane for a few communication steps, over the reference solution's path.",
    "spectral_radius": "Predicted spectral radius of the linearised co-simulation step, with the measured boundaries.",
    "work_precision": "Work-precision: the largest position deviation from the reference solution against wall "
                      "time and against doStep calls, for every fixed-step series (its step sizes) and every "
                      "error-controlled series (its tolerances, annotated).",
}

EXPLANATION = (
    "A zero-order hold keeps each exchanged signal, the voltages u in particular, constant over a "
    "communication step h. Between two communication points the held input differs from the one a "
    "continuous loop would apply by at most h max|du/dt|, a local error O(h) that the plant integrates "
    "into a deviation O(h) over the run. The deviation is therefore expected to fall linearly with h "
    "(slope 1 in the log-log figure) for both coupling orders (Jacobi holds every input for a step, "
    "Gauss-Seidel some of them) and both discretizations of the controller (Euler is first order itself; "
    "RK4 is fourth order, so the hold dominates). The linear coupling (the plant extrapolates u, the "
    "controller interpolates or extrapolates its inputs, on lines through the last communication points) "
    "leaves an input error O(h^2) instead: its series are expected at slope 2. The order is fitted by least "
    "squares in log-log over the smallest steps that lie on a straight line; larger steps, past the knee "
    "where higher-order terms or instability take over, are left out (`dsc_fmu.study.analysis.fit_order`)."
)


def _number(value, digits: int = 3) -> str:
    """A number to ``digits`` significant digits; None and NaN as a dash."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return f"{value:.{digits}g}"


def _setting(value) -> str:
    if isinstance(value, (list, tuple)):
        return ", ".join(_setting(item) for item in value)
    if isinstance(value, float):
        return _number(value)
    return "–" if value is None else str(value)


def _table(header: Sequence[str], lines: Sequence[Sequence[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header),
            *("| " + " | ".join(line) + " |" for line in lines), ""]


def _stable(row: Mapping) -> str:
    if row["diverged"]:
        signal = f" ({row['diverged_signal']})" if row.get("diverged_signal") else ""
        return f"diverged at t = {_number(row.get('diverged_time'))} s{signal}"
    return "yes" if row["stable"] else "no"


def _variant(row: Mapping) -> str:
    parts = [f"{name} = {_number(value) if isinstance(value, (int, float)) else value}"
             for name, value in sorted(overrides(row).items())]
    if row.get("sample") is not None:
        parts.append(f"sample {row['sample']}")
    return ", ".join(parts) or "nominal"


def _runs(rows: Sequence[Mapping]) -> list[str]:
    header = ["h (s)", "order", "discretization", "coupling", "tolerance (m)", "overrides / sample", "stable",
              "max position deviation (m)", "RMS position deviation (m)", "max heading deviation (rad)",
              "max u deviation (V)", "max tracking error, last third (m)", "wall time (s)"]
    lines = []
    for group in group_rows(rows).values():
        for row in group:
            lines.append([_number(row["step_size"]), row["order"], str(row.get("discretization", "")),
                          str(row.get("coupling", "hold")), _number(row.get("tolerance")), _variant(row),
                          _stable(row), *(_number(row.get(key)) for key in (
                              "max_position_deviation_m", "rms_position_deviation_m", "max_heading_deviation_rad",
                              "max_u_deviation_V", "max_position_error_m", "wall_time_s"))])
    return _table(header, lines)


def _slope(fit: Mapping | None) -> str:
    return "–" if not fit or "error" in fit else _number(fit["slope"])


def _orders(groups: Mapping[str, Mapping], expected: Mapping[str, int]) -> list[str]:
    header = ["series", "observed order (position)", "range of h (s)", "points", "max log10 residual",
              "order (heading)", "order (voltage)"]
    lines, remarks = [], []
    for label, group in groups.items():
        fits = group["observed_order"]
        fit = fits.get("max_position_deviation_m")
        if fit and "error" not in fit:
            lines.append([label, _number(fit["slope"]), f"{_number(fit['h_min'])} to {_number(fit['h_max'])}",
                          str(fit["points"]), _number(fit["max_residual"], 2)])
            order = expected.get(label, 1)
            name = {1: "first order", 2: "second order"}[order]
            verdict = f"{name}, as expected" if abs(fit["slope"] - order) <= 0.15 * order else f"NOT {name}"
            remarks.append(f"- {label}: the maximum position deviation falls as h^{fit['slope']:.2f} for h from "
                           f"{fit['h_min']:.3g} s to {fit['h_max']:.3g} s ({fit['points']} steps): {verdict}.")
        else:
            lines.append([label, "–", "–", "–", "–"])
            remarks.append(f"- {label}: no order fitted: {fit['error'] if fit else 'no fit given'}.")
        lines[-1] += [_slope(fits.get("max_heading_deviation_rad")), _slope(fits.get("max_u_deviation_V"))]
    return [EXPLANATION, "", *_table(header, lines), *remarks, ""]


def _boundaries(summary: Mapping, notes: Sequence[str]) -> list[str]:
    tolerance = summary.get("agreement_tolerance", 0.2)
    header = ["series", "grid bracket (s)", "refined bracket (s)", "measured h* (s)", "refinement runs",
              "predicted h* (s)", "predicted / measured"]
    lines, statements, disagreements = [], [], []
    for label, group in summary["groups"].items():
        stability, prediction = group["stability_boundary"], group["prediction"]
        grid, refined = stability["grid_bracket_s"], stability["refined"]
        lines.append([label, f"{_number(grid[0])} to {_number(grid[1])}" if grid else stability["status"],
                      f"{_number(refined['h_stable_s'])} to {_number(refined['h_unstable_s'])}" if refined else "–",
                      _number(stability["estimate_s"]), str(len(refined["evaluated"])) if refined else "–",
                      _number(prediction["predicted_boundary_s"]), _number(prediction["ratio_predicted_to_measured"])])
        statements.append(f"- {label}: {stability['message']}; {prediction['statement']}.")
        if prediction["agrees"] is False:
            disagreements.append(label)
    text = [f"{summary['stability_definition'].rstrip('.')}. The measured boundary h* is the "
            "largest step known stable below the first unstable one (stability need not be monotone in h); "
            "the bracket from the grid is refined by bisection at geometric midpoints. The predicted boundary "
            "is where the spectral radius of the linearised co-simulation step reaches 1.", "",
            *_table(header, lines), *statements, ""]
    if disagreements:
        text.append(f"**The predicted and the measured boundary differ by more than {tolerance:.0%}** for "
                    f"{', '.join(disagreements)}.")
        text.append("")
        text += ["Reasons given:", "", *(f"- {note}" for note in notes), ""] if notes else \
            ["No reason was given for the difference.", ""]
    elif any(group["prediction"]["agrees"] for group in summary["groups"].values()):
        text += [f"Every prediction agrees with its measurement within {tolerance:.0%}.", ""]
        text += ["Notes:", "", *(f"- {note}" for note in notes), ""] if notes else []
    else:
        text += ["No prediction was given.", ""]
        text += ["Notes:", "", *(f"- {note}" for note in notes), ""] if notes else []
    return text


def _controlled(entries: Sequence[Mapping]) -> list[str]:
    """The error-controlled runs: what each tolerance gave and cost (the work-precision figure shows
    them beside the fixed-step series)."""
    if not entries:
        return ["No error-controlled runs (`--tolerances`).", ""]
    header = ["series", "tolerance (m)", "max position deviation (m)", "deviation / tolerance", "steps",
              "taken again", "doStep calls", "wall time (s)"]
    lines = [[entry["series"], _number(entry["tolerance"]), _number(entry["max_position_deviation_m"]),
              _number((entry["max_position_deviation_m"] or math.nan) / entry["tolerance"], 2),
              _number(entry["steps"], 6), _number(entry["steps_rejected"], 6), _number(entry["fmu_steps"], 7),
              _number(entry["wall_time_s"])] for entry in entries]
    failed = [f"- {entry['series']}, tolerance {entry['tolerance']:g} m, failed: {entry['diverged_reason']}"
              for entry in entries if entry["diverged"]]
    return ["Each error-controlled run starts from the scenario's step, estimates the position error each step "
            "adds from the defect of the exchanged voltages and takes a step again, smaller, from the FMUs' "
            "saved states where the estimate exceeds the tolerance (`dsc_fmu.cosim.step_control`).", "",
            *_table(header, lines), *failed, *([""] if failed else [])]


def _figures(out_dir: Path, figures: Mapping[str, Path | str]) -> list[str]:
    text = []
    for name, path in figures.items():
        caption = FIGURE_CAPTIONS.get(name, name.replace("_", " "))
        path = Path(path) if Path(path).is_absolute() else out_dir / path
        if path.is_file() and path.stat().st_size > 0:
            link = Path(os.path.relpath(path, out_dir)).as_posix()
            text += [f"![{caption}]({link})", "", f"*{caption}*", ""]
        else:
            text += [f"*{caption}* (figure `{path.name}` was not written)", ""]
    return text or ["No figures were written.", ""]


def format_report(out_dir: Path | str, summary: Mapping, rows: Sequence[Mapping],
                  figures: Mapping[str, Path | str]) -> str:
    """The Markdown text of a sweep's report."""
    counts = summary["counts"]
    settings = [f"- {name}: {_setting(value)}" for name, value in summary.get("settings", {}).items()]
    return "\n".join([
        f"# Step-size sweep of the scenario `{summary['scenario']}`", "",
        "The three FMUs (reference robot, mobile robot, DSC controller) co-simulated for a grid of "
        "communication steps h, coupling orders, couplings (zero-order hold, linear) and discretizations of "
        "the controller, and with an error-controlled step at several tolerances; each run compared with the "
        "continuous reference solution.", "",
        "## Settings", "", *settings,
        f"- stable: {summary['stability_definition']}",
        f"- runs: {counts['runs']} at a fixed step, of which {counts['diverged']} diverged and {counts['unstable']} "
        f"not stable; {len(summary.get('error_controlled', []))} error-controlled (Accuracy per cost)", "",
        "## Observed convergence order", "", *_orders(summary["groups"], {
            group_label(row): 2 if (row.get("coupling"), row.get("discretization", "rk4")) == ("linear", "rk4") else 1
            for row in rows}),
        "## Stability boundary", "", *_boundaries(summary, summary.get("notes", [])),
        "## Accuracy per cost", "", *_controlled(summary.get("error_controlled", [])),
        "## Figures", "", *_figures(Path(out_dir), figures),
        "## Runs", "",
        "Deviations are the largest differences from the continuous reference solution over the run; the "
        "tracking error is the largest position error over the last third of the run.", "",
        *_runs(rows),
    ])


def write_report(out_dir: Path | str, summary: Mapping, rows: Sequence[Mapping],
                 figures: Mapping[str, Path | str]) -> Path:
    """Write a sweep's report to ``report.md``.

    Parameters
    ----------
    out_dir : pathlib.Path or str
        The directory, created if missing; figures are linked relative to it.
    summary : Mapping
        As from ``study.summarise`` (see ``format_report``).
    rows : sequence of Mapping
        The sweep's rows, one per fixed-step run (keys of ``study.rows.ROW_KEYS``).
    figures : Mapping of str to pathlib.Path or str
        Name -> image path (absolute or relative to ``out_dir``); a name of ``FIGURE_CAPTIONS`` gets
        its caption.

    Returns
    -------
    pathlib.Path
        ``out_dir/report.md``.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "report.md"
    path.write_text(format_report(out_dir, summary, rows, figures) + "\n")
    return path
