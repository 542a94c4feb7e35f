"""The co-simulation master: the three FMUs (FMI 2.0 or 3.0) on fmpy, a fixed communication step, Gauss-Seidel or Jacobi."""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import time as clock
import traceback
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from zipfile import BadZipFile

import numpy as np
from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.fmi2 import fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE
from fmpy.fmi3 import FMU3Slave
from fmpy.model_description import ValidationError

from . import signals
from ..build.fmus import fmu_build_id
from ..errors import DscFmuError
from ..registry import CONTROLLER, ORDER, PLANT, REFERENCE, fmu_files
from ..scenario import Scenario

__all__ = ["CosimulationError", "CosimulationResult", "Cosimulator", "LogMessage", "cosimulate", "step_count"]

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


class CosimulationError(DscFmuError, RuntimeError):
    """A run that diverged or in which an FMU failed; carries the time (s), the signal, its value,
    the rows recorded before the failure (``result``), the communication steps completed
    (``steps``) and, for a failing FMI call, the FMU's name (``fmu``)."""

    def __init__(self, message: str, time: float, signal: str | None = None, value: float | None = None):
        super().__init__(message)
        self.time, self.signal, self.value = time, signal, value
        self.result: np.ndarray | None = None
        self.steps: int | None = None  # communication steps completed before the failure
        self.fmu: str | None = None  # the FMU whose FMI call failed, if one did

    def __reduce__(self):  # picklable with its attributes, to cross from a worker process
        return type(self), (str(self), self.time, self.signal, self.value), self.__dict__


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


class _Fmi3Slave(FMU3Slave):
    """fmpy's FMU3Slave under the FMI 2.0 names the master calls: Real is Float64, Integer is Int32;
    ``setupExperiment`` keeps the times that FMI 3.0 passes to ``enterInitializationMode``."""

    getReal = FMU3Slave.getFloat64
    setReal = FMU3Slave.setFloat64
    getInteger = FMU3Slave.getInt32
    setInteger = FMU3Slave.setInt32
    _experiment = (0.0, None)

    def setupExperiment(self, startTime: float = 0.0, stopTime: float | None = None) -> None:
        self._experiment = (startTime, stopTime)

    def enterInitializationMode(self) -> None:
        start, stop = self._experiment
        super().enterInitializationMode(startTime=start, stopTime=stop)

    def doStep(self, currentCommunicationPoint: float, communicationStepSize: float) -> None:
        super().doStep(currentCommunicationPoint, communicationStepSize)


_KINDS = {"Float64": "Real", "Int32": "Integer"}  # FMI 3.0 types under the FMI 2.0 names


def _kind(variable) -> str:
    """The FMI 2.0 type name of ``variable`` (``Real``, ``Integer``, ...), for either FMI version."""
    return _KINDS.get(variable.type, variable.type)


def _fmi3_logger(log: list[LogMessage], name: str):
    """An FMI 3.0 logMessage callback appending to ``log`` as FMU ``name`` (FMI 3.0 passes no instance name)."""

    def logger(environment, status, category, message):
        text = (message or b"").decode(errors="replace")
        log.append(LogMessage(name, _STATUS[status] if 0 <= status < len(_STATUS) else str(status), text))

    return logger


class _Fmu:
    """One loaded FMU (FMI 2.0 or 3.0): its instance and the value references and types of its variables by name."""

    def __init__(self, name: str, workdir: Path | None, log: list[LogMessage] | None = None):
        self.name = name
        self.log = log if log is not None else []
        self.initialised = False
        self.slave = None
        self.folder = os.path.abspath(tempfile.mkdtemp(prefix=f"dsc_fmu_{name}_", dir=workdir))  # a file URI needs it

    def load(self, path: Path, callbacks) -> None:
        """Read the model description, extract the FMU and instantiate it with ``callbacks``."""
        self.path = path
        try:
            md = read_model_description(str(path))
        except (ValidationError, BadZipFile) as error:
            raise CosimulationError(f"{path}: not a valid FMU for {self.name}: {error}", 0.0) from None
        extract(str(path), unzipdir=self.folder)
        self.guid, self.model_identifier = md.guid, md.coSimulation.modelIdentifier
        self.fmi_version = 3 if md.fmiVersion.startswith("3") else 2
        self.variables = {v.name: v for v in md.modelVariables}
        self.outputs = [v.name for v in md.modelVariables if v.causality == "output"]
        self.inputs = [v.name for v in md.modelVariables if v.causality == "input"]
        self.instantiate(callbacks)

    def instantiate(self, callbacks) -> None:
        """Instantiate the extracted FMU with ``callbacks`` (a fresh instance, not yet used); an FMI 3.0
        FMU logs through its own callback instead, into the same log."""
        if self.fmi_version == 3:
            slave = _Fmi3Slave(guid=self.guid, unzipDirectory=self.folder,
                               modelIdentifier=self.model_identifier, instanceName=self.name)
            slave.instantiate(loggingOn=True, logMessage=_fmi3_logger(self.log, self.name))
        else:
            slave = FMU2Slave(guid=self.guid, unzipDirectory=self.folder,
                              modelIdentifier=self.model_identifier, instanceName=self.name)
            slave.instantiate(callbacks=callbacks, loggingOn=True)
        self.slave = slave  # only an instantiated slave is freed
        self.used = False

    def renew(self, callbacks) -> None:
        """Bring a used instance back to its state after instantiation: fmiReset, or, if the reset
        fails, free the instance and instantiate it again from the same folder."""
        if not self.used:
            return
        self.terminate()
        try:
            self.slave.reset()
            self.used = False
        except Exception:  # noqa: BLE001 - an instance that cannot be reset is replaced whatever the reason
            self.free()
            self.instantiate(callbacks)

    def variable(self, name: str):
        """The model variable named ``name``; CosimulationError if this FMU has none (a wrong FMU file)."""
        if name not in self.variables:
            raise CosimulationError(f"{self.path}: {self.name} has no variable {name!r}: not the FMU expected", 0.0)
        return self.variables[name]

    def refs(self, names) -> list[int]:
        """Value references of the named variables, in order."""
        return [self.variable(name).valueReference for name in names]

    def initialise(self, stop_time: float, parameters: dict) -> None:
        """Set up the experiment on [0, stop_time], set every parameter (Real or Integer) in
        initialisation mode and leave it."""
        self.enter_initialization(stop_time, parameters)
        self.slave.exitInitializationMode()

    def enter_initialization(self, stop_time: float | None, parameters: dict, *, set_first: bool = False) -> None:
        """Set up the experiment on [0, stop_time] (None: no stop time), enter initialisation mode and
        set ``parameters``: in it, or before it with ``set_first`` (as some masters do)."""
        self.used = True
        self.slave.setupExperiment(startTime=0.0, stopTime=stop_time)
        if set_first:
            self.set_values(parameters)
        self.slave.enterInitializationMode()
        self.initialised = True
        if not set_first:
            self.set_values(parameters)

    def set_values(self, values: dict) -> None:
        """Set Real and Integer variables by name."""
        integers = [name for name in values if _kind(self.variable(name)) == "Integer"]
        reals = [name for name in values if name not in integers]
        if integers:
            self.slave.setInteger(self.refs(integers), [int(values[name]) for name in integers])
        if reals:
            self.slave.setReal(self.refs(reals), [float(values[name]) for name in reals])

    def get_values(self, names) -> dict:
        """Real and Integer variables by name (others among ``names`` are left out)."""
        values = {}
        for kind, getter in (("Real", self.slave.getReal), ("Integer", self.slave.getInteger)):
            chosen = [name for name in names if _kind(self.variable(name)) == kind]
            if chosen:
                values.update(zip(chosen, getter(self.refs(chosen))))
        return values

    def terminate(self) -> None:
        """fmiTerminate if initialised; an FMU in an error state may refuse, which is ignored."""
        if self.initialised:
            self.initialised = False
            try:
                self.slave.terminate()
            except FMICallException:
                pass  # freeing or resetting it still applies

    def free(self) -> None:
        """Free the instance (and unload its library), if there is one."""
        slave, self.slave = self.slave, None
        if slave is not None:
            slave.freeInstance()

    def close(self) -> None:
        """Terminate (if initialised) and free the instance, then remove the extracted folder."""
        try:
            self.terminate()
            self.free()
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


class Cosimulator:
    """The three FMUs loaded once (extracted into ``workdir`` and instantiated) for many runs.

    Each FMU may be FMI 2.0 or 3.0 co-simulation (read from its model description; fmpy's
    FMU2Slave or FMU3Slave), with the same variable names; the runs are the same either way.

    ``run`` co-simulates a scenario as ``cosimulate`` does, bit for bit; between runs the instances
    are reset (``fmi2Reset`` / ``fmi3Reset``) instead of extracted again, and an instance that cannot be reset is
    freed and instantiated anew. ``close`` (or leaving the ``with`` block) frees every instance and
    removes the extracted folders. One Cosimulator serves one thread at a time.
    """

    def __init__(self, fmu_paths: dict[str, Path], workdir: Path | None = None):
        paths = fmu_files(fmu_paths)
        self.paths = paths
        self.fmus = {name: {"path": str(path), "build_id": fmu_build_id(path)} for name, path in paths.items()}
        self.runs = 0
        self.log: list[LogMessage] = []
        self._callbacks = _callbacks(self.log)
        self._loaded: list[_Fmu] = []
        self._finalizer = weakref.finalize(self, _close_all, self._loaded)
        try:
            for name in ORDER:
                self._loaded.append(_Fmu(name, workdir, self.log))
                self._loaded[-1].load(paths[name], self._callbacks)
            self._wire()
        except BaseException:
            self.close()
            raise

    def _wire(self) -> None:
        """Look up, once, the value references the exchange and the recording use."""
        for fmu in self._loaded:  # each FMU has the outputs recorded from it: a wrong file fails here
            fmu.refs(signals.RECORDED[fmu.name])
        ref, plant, ctl = self._loaded
        self.measured_plant = [name for name in ctl.inputs if name in plant.outputs]
        self.measured_ref = [name for name in ctl.inputs if name not in plant.outputs]
        self.plant_out, self.ref_out = plant.refs(self.measured_plant), ref.refs(self.measured_ref)
        self.ctl_in = ctl.refs(self.measured_plant + self.measured_ref)
        self.ctl_u, self.plant_u = ctl.refs(["u1", "u2"]), plant.refs(["u1", "u2"])
        self.checked = [f"{PLANT}.{s}" for s in self.measured_plant] + [f"{REFERENCE}.{s}" for s in self.measured_ref]
        self.columns = ["time", *(name for names in signals.RECORDED.values() for name in names)]
        self.readers, offset = [], 1  # (FMU index, kind, value references, table columns) of every recorded output
        for index, fmu in enumerate(self._loaded):
            names = signals.RECORDED[fmu.name]
            for kind in ("Real", "Integer"):
                chosen = [i for i, name in enumerate(names) if _kind(fmu.variable(name)) == kind]
                self.readers.append((index, kind, fmu.refs([names[i] for i in chosen]), [offset + i for i in chosen]))
            offset += len(names)

    def __enter__(self) -> Cosimulator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Terminate and free every instance and remove the extracted folders (idempotent)."""
        self._finalizer()

    def _prepare(self) -> None:
        """Bring every instance back to the state after instantiation: fmi2Reset, or free and
        instantiate anew if the reset fails."""
        if not self._finalizer.alive:
            raise RuntimeError("this Cosimulator is closed")
        for fmu in self._loaded:
            fmu.renew(self._callbacks)

    def run(self, scenario: Scenario, *, step_size: float | None = None, stop_time: float | None = None,
            order: str | None = None, output_interval: float | None = None) -> CosimulationResult:
        """Co-simulate ``scenario`` as ``cosimulate`` does (same settings, result, errors);
        ``wall_time`` counts this run only (not loading the FMUs)."""
        scenario = scenario.with_simulation(step_size=step_size, stop_time=stop_time, order=order,
                                            output_interval=output_interval)
        settings = scenario.simulation
        h, stop, bound = settings.step_size, settings.stop_time, settings.bound
        jacobi = settings.order == "jacobi"
        n = step_count(stop, h)
        every = max(1, round(settings.output_interval / h))
        started = clock.perf_counter()
        self._prepare()
        self.runs += 1
        self.log.clear()
        fmus = self._loaded
        columns = self.columns
        table = np.full((n // every + 1 + (n % every != 0), len(columns)), np.nan)
        row, t, k = 0, 0.0, 0
        try:
            for fmu in fmus:
                fmu.initialise(stop, scenario.parameters(fmu.name))
            ref_slave, plant_slave, ctl_slave = (fmu.slave for fmu in fmus)
            plant_out, ref_out, ctl_in = self.plant_out, self.ref_out, self.ctl_in
            ctl_u, plant_u, checked = self.ctl_u, self.plant_u, self.checked
            readers = [((fmus[i].slave.getReal if kind == "Real" else fmus[i].slave.getInteger), refs, cols)
                       for i, kind, refs, cols in self.readers]

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
            k, t = n, stop
            exchange(t, measurements, jacobi)
            record(t)
        except CosimulationError as error:
            error.result, error.steps = _result(table[:row], columns), k
            raise
        except FMICallException as error:
            name = _failing_fmu(error, fmus)
            messages = "; ".join([f"[{m.status}] {m.message}" for m in self.log if m.fmu == name][-3:]) or "none"
            failure = CosimulationError(f"{name} failed at t = {t:.6g} s: {error} Its last log messages: {messages}", t)
            failure.result, failure.steps, failure.fmu = _result(table[:row], columns), k, name
            raise failure from None
        finally:
            for fmu in reversed(fmus):
                fmu.terminate()
        return CosimulationResult(
            result=_result(table, columns),
            steps=n,
            wall_time=clock.perf_counter() - started,
            settings={"scenario": scenario.name, "step_size": h, "order": settings.order, "stop_time": stop,
                      "output_interval": settings.output_interval},
            log=list(self.log),
            fmus={name: dict(entry) for name, entry in self.fmus.items()},
        )


def _close_all(fmus: list[_Fmu]) -> None:
    """Close every FMU of ``fmus`` (last loaded first), removing all folders even if one fails."""
    try:
        while fmus:
            fmus.pop().close()
    finally:
        for fmu in fmus:
            shutil.rmtree(fmu.folder, ignore_errors=True)


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
    For many runs, load the FMUs once with ``Cosimulator`` instead: its runs give the same results.
    """
    scenario = scenario.with_simulation(step_size=step_size, stop_time=stop_time, order=order,
                                        output_interval=output_interval)
    started = clock.perf_counter()
    with Cosimulator(fmu_paths, workdir) as simulator:
        run = simulator.run(scenario)
    run.wall_time = clock.perf_counter() - started
    return run


def _result(table: np.ndarray, columns: list[str]) -> np.ndarray:
    """``table`` (columns named by ``columns``) as a ``signals.DTYPE`` array with the tracking errors."""
    result = np.zeros(len(table), dtype=signals.DTYPE)
    for index, name in enumerate(columns):
        result[name] = table[:, index]
    signals.add_tracking_errors(result)
    return result
