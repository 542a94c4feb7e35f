"""Co-simulation with the exchange schemes of other masters, to compare their results with ours: our Jacobi
recorded as an importer replaying one FMU sees it, libcosim's and ``fmpy.ssp.simulate_ssp``'s schedules
(docs/other-tools.md, "How the other masters exchange")."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ..scenario import Scenario, one_of
from . import signals
from .loading import LoadedFmus
from .loop import Exchange, Jacobi, Run
from .wiring import Wiring

__all__: list[str] = []  # the package's own: MODES, ExchangeRun, cosimulate_exchange


@dataclass
class ExchangeRun:
    """What a run under another master's exchange recorded: the rows (dtype ``signals.DTYPE``), the inputs each
    FMU held over each step (``time``: the step's start) and, Jacobi only, the outputs of each FMU with inputs read
    right after its step, before its inputs are updated (row 0: after the first exchange), as an importer replaying
    it alone records them (they differ from the rows' where an output depends on an input: the controller's ``u``,
    the plant's applied voltages), by FMU name."""

    result: np.ndarray
    inputs: dict
    before_inputs: dict | None = None


class _StepThenTransfer(Exchange):
    """The loop of libcosim and ``simulate_ssp``: parameters set before initialisation mode; before a step
    every FMU gets the values transferred last (0.0 before the first transfer, as SSP's connectors start);
    after it every output is read and transferred, and a row recorded."""

    parameters_first = True

    def __init__(self):
        self.pending = None

    def transfer(self, run: Run) -> None:
        self.pending = {end: feed.read(run.at[1], None) for end, feed in run.wiring.feeds.items()}

    def push(self, run: Run) -> None:
        if self.pending is None:
            self.pending = {end: [0.0] * len(feed.refs) for end, feed in run.wiring.feeds.items()}
        for end, feed in run.wiring.feeds.items():
            feed.set(self.pending[end])

    def start(self, run: Run) -> None:
        """None: no exchange after initialisation, no row at t = 0."""

    def step(self, run: Run, t: float, h: float, end: float) -> None:
        self.push(run)
        for fmu in run.wiring.in_order():
            fmu.do_step(t, h)
        run.stepped(end)
        self.transfer(run)


class _Libcosim(_StepThenTransfer):
    """libcosim's ``fixed_step_algorithm``: N rounds of (set, read, transfer) in initialisation mode, then
    a transfer and a row after it."""

    def initialise(self, run: Run) -> None:
        for _ in run.wiring.fmus:  # N iterations, N = number of simulators
            self.push(run)
            self.transfer(run)
        self.push(run)

    def start(self, run: Run) -> None:
        self.transfer(run)
        run.recorder.record(0.0)


class _SimulateSsp(_StepThenTransfer):
    """``fmpy.ssp.simulate_ssp``: no stop time, time advanced by adding h while below the stop time, each
    row stamped with the start of its step."""

    def stop_time(self, stop: float) -> None:
        return None

    def step_count(self, h: float, stop: float) -> int:
        return sum(1 for _ in self.time_points(h, stop))

    def time_points(self, h: float, stop: float) -> Iterator[tuple[float, float, float, float]]:
        t = 0.0
        while t < stop:
            yield t, h, t + h, t
            t += h


_EXCHANGES = {"jacobi": Jacobi, "libcosim": _Libcosim, "simulate_ssp": _SimulateSsp}
MODES = tuple(_EXCHANGES)


class _Trace:
    """What each FMU held over each step, and (``before``) the outputs of each FMU with inputs right after its step."""

    def __init__(self, wiring: Wiring, before: bool):
        self.wiring = wiring
        self.inputs = {end: [] for end in wiring.feeds}
        self.before = {end: [] for end in wiring.feeds} if before else None

    def stepped(self, t: float, end: float) -> None:
        for name, feed in self.wiring.feeds.items():
            self.inputs[name].append((t, *feed.held))
        if self.before is not None:
            for name, rows in self.before.items():
                values = self.wiring.fmus[name].get_values(signals.RECORDED[name])
                rows.append((end, *(values[output] for output in signals.RECORDED[name])))


def cosimulate_exchange(scenario: Scenario, fmu_paths: dict, mode: str, *, step_size: float | None = None,
                        stop_time: float | None = None) -> ExchangeRun:
    """Co-simulate a scenario at fixed steps with the exchange scheme ``mode`` (``MODES``; ScenarioError if not
    one of them)."""
    mode = one_of(_EXCHANGES, mode, "mode")
    scenario = scenario.with_simulation(step_size=step_size, stop_time=stop_time)
    log = []
    with LoadedFmus(fmu_paths, None, log) as fmus:
        wiring = Wiring(fmus.by_name)
        trace = _Trace(wiring, before=mode == "jacobi")
        run = Run(scenario, wiring, log, _EXCHANGES[mode](), 1, trace=trace)
        run.execute(fmus.loaded)
    result = run.recorder.result()
    inputs = {name: np.array(rows, dtype=[("time", np.float64), *((s, np.float64) for s in wiring.feeds[name].inputs)])
              for name, rows in trace.inputs.items()}
    before = None
    if trace.before is not None:
        before = {}
        for name, rows in trace.before.items():
            columns = ["time", *signals.RECORDED[name]]
            before[name] = np.array([tuple(result[columns][0]), *rows], dtype=[(c, np.float64) for c in columns])
    return ExchangeRun(result=result, inputs=inputs, before_inputs=before)
