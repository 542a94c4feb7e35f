"""The adaptation laws of Remark 4 compared on scenarios: tracking, the estimates' norms, the voltages and the
driver's limit (docs/scenarios.md, "Adaptation laws compared")."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from ..cosim.master import Cosimulator
from ..cosim.metrics import tracking_metrics
from ..errors import CosimulationError
from ..fmubuild.fmus import ensure_fmus, resolve_fmu_dir
from ..models.parameters import ADAPTATIONS
from ..scenario import Scenario, ScenarioError, one_of

__all__ = ["compare_adaptation_laws", "LAW_KEYS", "DEFAULT_SCENARIOS"]

DEFAULT_SCENARIOS = ("paper", "robustness")  # the paper's, and with the driver's limit and a disturbance

LAW_KEYS = (
    "scenario", "adaptation", "diverged_time_s", "diverged_reason",
    "rms_position_error_m", "final_position_error_m", "max_position_error_m",
    "estimates_norm_end", "estimates_norm_max", "estimates_norm_growth_per_s",
    "a1_hat_end", "a2_hat_end", "W1_hat_norm_end", "W2_hat_norm_end",
    "max_abs_u_V", "max_abs_u_applied_V", "limit_time_s", "limit_count",
)


def estimates_norm(result: np.ndarray) -> np.ndarray:
    """The Euclidean norm of all 16 estimates at each row: ``sqrt(a1_hat^2 + a2_hat^2 + |W1_hat|^2 + |W2_hat|^2)``."""
    return np.sqrt(result["a1_hat"] ** 2 + result["a2_hat"] ** 2 + result["W1_hat_norm"] ** 2
                   + result["W2_hat_norm"] ** 2)


def law_row(scenario: Scenario, law: str, result: np.ndarray, failure: CosimulationError | None = None) -> dict:
    """The row of ``LAW_KEYS`` of one run of ``scenario`` under ``law`` (its ``result`` rows, ``signals.DTYPE``;
    up to the ``failure`` of a run that diverged: then the time and reason, and NaN for the last third).

    Over the last third of the run ``[2T/3, T]``: the position error's RMS, final and largest value (m), and
    the growth of the estimates' norm, ``(|theta_hat|(T) - |theta_hat|(2T/3)) / (T/3)`` (1/s: zero for
    estimates that have settled, positive while they drift). Over the whole run (up to a failure): the
    largest commanded and applied voltages (V), and how long (s) and how many times the driver's limit acted.
    """
    stop = scenario.simulation.stop_time
    norm = estimates_norm(result)
    row = {"scenario": scenario.name, "adaptation": law, "diverged_time_s": math.nan, "diverged_reason": ""}
    if failure is None:
        metrics = tracking_metrics(result, stop)
        start = int(np.searchsorted(result["time"], 2.0 * stop / 3.0 - 1e-9 * stop))
        row.update({key: metrics[key] for key in ("rms_position_error_m", "final_position_error_m",
                                                   "max_position_error_m")},
                   estimates_norm_growth_per_s=float((norm[-1] - norm[start]) / (stop - result["time"][start])))
    else:
        row.update(dict.fromkeys(("rms_position_error_m", "final_position_error_m", "max_position_error_m",
                                  "estimates_norm_growth_per_s"), math.nan),
                   diverged_time_s=float(failure.time), diverged_reason=" ".join(str(failure).split()))
    finite = np.isfinite(norm)
    row.update({
        "estimates_norm_end": float(norm[finite][-1]), "estimates_norm_max": float(norm[finite].max()),
        **{f"{name}_end": float(result[name][-1]) for name in ("a1_hat", "a2_hat", "W1_hat_norm", "W2_hat_norm")},
        "max_abs_u_V": float(np.nanmax(np.abs([result["u1"], result["u2"]]))),
        "max_abs_u_applied_V": float(np.nanmax(np.abs([result["u1_applied"], result["u2_applied"]]))),
        "limit_time_s": float(result["saturation_time"][-1]), "limit_count": int(result["saturation_count"][-1]),
    })
    return {key: row[key] for key in LAW_KEYS}


def _table(rows: list[dict]) -> str:
    """The Markdown table of docs/scenarios.md."""
    lines = ["| scenario | adaptation | RMS position error, last third (m) | estimates' norm at the end | its growth, "
             "last third (1/s) | peak \\|u\\| commanded (V) | peak \\|u\\| applied (V) | limit acted (s) |",
             "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        tracking = f"diverged at {row['diverged_time_s']:.3g} s" if row["diverged_reason"] else \
            f"{row['rms_position_error_m']:.3g}"
        lines.append(f"| `{row['scenario']}` | `{row['adaptation']}` | {tracking} | "
                     f"{row['estimates_norm_end']:.4g} | {row['estimates_norm_growth_per_s']:.3g} | "
                     f"{row['max_abs_u_V']:.3g} | {row['max_abs_u_applied_V']:.3g} | {row['limit_time_s']:.3g} |")
    return "\n".join(lines) + "\n"


def plot_laws(results: dict, path: Path) -> Path:
    """The estimates' norm (top, linear up to 1, then log) and the position error (bottom, log scale) against time,
    one column per scenario and one line per law (a diverged run's ends where it diverged); ``results``:
    ``{scenario name: {law: result}}``."""
    from ..cosim.plots import new_figure  # matplotlib: slow to import

    figure = new_figure(5.0 * len(results), 7.0)
    grid = figure.subplots(2, len(results), squeeze=False, sharex="col")
    for column, (name, by_law) in enumerate(results.items()):
        top, bottom = grid[0][column], grid[1][column]
        for law, result in by_law.items():
            top.plot(result["time"], estimates_norm(result), label=law)
            bottom.semilogy(result["time"], np.maximum(result["position_error"], 1e-12), label=law)
        top.set(title=f"{name}: estimates' norm", ylabel="|theta_hat| (1)", yscale="symlog")
        bottom.set(title=f"{name}: position error", xlabel="time (s)", ylabel="position error (m)")
        for axes in (top, bottom):
            axes.grid(True, alpha=0.3)
            axes.legend(loc="best", title="adaptation")
    figure.savefig(path, dpi=120)
    return Path(path)


def compare_adaptation_laws(scenarios: list[Scenario], out_dir: Path | str, laws: tuple = ADAPTATIONS, *,
                            fmu_dir: Path | str | None = None, fmi_version: int | None = None) -> str:
    """Co-simulate each scenario under each adaptation law and write the comparison.

    Writes ``laws.csv`` and ``laws.json`` (a row of ``LAW_KEYS`` per scenario and law, ``law_row``),
    ``laws.md`` (the table of docs/scenarios.md) and ``laws.png`` (``plot_laws``). Each run is the scenario
    as given with the controller's ``adaptation`` replaced (docs/model.md §3).

    Parameters
    ----------
    scenarios : list of Scenario
        The scenarios to compare the laws on.
    out_dir : pathlib.Path or str
        The folder to write into, created if missing.
    laws : tuple of str, optional
        The laws, from ``ADAPTATIONS`` ("sigma", "e", "projection", "none"). Default: all four.
    fmu_dir : pathlib.Path or str or None, optional
        Where the FMUs are built (``ensure_fmus``). Default None: ``default_fmu_dir`` of the FMI version.
    fmi_version : {2, 3} or None, optional
        The FMI version of the FMUs. Default None: that of the FMUs in ``fmu_dir``, else 2.

    Returns
    -------
    str
        The table, and where the files are.

    Raises
    ------
    ScenarioError
        One line, for a law that is not one of ``ADAPTATIONS`` or no scenario or law; before anything runs.
    CosimulationError
        If an FMU fails before anything is recorded; a run that diverges is a row with its time and reason.
    """
    laws = tuple(one_of(ADAPTATIONS, law, "adaptation") for law in laws)
    if not scenarios or not laws:
        raise ScenarioError("nothing to compare: give at least one scenario and one adaptation law; allowed laws: "
                            f"{', '.join(ADAPTATIONS)}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fmu_paths = ensure_fmus(*resolve_fmu_dir(fmu_dir, fmi_version))
    rows, results = [], {}
    with Cosimulator(fmu_paths) as simulator:
        for scenario in scenarios:
            for law in laws:
                controller = {**scenario.controller, "adaptation": ADAPTATIONS.index(law)}
                try:
                    result, failure = simulator.run(dataclasses.replace(scenario, controller=controller)).result, None
                except CosimulationError as error:
                    if error.result is None or not len(error.result):
                        raise
                    result, failure = error.result, error
                results.setdefault(scenario.name, {})[law] = result
                rows.append(law_row(scenario, law, result, failure))
    with open(out_dir / "laws.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, LAW_KEYS)
        writer.writeheader()
        writer.writerows(rows)
    (out_dir / "laws.json").write_text(json.dumps(rows, indent=1))
    table = _table(rows)
    (out_dir / "laws.md").write_text(table)
    plot_laws(results, out_dir / "laws.png")
    return f"{table}written: {out_dir / 'laws.csv'}, {out_dir / 'laws.json'}, {out_dir / 'laws.md'}, " \
           f"{out_dir / 'laws.png'}"

