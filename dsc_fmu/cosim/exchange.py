"""Co-simulation with the exchange schemes of other masters, to compare their results with ours.

``dsc_fmu.cosim.master`` reads the controller's ``u`` *after* setting its inputs at every communication
point (direct feedthrough honoured). Other masters do not:

- ``"jacobi"``: our master's Jacobi, re-implemented here (same values bit for bit; a check of this
  module against ``dsc_fmu.cosim.master``).
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

from ..registry import CONNECTIONS, CONTROLLER, ORDER, PLANT, REFERENCE
from ..scenario import Scenario, one_of
from . import signals
from .instance import LoadedFmu
from .loading import LoadedFmus
from .master import step_count

__all__ = ["MODES", "SCHEMES", "ExchangeRun", "Scheme", "cosimulate_exchange"]


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
        Jacobi only: the controller's recorded outputs read right after each step, before its
        inputs are updated (see the attribute's note).
    """

    result: np.ndarray
    inputs: dict
    controller_before_inputs: np.ndarray | None = None
    """Jacobi only: the controller's recorded outputs at each communication point read right after
    its step, before its inputs are updated (row 0: after the first exchange), which is what an
    importer that replays it alone with its input file records (fmpy.simulate_fmu samples the
    outputs after each doStep and sets the next inputs afterwards)."""


class _Loop:
    """The three loaded FMUs of one run, the value each input connector holds, the outputs read last
    and the rows recorded: the operations every scheme is made of."""

    def __init__(self, slaves: dict[str, LoadedFmu]):
        self.slaves = slaves
        self.sources = {(c.end, c.signal): c.start for c in CONNECTIONS}
        self.held = dict.fromkeys(self.sources, 0.0)  # SSP: every connector starts at 0.0
        self.outputs = {name: {} for name in ORDER}
        self.rows, self.before = [], []
        self.seen = {name: [] for name in ORDER if slaves[name].inputs}

    def read_all(self) -> None:
        """Read every output of every FMU (Real and Integer)."""
        for name in ORDER:
            self.outputs[name] = self.slaves[name].get_values(self.slaves[name].outputs)

    def transfer(self) -> None:
        """Every input connector takes the output read last from its source."""
        for (name, signal), source in self.sources.items():
            self.held[(name, signal)] = self.outputs[source][signal]

    def push(self) -> None:
        """Set every FMU's inputs to the values their connectors hold."""
        for name in ORDER:
            self._set(name)

    def exchange(self) -> None:
        """Our master's exchange: measurements to the controller, then its ``u`` to the plant."""
        for name in (PLANT, REFERENCE):
            self.outputs[name] = self.slaves[name].get_values(signals.RECORDED[name])
        self._take(CONTROLLER)
        self.outputs[CONTROLLER] = self.slaves[CONTROLLER].get_values(signals.RECORDED[CONTROLLER])
        self._take(PLANT)

    def _take(self, name: str) -> None:
        for signal in self.slaves[name].inputs:
            self.held[(name, signal)] = self.outputs[self.sources[(name, signal)]][signal]
        self._set(name)

    def _set(self, name: str) -> None:
        slave = self.slaves[name]
        slave.set_values({s: self.held[(name, s)] for s in slave.inputs})

    def step(self, t: float, step: float) -> None:
        """Note the inputs each FMU holds, then ``doStep(t, step)`` on all three in ``ORDER``."""
        for name, table in self.seen.items():
            table.append((t, *(self.held[(name, s)] for s in self.slaves[name].inputs)))
        for name in ORDER:
            self.slaves[name].slave.doStep(currentCommunicationPoint=t, communicationStepSize=step)

    def record(self, at: float) -> None:
        self.rows.append((at, {n: v for name in ORDER for n, v in self.outputs[name].items()}))


class Scheme:
    """How a master exchanges: its time points, initialisation and what it does around each step.

    This base is the step-then-transfer loop of libcosim and ``simulate_ssp``: before a step every FMU
    gets the values transferred last; after it every output is read, transferred and recorded.
    """

    name = ""
    parameters_first = True  # parameters set before initialisation mode

    def time_points(self, h: float, stop: float) -> list[tuple[float, float, float]]:
        """The steps of a run: ``t_k = k h``, the last one shorter to end at ``stop``.

        Parameters
        ----------
        h : float
            Communication step in s.
        stop : float
            Stop time in s.

        Returns
        -------
        list of tuple of float
            (start, step, recorded time) of every step, in s.
        """
        n = step_count(stop, h)
        return [(k * h, h if k < n - 1 else stop - k * h, (k + 1) * h if k < n - 1 else stop) for k in range(n)]

    def stop_time(self, stop: float) -> float | None:
        """The stop time the master passes to ``setupExperiment``.

        Parameters
        ----------
        stop : float
            The run's stop time in s.

        Returns
        -------
        float or None
            In s; None: none.
        """
        return stop

    def initialise(self, loop: _Loop) -> None:
        """What the master does in initialisation mode, after the parameters.

        Parameters
        ----------
        loop : _Loop
            The loaded FMUs and their connectors.
        """

    def start(self, loop: _Loop) -> None:
        """What the master does after initialisation, before the first step.

        Parameters
        ----------
        loop : _Loop
            The loaded FMUs and their connectors.
        """

    def before_step(self, loop: _Loop) -> None:
        """What the master does before each step: set every FMU's inputs.

        Parameters
        ----------
        loop : _Loop
            The loaded FMUs and their connectors.
        """
        loop.push()

    def after_step(self, loop: _Loop, end: float) -> None:
        """What the master does after each step: read, transfer and record every output.

        Parameters
        ----------
        loop : _Loop
            The loaded FMUs and their connectors.
        end : float
            The time in s the row is recorded at.
        """
        loop.read_all()
        loop.transfer()
        loop.record(end)


class _Jacobi(Scheme):
    """Our master's Jacobi: the exchange (direct feedthrough honoured) at every point, then all step."""

    name = "jacobi"
    parameters_first = False

    def start(self, loop: _Loop) -> None:
        loop.exchange()
        loop.record(0.0)

    def before_step(self, loop: _Loop) -> None:
        pass

    def after_step(self, loop: _Loop, end: float) -> None:
        loop.before.append((end, loop.slaves[CONTROLLER].get_values(signals.RECORDED[CONTROLLER])))
        loop.exchange()
        loop.record(end)


class _Libcosim(Scheme):
    """libcosim's ``fixed_step_algorithm``: N rounds of (set, read, transfer) in initialisation mode."""

    name = "libcosim"

    def initialise(self, loop: _Loop) -> None:
        loop.read_all()
        for _ in ORDER:  # N iterations, N = number of simulators
            loop.push()
            loop.read_all()
            loop.transfer()
        loop.push()

    def start(self, loop: _Loop) -> None:
        loop.read_all()
        loop.transfer()
        loop.record(0.0)


class _SimulateSsp(Scheme):
    """``fmpy.ssp.simulate_ssp``: no stop time, no initial exchange, time advanced by adding h while
    below the stop time, each row stamped with the start of its step."""

    name = "simulate_ssp"

    def time_points(self, h: float, stop: float) -> list[tuple[float, float, float]]:
        points, t = [], 0.0
        while t < stop:
            points.append((t, h, t))
            t += h
        return points

    def stop_time(self, stop: float) -> None:
        return None


SCHEMES = {scheme.name: scheme for scheme in (_Jacobi(), _Libcosim(), _SimulateSsp())}
MODES = tuple(SCHEMES)


def cosimulate_exchange(scenario: Scenario, fmu_paths: dict, mode: str, *, step_size: float | None = None,
                        stop_time: float | None = None) -> ExchangeRun:
    """Co-simulate a scenario with another master's exchange scheme (see the module).

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
    """
    scheme = SCHEMES[one_of(SCHEMES, mode, "mode")]
    scenario = scenario.with_simulation(step_size=step_size, stop_time=stop_time)
    h, stop = scenario.simulation.step_size, scenario.simulation.stop_time
    with LoadedFmus(fmu_paths, None, []) as fmus:
        slaves = fmus.by_name
        loop = _Loop(slaves)
        for name in ORDER:
            slaves[name].enter_initialization(scheme.stop_time(stop), scenario.parameters(name),
                                              set_first=scheme.parameters_first)
        scheme.initialise(loop)
        for name in ORDER:
            slaves[name].slave.exitInitializationMode()
        scheme.start(loop)
        for t, step, end in scheme.time_points(h, stop):
            scheme.before_step(loop)
            loop.step(t, step)
            scheme.after_step(loop, end)
    return ExchangeRun(result=_table(loop.rows), inputs=_inputs(loop),
                       controller_before_inputs=_before(loop) if loop.before else None)


def _table(rows: list) -> np.ndarray:
    """The recorded rows as a ``signals.DTYPE`` array with the tracking errors."""
    result = np.zeros(len(rows), dtype=signals.DTYPE)
    result["time"] = [at for at, _ in rows]
    for name in ORDER:
        for signal in signals.RECORDED[name]:
            result[signal] = [values[signal] for _, values in rows]
    signals.add_tracking_errors(result)
    return result


def _inputs(loop: _Loop) -> dict:
    """The inputs each FMU held over each step, by FMU, as structured arrays (``time`` = the step's start)."""
    inputs = {}
    for name, table in loop.seen.items():
        dtype = [("time", np.float64), *((s, np.float64) for s in loop.slaves[name].inputs)]
        inputs[name] = np.array(table, dtype=dtype)
    return inputs


def _before(loop: _Loop) -> np.ndarray:
    """``ExchangeRun.controller_before_inputs`` of a Jacobi run."""
    columns = ["time", *signals.RECORDED[CONTROLLER]]
    first = loop.rows[0][1]
    table = [(0.0, {c: first[c] for c in columns[1:]}), *loop.before]
    before = np.zeros(len(table), dtype=[(c, np.float64) for c in columns])
    before["time"] = [at for at, _ in table]
    for c in columns[1:]:
        before[c] = [values[c] for _, values in table]
    return before
