"""The co-simulation master: the three FMUs on fmpy, a fixed communication step, Gauss-Seidel or Jacobi."""

from __future__ import annotations

import math
import shutil
import tempfile
import time as clock
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from zipfile import BadZipFile

import numpy as np
from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.fmi2 import fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE
from fmpy.model_description import ValidationError

from . import signals
from .build import fmu_build_id
from .scenario import Scenario

__all__ = ["CosimulationError", "CosimulationResult", "LogMessage", "cosimulate", "step_count"]

REFERENCE, PLANT, CONTROLLER = "ReferenceRobot", "MobileRobot", "DSCController"
_STATUS = ("OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING")


@dataclass(frozen=True)
class LogMessage:
    """One message an FMU sent to the logger callback: the FMU's name, the status and the text."""

    fmu: str
    status: str
    message: str


@dataclass
class CosimulationResult:
    """A finished run: ``result`` (structured array of dtype ``signals.DTYPE``, ``time`` in s first),
    ``steps`` (communication steps), ``wall_time`` (s, from loading the FMUs to freeing them),
    ``settings`` (scenario name and simulation settings), ``log`` (the FMUs' log messages) and
    ``fmus`` (each FMU's path and build id)."""

    result: np.ndarray
    steps: int
    wall_time: float
    settings: dict
    log: list[LogMessage] = field(default_factory=list)
    fmus: dict = field(default_factory=dict)


class CosimulationError(RuntimeError):
    """A run that diverged or in which an FMU failed; carries the time (s), the signal, its value and
    the rows recorded before the failure (``result``)."""

    def __init__(self, message: str, time: float, signal: str | None = None, value: float | None = None):
        super().__init__(message)
        self.time, self.signal, self.value = time, signal, value
        self.result: np.ndarray | None = None


def step_count(stop_time: float, step_size: float) -> int:
    """Number of communication steps: ``ceil(stop_time / step_size)``, a ratio within 1e-9 (relative)
    of a whole number counting as that number."""
    ratio = stop_time / step_size
    nearest = round(ratio)
    return max(1, nearest if abs(ratio - nearest) <= 1e-9 * ratio else math.ceil(ratio))


def _callbacks(log: list[LogMessage]) -> fmi2CallbackFunctions:
    """FMI callbacks whose logger appends every message to ``log``."""

    def logger(component, instance, status, category, message):
        text = [(b or b"").decode(errors="replace") for b in (instance, message)]
        log.append(LogMessage(text[0], _STATUS[status] if 0 <= status < len(_STATUS) else str(status), text[1]))

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    # No fmpy.logging.addLoggerProxy: it routes every proxied instance in the process to the last
    # logger registered, which dangles once this run's callbacks are gone. pythonfmu passes
    # formatted messages, so the variadic arguments are not needed.
    return callbacks


class _Fmu:
    """One loaded FMU: its instance and the value references and types of its variables by name."""

    def __init__(self, name: str, workdir: Path | None):
        self.name = name
        self.initialised = False
        self.slave = None
        self.folder = tempfile.mkdtemp(prefix=f"dsc_fmu_{name}_", dir=workdir)

    def load(self, path: Path, callbacks) -> None:
        """Read the model description, extract the FMU and instantiate it with ``callbacks``."""
        self.path = path
        try:
            md = read_model_description(str(path))
        except (ValidationError, BadZipFile) as error:
            raise CosimulationError(f"{path}: not a valid FMU for {self.name}: {error}", 0.0) from None
        extract(str(path), unzipdir=self.folder)
        self.variables = {v.name: v for v in md.modelVariables}
        self.outputs = [v.name for v in md.modelVariables if v.causality == "output"]
        self.inputs = [v.name for v in md.modelVariables if v.causality == "input"]
        slave = FMU2Slave(guid=md.guid, unzipDirectory=self.folder,
                          modelIdentifier=md.coSimulation.modelIdentifier, instanceName=self.name)
        slave.instantiate(callbacks=callbacks, loggingOn=True)
        self.slave = slave  # only an instantiated slave is freed

    def variable(self, name: str):
        """The model variable named ``name``; CosimulationError if this FMU has none (a wrong FMU file)."""
        if name not in self.variables:
            raise CosimulationError(f"{self.path}: {self.name} has no variable {name!r}: not the FMU expected", 0.0)
        return self.variables[name]

    def refs(self, names) -> list[int]:
        """Value references of the named variables, in order."""
        return [self.variable(name).valueReference for name in names]

    def initialise(self, stop_time: float, parameters: dict) -> None:
        """Set up the experiment on [0, stop_time] and set every parameter (Real or Integer)."""
        self.slave.setupExperiment(startTime=0.0, stopTime=stop_time)
        self.slave.enterInitializationMode()
        self.initialised = True
        integers = [name for name in parameters if self.variable(name).type == "Integer"]
        reals = [name for name in parameters if name not in integers]
        self.slave.setInteger(self.refs(integers), [int(parameters[name]) for name in integers])
        self.slave.setReal(self.refs(reals), [float(parameters[name]) for name in reals])
        self.slave.exitInitializationMode()

    def close(self) -> None:
        """Terminate (if initialised) and free the instance, then remove the extracted folder."""
        try:
            if self.initialised:
                try:
                    self.slave.terminate()
                except FMICallException:
                    pass  # an FMU in an error state may refuse; freeing it still applies
            if self.slave is not None:
                self.slave.freeInstance()
        finally:
            shutil.rmtree(self.folder, ignore_errors=True)


def _failing_fmu(error: FMICallException, fmus: list[_Fmu]) -> str:
    """Name of the FMU whose call raised ``error``: the ``self`` of fmpy's frame that raised it."""
    slaves = {id(fmu.slave): fmu.name for fmu in fmus}
    for frame, _ in traceback.walk_tb(error.__traceback__):
        name = slaves.get(id(frame.f_locals.get("self")))
        if name is not None:
            return name
    return "an FMU"


def cosimulate(scenario: Scenario, fmu_paths: dict[str, Path], *, step_size: float | None = None,
               stop_time: float | None = None, order: str | None = None, output_interval: float | None = None,
               workdir: Path | None = None) -> CosimulationResult:
    """Co-simulate ``scenario`` with the FMUs in ``fmu_paths`` (by name) on a fixed communication step.

    Settings left as None come from ``scenario.simulation``; the others are validated like the
    scenario's (ScenarioError). Communication points are ``t_k = k h`` (s) for ``k < n`` with
    ``n = step_count(stop_time, h)``, and ``t_n = stop_time``: the last step is shorter when
    ``stop_time`` is not a multiple of ``h``.

    At every communication point ``t_k`` the controller's inputs are set from the plant's and the
    reference's outputs of the same names, then ``u1, u2`` are read from the controller (direct
    feedthrough) and set on the plant. Then

    - Jacobi: all three FMUs ``doStep(t_k, h)`` with those inputs;
    - Gauss-Seidel: ReferenceRobot and MobileRobot ``doStep(t_k, h)`` first; then the controller's
      inputs are set from their new outputs (at ``t_{k+1}``) and the controller does
      ``doStep(t_k, h)``, so that its states integrate with the measurements of the end of the step.
      (Those inputs are already in place at the exchange at ``t_{k+1}``, so it does not set them again.)

    Rows are recorded at ``t = 0``, every ``max(1, round(output_interval / h))`` steps and at
    ``stop_time``, each after the exchange at that point: every output in ``signals.RECORDED``,
    then the tracking errors. After each exchange every measurement and ``u`` must be finite and
    within ``scenario.simulation.bound``, else CosimulationError; a failing FMI call also raises
    CosimulationError, with the FMU's last log messages. FMUs are extracted into temporary folders
    (inside ``workdir`` if given), and every instance is freed and every folder removed at the end.
    """
    scenario = scenario.with_simulation(step_size=step_size, stop_time=stop_time, order=order,
                                        output_interval=output_interval)
    paths = {name: Path(fmu_paths.get(name, f"{name}.fmu")) for name in (REFERENCE, PLANT, CONTROLLER)}
    for name, path in paths.items():
        if name not in fmu_paths or not path.is_file():
            raise FileNotFoundError(f"{path}: {name} FMU not found; build it with dsc_fmu.build.build_fmus")
    settings = scenario.simulation
    h, stop, bound = settings.step_size, settings.stop_time, settings.bound
    jacobi = settings.order == "jacobi"
    n = step_count(stop, h)
    every = max(1, round(settings.output_interval / h))
    log: list[LogMessage] = []
    callbacks = _callbacks(log)
    fmus: list[_Fmu] = []
    columns = ["time", *(name for names in signals.RECORDED.values() for name in names)]
    table = np.full((n // every + 1 + (n % every != 0), len(columns)), np.nan)
    row, t = 0, 0.0
    started = clock.perf_counter()
    try:
        for name in (REFERENCE, PLANT, CONTROLLER):
            fmus.append(_Fmu(name, workdir))
            fmus[-1].load(paths[name], callbacks)
        for fmu in fmus:
            fmu.initialise(stop, scenario.parameters(fmu.name))
        ref, plant, ctl = fmus
        ref_slave, plant_slave, ctl_slave = ref.slave, plant.slave, ctl.slave
        measured_plant = [name for name in ctl.inputs if name in plant.outputs]
        measured_ref = [name for name in ctl.inputs if name not in plant.outputs]
        plant_out, ref_out = plant.refs(measured_plant), ref.refs(measured_ref)
        ctl_in = ctl.refs(measured_plant + measured_ref)
        ctl_u, plant_u = ctl.refs(["u1", "u2"]), plant.refs(["u1", "u2"])
        checked = [f"{PLANT}.{s}" for s in measured_plant] + [f"{REFERENCE}.{s}" for s in measured_ref]
        readers, offset = [], 1  # (get, value references, table columns) of every recorded output
        for fmu in fmus:
            names = signals.RECORDED[fmu.name]
            for kind, get in (("Real", fmu.slave.getReal), ("Integer", fmu.slave.getInteger)):
                chosen = [i for i, name in enumerate(names) if fmu.variable(name).type == kind]
                readers.append((get, fmu.refs([names[i] for i in chosen]), [offset + i for i in chosen]))
            offset += len(names)

        def check(values, names, at):
            for name, value in zip(names, values):
                if not -bound <= value <= bound:
                    reason = "is not finite" if not math.isfinite(value) else f"exceeds the bound {bound:g}"
                    raise CosimulationError(f"diverged at t = {at:.6g} s: {name} = {value:.6g} {reason}",
                                            at, name, value)

        def exchange(at, measurements, set_inputs):
            if set_inputs:
                ctl_slave.setReal(ctl_in, measurements)
            u = ctl_slave.getReal(ctl_u)
            check(u, (f"{CONTROLLER}.u1", f"{CONTROLLER}.u2"), at)
            plant_slave.setReal(plant_u, u)

        def record(at):
            nonlocal row
            table[row, 0] = at
            for get, refs, cols in readers:
                if refs:
                    table[row, cols] = get(refs)
            row += 1

        measurements = plant_slave.getReal(plant_out) + ref_slave.getReal(ref_out)
        check(measurements, checked, t)
        for k in range(n):
            t = k * h
            exchange(t, measurements, jacobi or k == 0)
            if k % every == 0:
                record(t)
            step = h if k < n - 1 else stop - t
            ref_slave.doStep(t, step)
            plant_slave.doStep(t, step)
            measurements = plant_slave.getReal(plant_out) + ref_slave.getReal(ref_out)
            check(measurements, checked, stop if k == n - 1 else (k + 1) * h)
            if not jacobi:
                ctl_slave.setReal(ctl_in, measurements)
            ctl_slave.doStep(t, step)
        t = stop
        exchange(t, measurements, jacobi)
        record(t)
    except CosimulationError as error:
        error.result = _result(table[:row], columns)
        raise
    except FMICallException as error:
        name = _failing_fmu(error, fmus)
        messages = "; ".join([f"[{m.status}] {m.message}" for m in log if m.fmu == name][-3:]) or "none"
        failure = CosimulationError(f"{name} failed at t = {t:.6g} s: {error} Its last log messages: {messages}", t)
        failure.result = _result(table[:row], columns)
        raise failure from None
    finally:
        for fmu in reversed(fmus):
            fmu.close()
    return CosimulationResult(
        result=_result(table, columns),
        steps=n,
        wall_time=clock.perf_counter() - started,
        settings={"scenario": scenario.name, "step_size": h, "order": settings.order, "stop_time": stop,
                  "output_interval": settings.output_interval},
        log=log,
        fmus={name: {"path": str(path), "build_id": fmu_build_id(path)} for name, path in paths.items()},
    )


def _result(table: np.ndarray, columns: list[str]) -> np.ndarray:
    """``table`` (columns named by ``columns``) as a ``signals.DTYPE`` array with the tracking errors."""
    result = np.zeros(len(table), dtype=signals.DTYPE)
    for index, name in enumerate(columns):
        result[name] = table[:, index]
    signals.add_tracking_errors(result)
    return result
