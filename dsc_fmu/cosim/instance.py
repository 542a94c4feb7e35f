"""One FMU loaded for a master on fmpy's own classes (FMI 2.0 or 3.0, co-simulation or model exchange):
extracted, instantiated, its variables by name, its log messages collected, a failing call naming it."""

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

__all__: list[str] = []  # the package's own: LoadedFmu, load_fmu, failed_call, logging_callbacks, ...

_STATUS = ("OK", "WARNING", "DISCARD", "ERROR", "FATAL", "PENDING")


@dataclass(frozen=True)
class LogMessage:
    """One message an FMU sent to the logger; ``status`` is ``OK``, ``WARNING``, ..., ``PENDING``."""

    fmu: str
    status: str
    message: str


def _status(status: int) -> str:
    return _STATUS[status] if 0 <= status < len(_STATUS) else str(status)


def logging_callbacks(log: list[LogMessage]) -> fmi2CallbackFunctions:
    """FMI 2.0 callbacks whose logger appends every message to ``log`` (keep them alive while an instance uses them)."""

    def logger(component, instance, status, category, message):
        text = [(b or b"").decode(errors="replace") for b in (instance, message)]
        log.append(LogMessage(text[0], _status(status), text[1]))

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    # No fmpy.logging.addLoggerProxy: it routes every proxied instance in the process to the last
    # logger registered, which dangles once this run's callbacks are gone. pythonfmu passes
    # formatted messages, so the variadic arguments are not needed.
    return callbacks


def failed_call(error: FMICallException, log: list[LogMessage], at: float) -> CosimulationError:
    """The CosimulationError of a failing FMI call at ``at`` (s): it names the FMU (``fmu``), the time
    and the FMU's last three log messages."""
    name = getattr(error, "fmu", "an FMU")
    messages = "; ".join([f"[{m.status}] {m.message}" for m in log if m.fmu == name][-3:]) or "none"
    failure = CosimulationError(f"{name} failed at t = {at:.6g} s: {error} Its last log messages: {messages}", at)
    failure.fmu = name
    return failure


_KINDS = {"Float64": "Real", "Int32": "Integer"}  # FMI 3.0 types under the FMI 2.0 names


def type_name(variable) -> str:
    """A variable's FMI 2.0 type name: FMI 3.0's ``Float64`` and ``Int32`` as ``Real`` and ``Integer``."""
    return _KINDS.get(variable.type, variable.type)


class LoadedFmu:
    """One loaded FMU (``load_fmu``): its fmpy instance (``instance``), its variables by name and the calls
    the masters make.

    The calls that FMI 2.0 and 3.0 name differently are this interface's methods: ``get_floats``, ...,
    ``update_discrete_states`` on fmpy's methods that ``Fmi2Fmu`` and ``Fmi3Fmu`` name (``_CALLS``), and
    ``setup_experiment`` and ``enter_initialization_mode`` written in each (FMI 3.0 has no setup call); the others are fmpy's own methods of ``instance``, made through ``call``. Every call that fails raises
    fmpy's ``FMICallException`` with ``fmu`` set to this FMU's name (``failed_call``).
    """

    fmi_version = 0
    _CLASSES: dict = {}  # model_exchange -> fmpy's class
    _CALLS: tuple = ()  # fmpy's methods behind get_floats, set_floats, ..., update_discrete_states, in that order

    def __init__(self, name: str, workdir: Path | None, log: list[LogMessage], model_exchange: bool):
        self.name, self.log, self.model_exchange = name, log, model_exchange
        self.initialised = False
        self.instance = None
        self.folder = os.path.abspath(tempfile.mkdtemp(prefix=f"dsc_fmu_{name}_", dir=workdir))  # a file URI needs it

    def _read(self, path: Path, md) -> None:
        """The model description's facts the masters use; the FMU extracted."""
        self.path = path
        extract(str(path), unzipdir=self.folder)
        interface = md.modelExchange if self.model_exchange else md.coSimulation
        if interface is None:
            kind = "model exchange" if self.model_exchange else "co-simulation"
            raise CosimulationError(f"{path}: {self.name} does not offer {kind}; build it with `dsc-fmu build`", 0.0)
        self.guid, self.model_identifier = md.guid, interface.modelIdentifier
        self.states = len(md.derivatives)
        self.indicators = md.numberOfEventIndicators or 0
        self.variables = {v.name: v for v in md.modelVariables}
        self.outputs = [v.name for v in md.modelVariables if v.causality == "output"]
        self.inputs = [v.name for v in md.modelVariables if v.causality == "input"]
        real = lambda names: [name for name in names if type_name(self.variables[name]) == "Real"]  # noqa: E731
        self.real_outputs, self.real_inputs = real(self.outputs), real(self.inputs)
        self.state_names = [d.variable.derivative.name for d in md.derivatives]
        self.state_refs = [d.variable.derivative.valueReference for d in md.derivatives]
        self.derivative_refs = [d.variable.valueReference for d in md.derivatives]

    def instantiate(self, callbacks: fmi2CallbackFunctions) -> None:
        """A fresh instance of the extracted FMU (an FMI 2.0 one logs through ``callbacks``)."""
        instance = self._CLASSES[self.model_exchange](
            guid=self.guid, unzipDirectory=self.folder, modelIdentifier=self.model_identifier, instanceName=self.name,
            libraryPath=library_path(self.folder, self.fmi_version, self.model_identifier))
        self.call(self._instantiate, instance, callbacks)
        self.instance = instance  # only an instantiated instance is freed
        (self._get_floats, self._set_floats, self._get_integers, self._set_integers, self._get_derivatives,
         self._update_discrete_states) = (getattr(instance, name, None) for name in self._CALLS)  # None: not offered
        self.used = False

    def call(self, function, *args):
        """``function(*args)``, a method of ``instance``; a failing call names this FMU (``failed_call``)."""
        try:
            return function(*args)
        except FMICallException as error:
            error.fmu = self.name
            raise

    def renew(self, callbacks: fmi2CallbackFunctions) -> None:
        """Back to its state after instantiation: fmiReset, else a new instance from the same folder."""
        if not self.used:
            return
        self.terminate()
        try:
            self.instance.reset()
            self.used = False
        except Exception:  # noqa: BLE001 - an instance that cannot be reset is replaced whatever the reason
            self.free()
            self.instantiate(callbacks)

    def variable(self, name: str):
        """The model variable of a name; CosimulationError if this FMU has none (a wrong FMU file)."""
        if name not in self.variables:
            raise CosimulationError(f"{self.path}: {self.name} has no variable {name!r}: not the FMU expected", 0.0)
        return self.variables[name]

    def refs(self, names) -> list[int]:
        return [self.variable(name).valueReference for name in names]

    def enter_initialization(self, stop_time: float | None, parameters: dict, *, set_first: bool = False) -> None:
        """Set up the experiment on [0, ``stop_time``] s (None: no stop time), enter initialisation mode and
        set the ``parameters`` (by name) in it, or before it with ``set_first`` as some masters do."""
        self.used = True
        self.setup_experiment(stop_time)
        if set_first:
            self.set_values(parameters)
        self.enter_initialization_mode()
        self.initialised = True
        if not set_first:
            self.set_values(parameters)

    def set_values(self, values: dict) -> None:
        """Set Real and Integer variables by name (Integer ones get ``int`` of theirs)."""
        integers = [name for name in values if type_name(self.variable(name)) == "Integer"]
        reals = [name for name in values if name not in integers]
        if integers:
            self.set_integers(self.refs(integers), [int(values[name]) for name in integers])
        if reals:
            self.set_floats(self.refs(reals), [float(values[name]) for name in reals])

    def get_values(self, names) -> dict:
        """The values of the Real and Integer variables among ``names``, by name."""
        values = {}
        for kind, getter in (("Real", self.get_floats), ("Integer", self.get_integers)):
            chosen = [name for name in names if type_name(self.variable(name)) == kind]
            if chosen:
                values.update(zip(chosen, getter(self.refs(chosen))))
        return values

    def do_step(self, t: float, step: float) -> None:
        """fmi2DoStep / fmi3DoStep from ``t`` over ``step`` (s)."""
        try:
            self.instance.doStep(t, step)
        except FMICallException as error:
            error.fmu = self.name
            raise

    def get_floats(self, refs: list[int]) -> list[float]:
        try:
            return self._get_floats(refs)
        except FMICallException as error:
            error.fmu = self.name
            raise

    def set_floats(self, refs: list[int], values) -> None:
        try:
            self._set_floats(refs, values)
        except FMICallException as error:
            error.fmu = self.name
            raise

    def get_integers(self, refs: list[int]) -> list[int]:
        return self.call(self._get_integers, refs)

    def set_integers(self, refs: list[int], values) -> None:
        self.call(self._set_integers, refs, values)

    def get_derivatives(self, buffer, n: int) -> None:
        self.call(self._get_derivatives, buffer, n)

    def update_discrete_states(self) -> tuple[bool, bool]:
        """Whether the FMU needs another call, whether a continuous state changed."""
        needed, _, _, changed, _, _ = self.call(self._update_discrete_states)
        return needed, changed

    def terminate(self) -> None:
        """Terminate the instance if initialised; an FMU in an error state may refuse, which is ignored."""
        if self.initialised:
            self.initialised = False
            try:
                self.instance.terminate()
            except FMICallException:
                pass  # freeing or resetting it still applies

    def free(self) -> None:
        instance, self.instance = self.instance, None
        if instance is not None:
            instance.freeInstance()

    def close(self) -> None:
        """Terminate (if initialised) and free the instance, then remove the extracted folder."""
        try:
            self.terminate()
            self.free()
        finally:
            shutil.rmtree(self.folder, ignore_errors=True)


class Fmi2Fmu(LoadedFmu):
    """An FMI 2.0 FMU on fmpy's ``FMU2Slave`` or ``FMU2Model``."""

    fmi_version = 2
    _CLASSES = {False: FMU2Slave, True: FMU2Model}
    # fmi2GetReal, fmi2SetReal, fmi2GetInteger, fmi2SetInteger, fmi2GetDerivatives, fmi2NewDiscreteStates
    _CALLS = ("getReal", "setReal", "getInteger", "setInteger", "getDerivatives", "newDiscreteStates")

    def _instantiate(self, instance, callbacks) -> None:
        instance.instantiate(callbacks=callbacks, loggingOn=True)

    def setup_experiment(self, stop_time: float | None) -> None:
        """fmi2SetupExperiment on [0, ``stop_time``] s."""
        self.call(self.instance.setupExperiment, None, 0.0, stop_time)

    def enter_initialization_mode(self) -> None:
        self.call(self.instance.enterInitializationMode)


class Fmi3Fmu(LoadedFmu):
    """An FMI 3.0 FMU on fmpy's ``FMU3Slave`` or ``FMU3Model`` (its messages logged under its name: FMI 3.0's
    logger gets no instance name)."""

    fmi_version = 3
    _CLASSES = {False: FMU3Slave, True: FMU3Model}
    # fmi3GetFloat64, fmi3SetFloat64, fmi3GetInt32, fmi3SetInt32, fmi3GetContinuousStateDerivatives,
    # fmi3UpdateDiscreteStates
    _CALLS = ("getFloat64", "setFloat64", "getInt32", "setInt32", "getContinuousStateDerivatives",
              "updateDiscreteStates")

    def _instantiate(self, instance, callbacks) -> None:
        def logger(environment, status, category, message):
            self.log.append(LogMessage(self.name, _status(status), (message or b"").decode(errors="replace")))

        instance.instantiate(loggingOn=True, logMessage=logger)

    def setup_experiment(self, stop_time: float | None) -> None:
        """Keep [0, ``stop_time``] s for fmi3EnterInitializationMode, which takes the experiment's times."""
        self._stop_time = stop_time

    def enter_initialization_mode(self) -> None:
        self.call(self.instance.enterInitializationMode, None, 0.0, self._stop_time)


def load_fmu(name: str, path: Path, workdir: Path | None, log: list[LogMessage], callbacks: fmi2CallbackFunctions,
             model_exchange: bool = False) -> LoadedFmu:
    """Read an FMU's model description, extract and instantiate it (``Fmi2Fmu`` or ``Fmi3Fmu``); its folder
    is removed if that fails. CosimulationError if the file is not a valid FMU or lacks the interface."""
    try:
        md = read_model_description(str(path))
    except (ValidationError, BadZipFile) as error:
        raise CosimulationError(f"{path}: not a valid FMU for {name}: {error}", 0.0) from None
    fmu = (Fmi3Fmu if md.fmiVersion.startswith("3") else Fmi2Fmu)(name, workdir, log, model_exchange)
    try:
        fmu._read(path, md)
        fmu.instantiate(callbacks)
    except BaseException:
        fmu.close()
        raise
    return fmu
