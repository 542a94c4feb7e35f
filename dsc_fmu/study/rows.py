"""One case to one row: its run and reference solution, their comparison, its stability."""

from __future__ import annotations

import json
import math
import time as clock
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..cosim.master import CosimulationError, Cosimulator
from ..cosim.metrics import tracking_metrics
from ..scenario import Scenario, Stability
from .cache import (
    REFERENCE_COLUMNS, REFERENCE_GRID, REFERENCE_SETTINGS, TRAJECTORY, case_key, fmu_identities, reference_key,
)
from .cases import Case, apply

__all__ = ["STABLE_POSITION_ERROR", "SETTLED_DEFINITION", "LOCAL_DEFINITION", "METRIC_KEYS", "DEVIATION_KEYS",
           "ROW_KEYS", "simulate"]

STABLE_POSITION_ERROR = 0.5  # m
GROWTH_FACTOR, GROWTH_SLACK = 1.25, 1e-3  # 1, m: the position error over the last third
DEVIATION_GROWTH, DEVIATION_SLACK = 2.0, 1e-5  # 1, m: the deviation from the reference solution after its start
SEED_TIME, SEED_ROWS = 1.0, 3  # s, rows after t = 0: the window over which the first steps seed the deviation
SETTLED_DEFINITION = (
    "A run is stable if it did not diverge (every exchanged signal stayed finite and within the scenario's "
    f"bound, and no FMU failed), its position error sqrt(xe^2 + ye^2) stayed below {STABLE_POSITION_ERROR:g} m "
    "over the last third of the run, and it did not grow there: its maximum over the last sixth of the run is "
    f"at most {GROWTH_FACTOR:g} times its maximum over the sixth before, plus {GROWTH_SLACK * 1e3:g} mm (a slowly "
    "growing oscillation, a spectral radius just above 1, is unstable even if it has not diverged yet). The "
    "criterion assumes a run long enough for the start-up transient to have decayed by its last third "
    "(30 s for the paper's scenario)."
)
LOCAL_DEFINITION = (
    "Stability of steady tracking ([simulation] stability = \"local\", for a scenario that starts in steady "
    "tracking): a run is stable if it is stable as a settled run is (it did not diverge, its position error "
    f"stayed below {STABLE_POSITION_ERROR:g} m over the last third of the run and did not grow there by more "
    f"than {GROWTH_FACTOR:g} times plus {GROWTH_SLACK * 1e3:g} mm from the sixth before the last to the last) "
    "and it stayed with the reference solution: its position deviation from it never exceeded "
    f"{DEVIATION_GROWTH:g} times its maximum over the first {SEED_TIME:g} s of the run (at least its first "
    f"{SEED_ROWS} recorded steps), plus {DEVIATION_SLACK * 1e3:g} mm. The coupling error of the first steps seeds "
    "the deviation, which a stable loop reaches within a few tenths of a second; a sampled loop that is stable "
    "about steady tracking keeps it at that level, an unstable one amplifies it, even where the oscillation "
    "later moves the parameter estimates and the adaptation damps it (the linearised prediction freezes the "
    "estimates: this is the instability it predicts). A run no longer than that window, an error-controlled "
    "run (its step grows by design) and a run without a reference solution are judged as settled ones."
)
METRIC_KEYS = ("final_position_error_m", "rms_position_error_m", "max_position_error_m", "max_abs_thetae_rad",
               "settling_time_0p1_s", "max_abs_u_V", "beta_guard_count")
DEVIATION_KEYS = ("max_position_deviation_m", "rms_position_deviation_m", "max_heading_deviation_rad",
                  "rms_heading_deviation_rad", "max_u_deviation_V", "rms_u_deviation_V")
ROW_KEYS = ("scenario", "step_size", "order", "discretization", "coupling", "tolerance", "sample", "key",
            "reference_key", "diverged", "diverged_time", "diverged_signal", "diverged_reason", "stability", "stable",
            *DEVIATION_KEYS, *METRIC_KEYS, "wall_time_s", "steps", "steps_rejected", "fmu_steps")
"""The keys of a row, in order; a case's overrides (``table.name``) come between ``sample`` and ``key``
(``row_keys``)."""


def row_keys(case: Case) -> tuple[str, ...]:
    """``ROW_KEYS`` with the names of the case's overrides (``table.name``) between ``sample`` and ``key``."""
    at = ROW_KEYS.index("key")
    return (*ROW_KEYS[:at], *(key for key, _ in case.overrides), *ROW_KEYS[at:])


def _columns(result: np.ndarray, names) -> np.ndarray:
    """The columns ``names`` of a structured array, as a new compact array."""
    out = np.zeros(len(result), dtype=[(name, np.float64) for name in names])
    for name in names:
        out[name] = result[name]
    return out


class Plan(NamedTuple):
    """A case of a sweep ready to run: the case, the scenario it runs (``cases.apply``), the cache keys of its
    row and of its reference solution (``cache.case_key``, ``cache.reference_key``)."""

    case: Case
    applied: Scenario
    key: str
    reference_key: str

    @classmethod
    def of(cls, scenario: Scenario, case: Case, identities: dict) -> Plan:
        """The plan of ``case`` on the sweep's ``scenario``, with FMUs of ``identities`` (``cache.fmu_identities``)."""
        return cls(case, apply(scenario, case), case_key(scenario, case, identities),
                   reference_key(scenario, case, identities))


@dataclass(frozen=True, eq=False)
class Outcome:
    """What a run gives its row: made by ``simulate``, or by ``Outcome.of_lost`` for a run that did not finish.

    The ``TRAJECTORY`` as recorded (up to the failure for a diverged run, empty if lost); the tracking
    metrics (``METRIC_KEYS``; None if diverged or lost); when (s) and where (the signal, or the failing
    FMU) it diverged and why, on one line (also why it did not finish); the communication steps, the
    error-controlled steps taken again and the doStep calls over all FMUs (NaN where unknown); its wall
    time (s); ``lost``: its worker process was lost, so it is not cached (a later sweep tries it again).
    """

    trajectory: np.ndarray
    metrics: dict | None
    diverged_time: float = math.nan
    diverged_signal: str | None = None
    diverged_reason: str | None = None
    steps: float = math.nan
    steps_rejected: float = math.nan
    fmu_steps: float = math.nan
    wall_time_s: float = math.nan
    lost: bool = False

    @classmethod
    def of_lost(cls, reason: str) -> Outcome:
        """A run that did not finish because its worker process was lost, ``reason`` on one line."""
        return cls(np.zeros(0, dtype=[(name, np.float64) for name in TRAJECTORY]), None, diverged_reason=reason,
                   lost=True)


def simulate(applied: Scenario, cosimulator: Cosimulator) -> Outcome:
    """Run one applied case and return what its row needs.

    Parameters
    ----------
    applied : Scenario
        A case applied to its scenario (``cases.apply``).
    cosimulator : Cosimulator
        The loaded FMUs to run it with.

    Returns
    -------
    Outcome
        The trajectory, the tracking metrics (None if it diverged), the divergence, the steps and
        the wall time (s).
    """
    started = clock.perf_counter()
    try:
        run = cosimulator.run(applied)
    except CosimulationError as error:
        return Outcome(_columns(error.result, TRAJECTORY), None, float(error.time), error.signal or error.fmu,
                       " ".join(str(error).split()), error.steps, wall_time_s=clock.perf_counter() - started)
    metrics = tracking_metrics(run.result, applied.simulation.stop_time)
    return Outcome(_columns(run.result, TRAJECTORY), {k: metrics[k] for k in METRIC_KEYS}, steps=run.steps,
                   steps_rejected=run.rejected, fmu_steps=run.fmu_steps, wall_time_s=clock.perf_counter() - started)


class ReferenceOutcome(NamedTuple):
    """``REFERENCE_COLUMNS`` every ``REFERENCE_GRID`` s up to the stop time, or None and why the solver failed."""

    solution: np.ndarray | None
    failure: str | None


def compute_reference(applied: Scenario, fmu_paths: dict | None = None) -> ReferenceOutcome:
    """The ReferenceOutcome of an applied case (``cases.apply``): of the monolithic ODE (docs/model.md), or
    with ``applied.simulation.reference`` = "model-exchange" of the FMUs of ``fmu_paths`` as one ODE
    (ValueError without them)."""
    from ..cosim.model_exchange import simulate_model_exchange  # scipy: only where references are computed
    from ..cosim.reference_solution import output_times, reference_solution

    through_fmus = applied.simulation.reference.through_fmus
    if through_fmus and fmu_paths is None:
        raise ValueError("a reference solution through model exchange needs the FMUs (fmu_paths)")
    try:
        if through_fmus:
            solution = simulate_model_exchange(applied, fmu_paths, tolerance=REFERENCE_SETTINGS["rtol"],
                                               output_interval=REFERENCE_GRID).result
        else:
            times = output_times(applied.simulation.stop_time, REFERENCE_GRID)
            solution = reference_solution(applied, times=times, **REFERENCE_SETTINGS)
    except (RuntimeError, ArithmeticError, ValueError, CosimulationError) as error:
        return ReferenceOutcome(None, " ".join(str(error).split()))
    return ReferenceOutcome(_columns(solution, REFERENCE_COLUMNS), None)


def _grows_at_end(t: np.ndarray, values: np.ndarray) -> bool:
    """Whether ``values`` over the last sixth of ``t`` exceed ``GROWTH_FACTOR`` times their maximum over
    the sixth before, plus ``GROWTH_SLACK``."""
    end = t[-1]
    earlier = values[(t >= 2.0 * end / 3.0) & (t < 5.0 * end / 6.0)]
    later = values[t >= 5.0 * end / 6.0]
    if not len(earlier) or not len(later):
        return False
    return bool(later.max() > GROWTH_FACTOR * earlier.max() + GROWTH_SLACK)


def error_grows(trajectory: np.ndarray) -> bool:
    """Whether the position error's maximum over the last sixth of the run exceeds ``GROWTH_FACTOR`` times
    that over the sixth before plus ``GROWTH_SLACK`` (m) (``SETTLED_DEFINITION``)."""
    error = np.hypot(trajectory["x_r"] - trajectory["x"], trajectory["y_r"] - trajectory["y"])
    return _grows_at_end(trajectory["time"], error)


def _reference_at(trajectory: np.ndarray, reference: np.ndarray, names) -> dict:
    """The reference solution's columns ``names`` interpolated linearly at the run's times."""
    return {name: np.interp(trajectory["time"], reference["time"], reference[name]) for name in names}


def position_deviation(trajectory: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The run's distance (m) from the reference solution, interpolated linearly, at each of its times."""
    at = _reference_at(trajectory, reference, ("x", "y"))
    return np.hypot(trajectory["x"] - at["x"], trajectory["y"] - at["y"])


def seed_window(t: np.ndarray) -> np.ndarray | None:
    """The mask of the rows over which the first steps seed the deviation (``LOCAL_DEFINITION``): the first
    ``SEED_TIME`` s, at least ``SEED_ROWS`` rows after t = 0; None for a run no longer than that."""
    if len(t) <= SEED_ROWS + 1:
        return None
    start = t <= max(SEED_TIME, t[SEED_ROWS])
    return None if start.all() else start


def deviation_grows(trajectory: np.ndarray, reference: np.ndarray) -> bool:
    """Whether the sampled loop amplifies the coupling error about steady tracking (``LOCAL_DEFINITION``): the
    position deviation ever exceeds ``DEVIATION_GROWTH`` times its maximum over the ``seed_window`` plus
    ``DEVIATION_SLACK`` (m); False for a run without a seed window."""
    start = seed_window(trajectory["time"])
    if start is None:
        return False
    deviation = position_deviation(trajectory, reference)
    return bool(deviation.max() > DEVIATION_GROWTH * deviation[start].max() + DEVIATION_SLACK)


def stability_definition(stability: str) -> str:
    """What "stable" means for a scenario's ``[simulation] stability``."""
    return LOCAL_DEFINITION if Stability(stability).from_start else SETTLED_DEFINITION


def deviations(trajectory: np.ndarray, reference: np.ndarray) -> dict:
    """``DEVIATION_KEYS``: the largest and RMS deviation of a run from the reference solution over all its
    rows, of position (m), wrapped heading (rad) and the voltage of both wheels (V)."""
    at = _reference_at(trajectory, reference, ("theta", "u1", "u2"))
    position = position_deviation(trajectory, reference)
    heading = np.abs(np.remainder(trajectory["theta"] - at["theta"] + np.pi, 2.0 * np.pi) - np.pi)
    voltage = np.abs(np.concatenate([trajectory["u1"] - at["u1"], trajectory["u2"] - at["u2"]]))
    values = {}
    for name, error, unit in (("position", position, "m"), ("heading", heading, "rad"), ("u", voltage, "V")):
        values[f"max_{name}_deviation_{unit}"] = float(np.max(error))
        values[f"rms_{name}_deviation_{unit}"] = float(np.sqrt(np.mean(error**2)))
    return values


def make_row(plan: Plan, outcome: Outcome, reference: np.ndarray | None) -> dict:
    """The row of a simulated case (``row_keys(plan.case)``, JSON-serialisable, NaN where a value does not
    apply): its settings, its deviations from ``reference`` (None: NaN, and judged as a settled run), its
    metrics and stability, ``stability`` naming the definition ``stable`` was judged by."""
    case, applied = plan.case, plan.applied
    diverged = outcome.metrics is None
    metrics = dict.fromkeys(METRIC_KEYS, math.nan) if diverged else outcome.metrics
    usable = not diverged and reference is not None and len(outcome.trajectory)
    local = bool(usable and applied.simulation.stability.from_start and case.tolerance is None
                 and seed_window(outcome.trajectory["time"]) is not None)
    row = {"scenario": applied.name, "step_size": case.step_size, "order": case.order,
           "discretization": case.discretization, "coupling": case.coupling, "tolerance": case.tolerance,
           "sample": case.sample, **dict(case.overrides), "key": plan.key, "reference_key": plan.reference_key,
           "diverged": diverged, "diverged_time": outcome.diverged_time,
           "diverged_signal": outcome.diverged_signal, "diverged_reason": outcome.diverged_reason,
           "stability": Stability.LOCAL if local else Stability.SETTLED,
           "stable": not diverged and metrics["max_position_error_m"] < STABLE_POSITION_ERROR
           and not error_grows(outcome.trajectory)
           and not (local and deviation_grows(outcome.trajectory, reference))}
    row.update(deviations(outcome.trajectory, reference) if usable else dict.fromkeys(DEVIATION_KEYS, math.nan))
    row.update({name: math.nan if value is None else value for name, value in metrics.items()})
    row.update(wall_time_s=outcome.wall_time_s, steps=outcome.steps, steps_rejected=outcome.steps_rejected,
               fmu_steps=outcome.fmu_steps)
    return json.loads(json.dumps(row))  # exactly what the cache gives back


def run_case(scenario: Scenario, case: Case, cosimulator: Cosimulator, reference: np.ndarray | None) -> dict:
    """The row of ``case`` run in this process with ``cosimulator``, as a sweep makes it; ``reference`` None
    leaves the deviations NaN and judges the run as a settled one."""
    plan = Plan.of(scenario, case, fmu_identities(cosimulator.paths))
    return make_row(plan, simulate(plan.applied, cosimulator), reference)
