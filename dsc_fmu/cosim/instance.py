"""One FMU loaded for a master (FMI 2.0 or 3.0, co-simulation or model exchange, on fmpy): extracted,
instantiated, its variables by name, its log messages collected."""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from zipfile import BadZipFile

from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Model, FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.fmi2 import fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE
from fmpy.fmi3 import FMU3Model, FMU3Slave
from fmpy.model_description import ValidationError

from ..errors import CosimulationError

__all__ = ["LogMessage", "LoadedFmu", "logging_callbacks", "type_name"]

_STATUS = ("OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING")


@dataclass(frozen=True)
class LogMessage:
    """One message an FMU sent to the logger callback: the FMU's name, the status and the text."""

    fmu: str
    status: str
    message: str


def logging_callbacks(log: list[LogMessage]) -> fmi2CallbackFunctions:
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


class _Named:
    """An fmpy slave whose failing FMI calls name their FMU: the FMICallException gets ``fmu``."""

    fmu = "an FMU"

    def _call(self, fname: str, *args):
        try:
            return super()._call(fname, *args)
        except FMICallException as error:
            error.fmu = self.fmu
            raise


class FMU2SlaveNamed(_Named, FMU2Slave):
    """fmpy's FMU2Slave, naming its FMU in a failing call (fmpy reads the FMI version from the class
    name's start)."""


class _Fmi2Names(_Named):
    """An fmpy FMI 3.0 instance under the FMI 2.0 names the masters call: Real is Float64, Integer is
    Int32; ``setupExperiment`` keeps the times that FMI 3.0 passes to ``enterInitializationMode``; a
    failing call names its FMU."""

    _experiment = (0.0, None)

    def getReal(self, vr):
        return self.getFloat64(vr)

    def setReal(self, vr, values):
        self.setFloat64(vr, values)

    def getInteger(self, vr):
        return self.getInt32(vr)

    def setInteger(self, vr, values):
        self.setInt32(vr, values)

    def setupExperiment(self, startTime: float = 0.0, stopTime: float | None = None) -> None:
        self._experiment = (startTime, stopTime)

    def enterInitializationMode(self) -> None:
        start, stop = self._experiment
        super().enterInitializationMode(startTime=start, stopTime=stop)


class FMU3SlaveNamed(_Fmi2Names, FMU3Slave):
    """fmpy's FMU3Slave under the FMI 2.0 names (fmpy reads the FMI version from the class name's start)."""

    def doStep(self, currentCommunicationPoint: float, communicationStepSize: float) -> None:
        super().doStep(currentCommunicationPoint, communicationStepSize)


class FMU2ModelNamed(_Named, FMU2Model):
    """fmpy's FMU2Model (model exchange), naming its FMU in a failing call."""


class FMU3ModelNamed(_Fmi2Names, FMU3Model):
    """fmpy's FMU3Model under the FMI 2.0 names, model exchange's included."""

    def getDerivatives(self, dx, nx):
        self.getContinuousStateDerivatives(dx, nx)

    def newDiscreteStates(self):
        return self.updateDiscreteStates()


_KINDS = {"Float64": "Real", "Int32": "Integer"}  # FMI 3.0 types under the FMI 2.0 names


def type_name(variable) -> str:
    """The FMI 2.0 type name of ``variable`` (``Real``, ``Integer``, ...), for either FMI version."""
    return _KINDS.get(variable.type, variable.type)


def _fmi3_logger(log: list[LogMessage], name: str):
    """An FMI 3.0 logMessage callback appending to ``log`` as FMU ``name`` (FMI 3.0 passes no instance name)."""

    def logger(environment, status, category, message):
        text = (message or b"").decode(errors="replace")
        log.append(LogMessage(name, _STATUS[status] if 0 <= status < len(_STATUS) else str(status), text))

    return logger


_CLASSES = {(2, False): FMU2SlaveNamed, (3, False): FMU3SlaveNamed, (2, True): FMU2ModelNamed,
            (3, True): FMU3ModelNamed}


class LoadedFmu:
    """One loaded FMU (FMI 2.0 or 3.0; co-simulation, or with ``model_exchange`` model exchange): its instance
    and the value references and types of its variables by name."""

    def __init__(self, name: str, workdir: Path | None, log: list[LogMessage] | None = None, *,
                 model_exchange: bool = False):
        self.name = name
        self.model_exchange = model_exchange
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
        interface = md.modelExchange if self.model_exchange else md.coSimulation
        if interface is None:
            kind = "model exchange" if self.model_exchange else "co-simulation"
            raise CosimulationError(f"{path}: {self.name} does not offer {kind}; build it with `dsc-fmu build`", 0.0)
        self.guid, self.model_identifier = md.guid, interface.modelIdentifier
        self.states = len(md.derivatives)
        self.indicators = md.numberOfEventIndicators or 0
        self.fmi_version = 3 if md.fmiVersion.startswith("3") else 2
        self.variables = {v.name: v for v in md.modelVariables}
        self.outputs = [v.name for v in md.modelVariables if v.causality == "output"]
        self.inputs = [v.name for v in md.modelVariables if v.causality == "input"]
        self.instantiate(callbacks)

    def instantiate(self, callbacks) -> None:
        """Instantiate the extracted FMU with ``callbacks`` (a fresh instance, not yet used); an FMI 3.0
        FMU logs through its own callback instead, into the same log."""
        kind = _CLASSES[self.fmi_version, self.model_exchange]
        slave = kind(guid=self.guid, unzipDirectory=self.folder, modelIdentifier=self.model_identifier,
                     instanceName=self.name)
        if self.fmi_version == 3:
            slave.instantiate(loggingOn=True, logMessage=_fmi3_logger(self.log, self.name))
        else:
            slave.instantiate(callbacks=callbacks, loggingOn=True)
        slave.fmu = self.name
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
        integers = [name for name in values if type_name(self.variable(name)) == "Integer"]
        reals = [name for name in values if name not in integers]
        if integers:
            self.slave.setInteger(self.refs(integers), [int(values[name]) for name in integers])
        if reals:
            self.slave.setReal(self.refs(reals), [float(values[name]) for name in reals])

    def get_values(self, names) -> dict:
        """Real and Integer variables by name (others among ``names`` are left out)."""
        values = {}
        for kind, getter in (("Real", self.slave.getReal), ("Integer", self.slave.getInteger)):
            chosen = [name for name in names if type_name(self.variable(name)) == kind]
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
