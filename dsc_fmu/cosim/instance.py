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
from ..platforms import library_path

__all__ = ["LogMessage", "LoadedFmu", "failed_call", "logging_callbacks", "type_name"]

_STATUS = ("OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING")


@dataclass(frozen=True)
class LogMessage:
    """One message an FMU sent to the logger callback.

    Parameters
    ----------
    fmu : str
        The FMU's instance name.
    status : str
        ``OK``, ``WARNING``, ``DISCARD``, ``ERROR``, ``FATAL`` or ``PENDING``.
    message : str
        The text.
    """

    fmu: str
    status: str
    message: str


def logging_callbacks(log: list[LogMessage]) -> fmi2CallbackFunctions:
    """FMI 2.0 callbacks whose logger appends every message to ``log``.

    Parameters
    ----------
    log : list of LogMessage
        Where the messages go.

    Returns
    -------
    fmpy.fmi2.fmi2CallbackFunctions
        Keep it alive as long as an instance uses it.
    """

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


def failed_call(error: FMICallException, log: list[LogMessage], at: float) -> CosimulationError:
    """The CosimulationError of a failing FMI call at ``at`` (s), naming the FMU that made it.

    Parameters
    ----------
    error : fmpy.fmi1.FMICallException
        The failing call, as a ``LoadedFmu``'s instance raises it (its ``fmu`` names the FMU).
    log : list of LogMessage
        The run's log messages; the FMU's last three go into the message.
    at : float
        Time of the failure in s.

    Returns
    -------
    CosimulationError
        Its message names the FMU, the time and the FMU's last log messages; ``fmu`` is the FMU's name.
    """
    name = getattr(error, "fmu", "an FMU")
    messages = "; ".join([f"[{m.status}] {m.message}" for m in log if m.fmu == name][-3:]) or "none"
    failure = CosimulationError(f"{name} failed at t = {at:.6g} s: {error} Its last log messages: {messages}", at)
    failure.fmu = name
    return failure


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
    """The FMI 2.0 type name of a model variable of either FMI version.

    Parameters
    ----------
    variable : fmpy.model_description.ScalarVariable
        The variable.

    Returns
    -------
    str
        ``Real``, ``Integer``, ...: FMI 3.0's ``Float64`` and ``Int32`` under their FMI 2.0 names.
    """
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
    """One loaded FMU: its instance and its variables by name.

    FMI 2.0 or 3.0 (read from its model description), co-simulation or model exchange, on fmpy.

    Parameters
    ----------
    name : str
        The FMU's name, also its instance name.
    workdir : pathlib.Path or None
        Where its extraction folder is made; None: the system's temporary folder.
    log : list of LogMessage, optional
        Where an FMI 3.0 instance's messages go (FMI 2.0 ones go through the callbacks given).
    model_exchange : bool, optional
        Model exchange instead of co-simulation. Default False.
    """

    def __init__(self, name: str, workdir: Path | None, log: list[LogMessage] | None = None, *,
                 model_exchange: bool = False):
        self.name = name
        self.model_exchange = model_exchange
        self.log = log if log is not None else []
        self.initialised = False
        self.slave = None
        self.folder = os.path.abspath(tempfile.mkdtemp(prefix=f"dsc_fmu_{name}_", dir=workdir))  # a file URI needs it

    def load(self, path: Path, callbacks) -> None:
        """Read the model description, extract the FMU and instantiate it.

        Parameters
        ----------
        path : pathlib.Path
            The FMU file.
        callbacks : fmpy.fmi2.fmi2CallbackFunctions
            The logger and memory callbacks (``logging_callbacks``).

        Raises
        ------
        CosimulationError
            If the file is not a valid FMU or lacks the interface asked for.
        """
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
        real = lambda names: [name for name in names if type_name(self.variables[name]) == "Real"]  # noqa: E731
        self.real_outputs, self.real_inputs = real(self.outputs), real(self.inputs)
        self.state_names = [d.variable.derivative.name for d in md.derivatives]
        self.state_refs = [d.variable.derivative.valueReference for d in md.derivatives]
        self.derivative_refs = [d.variable.valueReference for d in md.derivatives]
        self.instantiate(callbacks)

    def instantiate(self, callbacks) -> None:
        """Instantiate the extracted FMU: a fresh instance, not yet used.

        Parameters
        ----------
        callbacks : fmpy.fmi2.fmi2CallbackFunctions
            The callbacks of an FMI 2.0 FMU; an FMI 3.0 FMU logs through its own callback instead,
            into the same log.
        """
        kind = _CLASSES[self.fmi_version, self.model_exchange]
        slave = kind(guid=self.guid, unzipDirectory=self.folder, modelIdentifier=self.model_identifier,
                     instanceName=self.name,
                     libraryPath=library_path(self.folder, self.fmi_version, self.model_identifier))
        if self.fmi_version == 3:
            slave.instantiate(loggingOn=True, logMessage=_fmi3_logger(self.log, self.name))
        else:
            slave.instantiate(callbacks=callbacks, loggingOn=True)
        slave.fmu = self.name
        self.slave = slave  # only an instantiated slave is freed
        self.used = False

    def renew(self, callbacks) -> None:
        """Bring a used instance back to its state after instantiation.

        fmiReset, or, if the reset fails, free the instance and instantiate it again from the same folder.

        Parameters
        ----------
        callbacks : fmpy.fmi2.fmi2CallbackFunctions
            For a new instance, as for ``instantiate``.
        """
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
        """The model variable of a name.

        Parameters
        ----------
        name : str
            The variable's name.

        Returns
        -------
        fmpy.model_description.ScalarVariable
            The variable.

        Raises
        ------
        CosimulationError
            If this FMU has none (a wrong FMU file).
        """
        if name not in self.variables:
            raise CosimulationError(f"{self.path}: {self.name} has no variable {name!r}: not the FMU expected", 0.0)
        return self.variables[name]

    def refs(self, names) -> list[int]:
        """Value references of named variables.

        Parameters
        ----------
        names : iterable of str
            The variables' names.

        Returns
        -------
        list of int
            Their value references, in order.
        """
        return [self.variable(name).valueReference for name in names]

    def initialise(self, stop_time: float, parameters: dict) -> None:
        """Initialise: set up the experiment, set the parameters in initialisation mode and leave it.

        Parameters
        ----------
        stop_time : float
            The experiment runs on [0, stop_time], in s.
        parameters : dict
            Values of Real or Integer variables by name.
        """
        self.enter_initialization(stop_time, parameters)
        self.slave.exitInitializationMode()

    def enter_initialization(self, stop_time: float | None, parameters: dict, *, set_first: bool = False) -> None:
        """Set up the experiment, enter initialisation mode and set the parameters.

        Parameters
        ----------
        stop_time : float or None
            The experiment runs on [0, stop_time], in s; None: no stop time.
        parameters : dict
            Values of Real or Integer variables by name.
        set_first : bool, optional
            Set them before initialisation mode instead of in it, as some masters do. Default False.
        """
        self.used = True
        self.slave.setupExperiment(startTime=0.0, stopTime=stop_time)
        if set_first:
            self.set_values(parameters)
        self.slave.enterInitializationMode()
        self.initialised = True
        if not set_first:
            self.set_values(parameters)

    def set_values(self, values: dict) -> None:
        """Set Real and Integer variables by name.

        Parameters
        ----------
        values : dict
            Values by variable name (Integer variables get ``int`` of theirs).
        """
        integers = [name for name in values if type_name(self.variable(name)) == "Integer"]
        reals = [name for name in values if name not in integers]
        if integers:
            self.slave.setInteger(self.refs(integers), [int(values[name]) for name in integers])
        if reals:
            self.slave.setReal(self.refs(reals), [float(values[name]) for name in reals])

    def get_values(self, names) -> dict:
        """Values of Real and Integer variables.

        Parameters
        ----------
        names : iterable of str
            The variables' names; those of other types are left out.

        Returns
        -------
        dict
            Values by name.
        """
        values = {}
        for kind, getter in (("Real", self.slave.getReal), ("Integer", self.slave.getInteger)):
            chosen = [name for name in names if type_name(self.variable(name)) == kind]
            if chosen:
                values.update(zip(chosen, getter(self.refs(chosen))))
        return values

    def terminate(self) -> None:
        """Terminate the instance if initialised; an FMU in an error state may refuse, which is ignored."""
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
