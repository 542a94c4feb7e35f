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

import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import signals
from .master import _callbacks, _Fmu, step_count
from ..registry import CONTROLLER, ORDER, PLANT, REFERENCE
from ..scenario import Scenario

__all__ = ["MODES", "ExchangeRun", "cosimulate_exchange"]

MODES = ("jacobi", "libcosim", "simulate_ssp")


@dataclass
class ExchangeRun:
    """``result``: structured array (``signals.DTYPE``) at every communication point;
    ``inputs``: for each FMU with inputs, the inputs it held over each step (``time`` = start)."""

    result: np.ndarray
    inputs: dict
    controller_before_inputs: np.ndarray | None = None
    """Jacobi only: the controller's recorded outputs at each communication point read right after
    its step, before its inputs are updated (row 0: after the first exchange), which is what an
    importer that replays it alone with its input file records (fmpy.simulate_fmu samples the
    outputs after each doStep and sets the next inputs afterwards)."""


def _connections(slaves: dict) -> dict:
    """For every input of every FMU, the (source FMU, output) feeding it: same names."""
    sources = {}
    for name in ORDER:
        for signal in slaves[name].inputs:
            source = next(s for s in ORDER if s != name and signal in slaves[s].outputs)
            sources[(name, signal)] = source
    return sources


def cosimulate_exchange(scenario: Scenario, fmu_paths: dict, mode: str, *, step_size: float | None = None,
                        stop_time: float | None = None) -> ExchangeRun:
    """Co-simulate ``scenario`` with the exchange scheme ``mode`` (one of ``MODES``, see the module)."""
    if mode not in MODES:
        raise ValueError(f"mode {mode!r} is not allowed; allowed: {', '.join(MODES)}")
    scenario = scenario.with_simulation(step_size=step_size, stop_time=stop_time)
    h, stop = scenario.simulation.step_size, scenario.simulation.stop_time
    if mode == "simulate_ssp":
        times, t = [], 0.0
        while t < stop:
            times.append(t)
            t += h
        steps = [(t0, h) for t0 in times]
        ends = times  # simulate_ssp stamps each row with the start of its step
    else:
        n = step_count(stop, h)
        steps = [(k * h, h if k < n - 1 else stop - k * h) for k in range(n)]
        ends = [(k + 1) * h for k in range(n - 1)] + [stop]  # the master's time points
    root = Path(tempfile.mkdtemp(prefix="dsc_fmu_exchange_"))
    slaves = {}
    callbacks = _callbacks([])  # the master's logger, not fmpy's process-wide proxy
    try:
        for name in ORDER:
            slaves[name] = _Fmu(name, root)
            slaves[name].load(Path(fmu_paths[name]), callbacks)
        sources = _connections(slaves)
        held = {key: 0.0 for key in sources}  # the value each input connector holds (SSP: 0.0 at start)
        outputs = {name: {} for name in ORDER}

        def read_all():
            for name in ORDER:
                outputs[name] = slaves[name].get_values(slaves[name].outputs)  # Real and Integer ones

        def transfer():
            for (name, signal), source in sources.items():
                held[(name, signal)] = outputs[source][signal]

        def push():
            for name in ORDER:
                slaves[name].set_values({s: held[(name, s)] for s in slaves[name].inputs})

        for name in ORDER:
            slaves[name].enter_initialization(None if mode == "simulate_ssp" else stop, scenario.parameters(name),
                                              set_first=mode != "jacobi")
        if mode == "libcosim":
            read_all()
            for _ in ORDER:  # N iterations, N = number of simulators
                push()
                read_all()
                transfer()
            push()
        for name in ORDER:
            slaves[name].slave.exitInitializationMode()

        rows, seen, before = [], {name: [] for name in ORDER if slaves[name].inputs}, []

        def record(at):
            rows.append((at, {n: v for name in ORDER for n, v in outputs[name].items()}))

        def exchange_jacobi():
            plant, ref, ctl = slaves[PLANT], slaves[REFERENCE], slaves[CONTROLLER]
            outputs[PLANT] = plant.get_values(signals.RECORDED[PLANT])
            outputs[REFERENCE] = ref.get_values(signals.RECORDED[REFERENCE])
            for s in ctl.inputs:
                held[(CONTROLLER, s)] = outputs[sources[(CONTROLLER, s)]][s]
            ctl.set_values({s: held[(CONTROLLER, s)] for s in ctl.inputs})
            outputs[CONTROLLER] = ctl.get_values(signals.RECORDED[CONTROLLER])
            for s in plant.inputs:
                held[(PLANT, s)] = outputs[CONTROLLER][s]
            plant.set_values({s: held[(PLANT, s)] for s in plant.inputs})

        if mode == "libcosim":
            read_all()
            transfer()
            record(0.0)
        elif mode == "jacobi":
            exchange_jacobi()
            record(0.0)
        for (t, step), end in zip(steps, ends):
            if mode != "jacobi":
                push()
            for name in seen:
                seen[name].append((t, *(held[(name, s)] for s in slaves[name].inputs)))
            for name in ORDER:
                slaves[name].slave.doStep(currentCommunicationPoint=t, communicationStepSize=step)
            if mode == "jacobi":
                before.append((end, slaves[CONTROLLER].get_values(signals.RECORDED[CONTROLLER])))
                exchange_jacobi()
            else:
                read_all()
                transfer()
            record(end)
    finally:
        for slave in reversed(list(slaves.values())):
            slave.close()
        shutil.rmtree(root, ignore_errors=True)

    result = np.zeros(len(rows), dtype=signals.DTYPE)
    result["time"] = [at for at, _ in rows]
    for name in ORDER:
        for signal in signals.RECORDED[name]:
            result[signal] = [values[signal] for _, values in rows]
    signals.add_tracking_errors(result)
    inputs = {}
    for name, table in seen.items():
        dtype = [("time", np.float64), *((s, np.float64) for s in slaves[name].inputs)]
        inputs[name] = np.array(table, dtype=dtype)
    controller_before = None
    if mode == "jacobi":
        columns = ["time", *signals.RECORDED[CONTROLLER]]
        controller_before = np.zeros(len(rows), dtype=[(c, np.float64) for c in columns])
        first = rows[0][1]
        table = [(0.0, {c: first[c] for c in columns[1:]}), *before]
        controller_before["time"] = [at for at, _ in table]
        for c in columns[1:]:
            controller_before[c] = [values[c] for _, values in table]
    return ExchangeRun(result=result, inputs=inputs, controller_before_inputs=controller_before)

