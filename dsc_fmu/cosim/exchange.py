"""Co-simulation with the exchange schemes of other masters, to compare their results with ours.

``dsc_fmu.cosim.master`` reads the controller's ``u`` *after* setting its inputs at every communication
point (direct feedthrough honoured). Other masters do not:

- ``"jacobi"``: our master's Jacobi (``loop.Jacobi``), recorded at every step with what each FMU held.
- ``"libcosim"``: libcosim's ``fixed_step_algorithm`` (OSP). Initialisation: parameters set, then in
  initialisation mode N = 3 rounds of (set pending inputs, read outputs, transfer), then
  ``fmi2ExitInitializationMode`` on all, one more read and transfer. Step k: every FMU gets the
  values transferred last, all ``doStep(t_k, h)``, then every output is read and transferred.
  So the controller's ``u`` that reaches the plant for the step from ``t_k`` (k >= 1) is read
  right after the controller's step, before its inputs are updated: ``u_k = law(c_k, m_{k-1})``
  instead of ours ``law(c_k, m_k)``: one extra step of delay on the feedthrough path. At t = 0
  the initialisation rounds give ``u_0 = law(c_0, m_0)``, as ours.
- ``"simulate_ssp"``: ``fmpy.ssp.simulate_ssp``: parameters set before initialisation, no
  initial exchange (every connector starts at 0.0, so the controller's first step sees all-zero
  measurements, v_r = 0 among them: it refuses the step, or with ``start_on`` = valid_inputs waits
  it out with u = 0; the plant's first step gets u = 0), then the same step/transfer order as
  libcosim, the FMUs stepped in the order of the SSD, the time advanced by repeated addition of h
  while ``time < stop_time``.

Rows: ``time`` and every output of ``signals.RECORDED`` at every communication point, as each
master observes it: our Jacobi after the exchange at ``t_k``; libcosim and simulate_ssp after the
step that ends at ``t_k`` (libcosim's time series observer; ``simulate_ssp`` stamps that row with
``t_{k-1}``). The inputs each FMU held over each step are
recorded too (``inputs``: name -> structured array, ``time`` = the step's start).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..registry import CONTROLLER
from ..scenario import Scenario, one_of
from . import signals
from .loading import LoadedFmus
from .loop import Exchange, Jacobi, Run
from .wiring import Wiring

__all__ = ["MODES", "ExchangeRun", "cosimulate_exchange"]


@dataclass
class ExchangeRun:
    """What a run under another master's exchange recorded.

    Parameters
    ----------
    result : numpy.ndarray
        A row at every communication point, dtype ``signals.DTYPE``.
    inputs : dict of str to numpy.ndarray
        For each FMU with inputs, the inputs it held over each step (``time``: the step's start, s).
    controller_before_inputs : numpy.ndarray, optional
        Jacobi only: the controller's recorded outputs at each communication point read right after
        its step, before its inputs are updated (row 0: after the first exchange), which is what an
        importer that replays it alone with its input file records (fmpy.simulate_fmu samples the
        outputs after each doStep and sets the next inputs afterwards).
    """

    result: np.ndarray
    inputs: dict
    controller_before_inputs: np.ndarray | None = None


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

    def time_points(self, h: float, stop: float) -> list[tuple[float, float, float, float]]:
        points, t = [], 0.0
        while t < stop:
            points.append((t, h, t + h, t))
            t += h
        return points


_EXCHANGES = {"jacobi": Jacobi, "libcosim": _Libcosim, "simulate_ssp": _SimulateSsp}
MODES = tuple(_EXCHANGES)


class _Trace:
    """What each FMU held over each step, and (``before``) the controller's outputs right after its step."""

    def __init__(self, wiring: Wiring, before: bool):
        self.wiring = wiring
        self.inputs = {end: [] for end in wiring.feeds}
        self.before = [] if before else None

    def stepped(self, t: float, end: float) -> None:
        for name, feed in self.wiring.feeds.items():
            self.inputs[name].append((t, *feed.held))
        if self.before is not None:
            values = self.wiring.controller.get_values(signals.RECORDED[CONTROLLER])
            self.before.append((end, *(values[name] for name in signals.RECORDED[CONTROLLER])))


def cosimulate_exchange(scenario: Scenario, fmu_paths: dict, mode: str, *, step_size: float | None = None,
                        stop_time: float | None = None) -> ExchangeRun:
    """Co-simulate a scenario with another master's exchange scheme (see the module), at fixed steps.

    Parameters
    ----------
    scenario : Scenario
        The scenario.
    fmu_paths : dict
        The three FMU files by name.
    mode : {"jacobi", "libcosim", "simulate_ssp"}
        The scheme (``MODES``).
    step_size, stop_time : float, optional
        s; None: the scenario's.

    Returns
    -------
    ExchangeRun
        The rows as that master observes them, and the inputs each FMU held.

    Raises
    ------
    ScenarioError
        If ``mode`` is not one of ``MODES``.
    FmuNotFoundError
        If an FMU is not given or not a file.
    CosimulationError
        Our Jacobi: a divergence, as for ``cosimulate``; any scheme: a failing FMI call.
    """
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
        columns = ["time", *signals.RECORDED[CONTROLLER]]
        before = np.array([tuple(result[columns][0]), *trace.before], dtype=[(c, np.float64) for c in columns])
    return ExchangeRun(result=result, inputs=inputs, controller_before_inputs=before)
