"""A minimal FMI 2.0 and FMI 3.0 driver (co-simulation; model exchange instantiated, its calls raw) on ctypes and the standard library only.

The isolation tests load it by file path inside a subprocess in which numpy, fmpy, scipy and
dsc_fmu cannot be imported (see ``isolation.py``), so it imports nothing outside the standard
library, not even the modules beside it.

It extracts an FMU with ``zipfile``, reads ``modelDescription.xml`` with ``xml.etree``, loads
``binaries/<platform>/<modelIdentifier>.<ext>`` and calls the FMI C API.
"""

from __future__ import annotations  # its annotations are read by CPython 3.9 too

import ctypes
import os
import platform
import sys
import zipfile
from ctypes import (
    CFUNCTYPE, POINTER, Structure, byref, c_bool, c_char_p, c_double, c_int, c_int32, c_size_t, c_uint32, c_void_p,
)
from pathlib import Path
from xml.etree import ElementTree

__all__ = ["FmiCallError", "Fmi2Slave", "Fmi3Slave", "extract"]

WARNING, FATAL = 1, 4  # the same statuses in FMI 2.0 and 3.0
EXTENSIONS = {"Linux": ".so", "Darwin": ".dylib", "Windows": ".dll"}
# fmi2ValueReference is an unsigned int, fmi3ValueReference a uint32_t: the same on these platforms.
ValueReferences = POINTER(c_uint32)


class FmiCallError(Exception):
    """An FMI function returned a status worse than a warning."""

    def __init__(self, function: str, status: int, labels: tuple):
        label = labels[status] if 0 <= status < len(labels) else "illegal"
        super().__init__(f"{function} returned status {status} ({label})")
        self.function = function
        self.status = status


def extract(fmu: Path, target: Path) -> Path:
    """Unzip ``fmu`` into ``target`` (created) and return it."""
    target = Path(target)
    target.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(fmu) as archive:
        archive.extractall(target)
    return target


def _system() -> str:
    system = platform.system()
    if system not in EXTENSIONS:
        raise OSError(f"unsupported platform {system}")
    return system


def _decode(text):
    return None if text is None else text.decode("utf-8", "replace")


class _Slave:
    """What an FMI 2.0 and an FMI 3.0 instance share: the model description, the library, the calls.

    ``variables`` maps each name to ``(valueReference, type, causality)`` from ``modelDescription.xml``.
    A subclass names its ``PREFIX``, ``STATUS_LABELS``, C ``SIGNATURES`` and ``GETTERS`` (the method
    that reads each output type), and defines ``_type`` (of a variable element) and ``_platform_folder``.
    """

    PREFIX: str
    STATUS_LABELS: tuple
    SIGNATURES: dict
    GETTERS: dict
    COUNTS_VALUES = False  # whether get and set functions take the number of values after the array

    def __init__(self, unzipped: Path, instance_name: str = "instance"):
        self.unzipped = Path(unzipped).resolve()
        self.description = ElementTree.parse(self.unzipped / "modelDescription.xml").getroot()
        self.model_identifier = self.description.find("CoSimulation").get("modelIdentifier")
        self.variables = {
            variable.get("name"): (int(variable.get("valueReference")), self._type(variable),
                                   variable.get("causality", "local"))
            for variable in self.description.find("ModelVariables")
        }
        system = _system()
        self.library_path = (self.unzipped / "binaries" / self._platform_folder(system)
                             / (self.model_identifier + EXTENSIONS[system]))
        self.dll = ctypes.CDLL(str(self.library_path))
        self._functions = {}
        for name, (restype, argtypes) in self.SIGNATURES.items():
            function = getattr(self.dll, name)
            function.restype = restype
            function.argtypes = argtypes
            self._functions[name] = function
        self.instance_name = instance_name
        self.messages = []
        self.instance = None

    def _call(self, name, *args):
        status = self._functions[name](self.instance, *args)
        if status > WARNING:
            raise FmiCallError(name, status, self.STATUS_LABELS)
        return status

    def _instantiate(self, function, *args):
        instance = self._functions[function](*args)
        if not instance:
            raise FmiCallError(function, FATAL, self.STATUS_LABELS)
        self.instance = instance

    def _transfer(self, function, kind, ctype, names, values=()) -> list:
        """Set the named variables of FMI type ``kind`` to ``values``, or get them (no values)."""
        refs = []
        for name in names:
            vr, tag, _ = self.variables[name]
            if tag != kind:
                raise TypeError(f"{name} is {tag}, not {kind}")
            refs.append(vr)
        array = (ctype * len(refs))(*values)
        counts = (len(refs),) if self.COUNTS_VALUES else ()
        self._call(function, (c_uint32 * len(refs))(*refs), len(refs), array, *counts)
        return list(array)

    def names(self, causality: str, kind: str) -> list:
        """Names of the variables of this causality and type, in the order of the model description."""
        return [name for name, (_, tag, role) in self.variables.items() if role == causality and tag == kind]

    def outputs(self) -> dict:
        """Every output by name: type by type as in ``GETTERS``, each in the model description's order."""
        row = {}
        for kind, getter in self.GETTERS.items():
            names = self.names("output", kind)
            if names:
                row.update(zip(names, getattr(self, getter)(names)))
        return row

    def exit_initialization_mode(self):
        return self._call(self.PREFIX + "ExitInitializationMode")

    def terminate(self):
        return self._call(self.PREFIX + "Terminate")

    def free_instance(self):
        if self.instance is not None:
            self._functions[self.PREFIX + "FreeInstance"](self.instance)
            self.instance = None


# --- FMI 2.0 ----------------------------------------------------------------------------------------

FMI2_MODEL_EXCHANGE, FMI2_CO_SIMULATION = 0, 1  # fmi2Type
# The logger is variadic in C; ctypes cannot receive the varargs, so they are ignored (the message
# is kept as its format string, which is what pythonfmu passes: a complete message without arguments).
LoggerType = CFUNCTYPE(None, c_void_p, c_char_p, c_int, c_char_p, c_char_p)
AllocateType = CFUNCTYPE(c_void_p, c_size_t, c_size_t)
FreeType = CFUNCTYPE(None, c_void_p)
StepFinishedType = CFUNCTYPE(None, c_void_p, c_int)


class CallbackFunctions(Structure):
    _fields_ = [
        ("logger", LoggerType),
        ("allocateMemory", AllocateType),
        ("freeMemory", FreeType),
        ("stepFinished", StepFinishedType),
        ("componentEnvironment", c_void_p),
    ]


class Fmi2Slave(_Slave):
    """One instance of an extracted FMI 2.0 FMU (co-simulation, or model exchange with ``instantiate``'s flag).

    ``messages`` collects ``(instance_name, status, category, message)`` from the FMU's logger.
    """

    PREFIX = "fmi2"
    STATUS_LABELS = ("ok", "warning", "discard", "error", "fatal", "pending")
    GETTERS = {"Real": "get_real", "Integer": "get_integer", "Boolean": "get_boolean"}
    SIGNATURES = {
        "fmi2Instantiate": (c_void_p, [c_char_p, c_int, c_char_p, c_char_p, POINTER(CallbackFunctions), c_int, c_int]),
        "fmi2FreeInstance": (None, [c_void_p]),
        "fmi2SetupExperiment": (c_int, [c_void_p, c_int, c_double, c_double, c_int, c_double]),
        "fmi2EnterInitializationMode": (c_int, [c_void_p]),
        "fmi2ExitInitializationMode": (c_int, [c_void_p]),
        "fmi2Terminate": (c_int, [c_void_p]),
        "fmi2GetReal": (c_int, [c_void_p, ValueReferences, c_size_t, POINTER(c_double)]),
        "fmi2SetReal": (c_int, [c_void_p, ValueReferences, c_size_t, POINTER(c_double)]),
        "fmi2GetInteger": (c_int, [c_void_p, ValueReferences, c_size_t, POINTER(c_int)]),
        "fmi2SetInteger": (c_int, [c_void_p, ValueReferences, c_size_t, POINTER(c_int)]),
        "fmi2GetBoolean": (c_int, [c_void_p, ValueReferences, c_size_t, POINTER(c_int)]),
        "fmi2DoStep": (c_int, [c_void_p, c_double, c_double, c_int]),
    }

    def __init__(self, unzipped: Path, instance_name: str = "instance"):
        super().__init__(unzipped, instance_name)
        # The structure holds its ctypes callbacks: it lives as long as the instance may call them.
        self._callbacks = CallbackFunctions(
            logger=LoggerType(self._log), allocateMemory=AllocateType(self._calloc),
            freeMemory=FreeType(self._free_memory), stepFinished=StepFinishedType(), componentEnvironment=None,
        )
        self._libc = None

    @staticmethod
    def _type(variable):
        return variable[0].tag  # a ScalarVariable holds one element named after its type

    @staticmethod
    def _platform_folder(system):
        if system == "Linux" and platform.machine().lower() in ("aarch64", "arm64"):
            return "aarch64-linux"  # FMI 2.0.4 names x86 folders only: FMI 3.0's tuple elsewhere
        bits = "64" if sys.maxsize > 2**32 else "32"
        return ("win" if system == "Windows" else system.lower()) + bits

    def _log(self, environment, instance_name, status, category, message):
        self.messages.append((_decode(instance_name), status, _decode(category), _decode(message)))

    def _c_runtime(self):
        # Only needed if the FMU uses the memory callbacks (pythonfmu declares it does not).
        if self._libc is None:
            libc = ctypes.CDLL("msvcrt") if platform.system() == "Windows" else ctypes.CDLL(None)
            libc.calloc.restype = c_void_p
            libc.calloc.argtypes = [c_size_t, c_size_t]
            libc.free.argtypes = [c_void_p]
            self._libc = libc
        return self._libc

    def _calloc(self, count, size):
        return self._c_runtime().calloc(count, size)

    def _free_memory(self, pointer):
        self._c_runtime().free(pointer)

    def instantiate(self, logging_on: bool = True, visible: bool = False, model_exchange: bool = False):
        resources = (self.unzipped / "resources").as_uri()
        self._instantiate(
            "fmi2Instantiate", self.instance_name.encode(), FMI2_MODEL_EXCHANGE if model_exchange else FMI2_CO_SIMULATION,
            self.description.get("guid").encode(), resources.encode(), byref(self._callbacks), int(visible),
            int(logging_on),
        )

    def setup_experiment(self, start_time: float = 0.0, stop_time: float | None = None):
        return self._call("fmi2SetupExperiment", 0, 0.0, start_time, stop_time is not None, stop_time or 0.0)

    def enter_initialization_mode(self):
        return self._call("fmi2EnterInitializationMode")

    def set_real(self, names, values):
        self._transfer("fmi2SetReal", "Real", c_double, names, values)

    def get_real(self, names) -> list:
        return self._transfer("fmi2GetReal", "Real", c_double, names)

    def set_integer(self, names, values):
        self._transfer("fmi2SetInteger", "Integer", c_int, names, values)

    def get_integer(self, names) -> list:
        return self._transfer("fmi2GetInteger", "Integer", c_int, names)

    def get_boolean(self, names) -> list:
        return [bool(v) for v in self._transfer("fmi2GetBoolean", "Boolean", c_int, names)]

    def do_step(self, current_time: float, step_size: float, no_set_prior: bool = True):
        return self._call("fmi2DoStep", current_time, step_size, int(no_set_prior))


# --- FMI 3.0 ----------------------------------------------------------------------------------------

# fmi3Boolean is C's bool, fmi3Status an enum (int).
LogMessageType = CFUNCTYPE(None, c_void_p, c_int, c_char_p, c_char_p)
IntermediateUpdateType = CFUNCTYPE(
    None, c_void_p, c_double, c_bool, c_bool, c_bool, c_bool, POINTER(c_bool), POINTER(c_double),
)


class Fmi3Slave(_Slave):
    """One instance of an extracted FMI 3.0 FMU (co-simulation, or model exchange with ``instantiate``'s flag).

    ``messages`` collects ``(status, category, message)`` from the FMU's logMessage callback.
    """

    PREFIX = "fmi3"
    STATUS_LABELS = ("ok", "warning", "discard", "error", "fatal")
    GETTERS = {"Float64": "get_float64", "Int32": "get_int32", "Boolean": "get_boolean"}
    COUNTS_VALUES = True
    SIGNATURES = {
        "fmi3InstantiateCoSimulation": (c_void_p, [
            c_char_p, c_char_p, c_char_p, c_bool, c_bool, c_bool, c_bool, ValueReferences, c_size_t, c_void_p,
            LogMessageType, IntermediateUpdateType,
        ]),
        "fmi3InstantiateModelExchange": (c_void_p, [
            c_char_p, c_char_p, c_char_p, c_bool, c_bool, c_void_p, LogMessageType,
        ]),
        "fmi3FreeInstance": (None, [c_void_p]),
        "fmi3EnterInitializationMode": (c_int, [c_void_p, c_bool, c_double, c_double, c_bool, c_double]),
        "fmi3ExitInitializationMode": (c_int, [c_void_p]),
        "fmi3Terminate": (c_int, [c_void_p]),
        "fmi3GetFloat64": (c_int, [c_void_p, ValueReferences, c_size_t, POINTER(c_double), c_size_t]),
        "fmi3SetFloat64": (c_int, [c_void_p, ValueReferences, c_size_t, POINTER(c_double), c_size_t]),
        "fmi3GetInt32": (c_int, [c_void_p, ValueReferences, c_size_t, POINTER(c_int32), c_size_t]),
        "fmi3GetBoolean": (c_int, [c_void_p, ValueReferences, c_size_t, POINTER(c_bool), c_size_t]),
        "fmi3DoStep": (c_int, [
            c_void_p, c_double, c_double, c_bool, POINTER(c_bool), POINTER(c_bool), POINTER(c_bool), POINTER(c_double),
        ]),
    }

    def __init__(self, unzipped: Path, instance_name: str = "instance"):
        super().__init__(unzipped, instance_name)
        # Keep the ctypes callback referenced for as long as the instance may call it.
        self._log_message = LogMessageType(self._log)

    @staticmethod
    def _type(variable):
        return variable.tag

    @staticmethod
    def _platform_folder(system):
        machine = platform.machine().lower()
        return {"amd64": "x86_64", "arm64": "aarch64"}.get(machine, machine) + "-" + system.lower()

    def _log(self, environment, status, category, message):
        self.messages.append((status, _decode(category), _decode(message)))

    def instantiate(self, logging_on: bool = True, visible: bool = False, model_exchange: bool = False):
        resources = str(self.unzipped / "resources") + os.sep
        names = (self.instance_name.encode(), self.description.get("instantiationToken").encode(), resources.encode())
        if model_exchange:
            self._instantiate("fmi3InstantiateModelExchange", *names, visible, logging_on, None, self._log_message)
        else:
            self._instantiate("fmi3InstantiateCoSimulation", *names, visible, logging_on, False, False, None, 0, None,
                              self._log_message, IntermediateUpdateType())

    def enter_initialization_mode(self, start_time: float = 0.0, stop_time: float | None = None,
                                  tolerance: float | None = None):
        return self._call("fmi3EnterInitializationMode", tolerance is not None, tolerance or 0.0, start_time,
                          stop_time is not None, stop_time or 0.0)

    def set_float64(self, names, values):
        self._transfer("fmi3SetFloat64", "Float64", c_double, names, values)

    def get_float64(self, names) -> list:
        return self._transfer("fmi3GetFloat64", "Float64", c_double, names)

    def get_int32(self, names) -> list:
        return self._transfer("fmi3GetInt32", "Int32", c_int32, names)

    def get_boolean(self, names) -> list:
        return self._transfer("fmi3GetBoolean", "Boolean", c_bool, names)

    def do_step(self, current_time: float, step_size: float, no_set_prior: bool = True) -> tuple:
        """One step; returns ``(eventHandlingNeeded, terminateSimulation, earlyReturn, lastSuccessfulTime)``."""
        event, terminate, early, last = c_bool(), c_bool(), c_bool(), c_double()
        self._call("fmi3DoStep", current_time, step_size, no_set_prior, byref(event), byref(terminate),
                   byref(early), byref(last))
        return event.value, terminate.value, early.value, last.value
