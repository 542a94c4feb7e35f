"""A minimal FMI 2.0 co-simulation driver on ctypes and the standard library only.

Used by ``test_fmu_isolation.py`` inside a subprocess in which numpy, fmpy, scipy and dsc_fmu
cannot be imported, so it must import nothing outside the standard library (no numpy, no fmpy).

It extracts an FMU with ``zipfile``, reads the variables of ``modelDescription.xml`` with
``xml.etree``, loads ``binaries/<platform>/<modelIdentifier>.<ext>`` and calls the FMI 2.0 C API.
"""

import ctypes
import platform
import sys
import zipfile
from ctypes import CFUNCTYPE, POINTER, Structure, byref, c_char_p, c_double, c_int, c_size_t, c_uint, c_void_p
from pathlib import Path
from xml.etree import ElementTree

__all__ = ["Fmi2CallError", "Fmi2Slave", "extract", "STATUS_LABELS"]

fmi2OK, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal, fmi2Pending = range(6)
STATUS_LABELS = ("ok", "warning", "discard", "error", "fatal", "pending")
fmi2CoSimulation = 1

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


class Fmi2CallError(Exception):
    """An FMI function returned a status worse than fmi2Warning."""

    def __init__(self, function: str, status: int):
        label = STATUS_LABELS[status] if 0 <= status < len(STATUS_LABELS) else "illegal"
        super().__init__(f"{function} returned status {status} ({label})")
        self.function = function
        self.status = status


def _platform_folder() -> tuple:
    system = platform.system()
    bits = "64" if sys.maxsize > 2**32 else "32"
    if system == "Linux":
        return f"linux{bits}", ".so"
    if system == "Darwin":
        return f"darwin{bits}", ".dylib"
    if system == "Windows":
        return f"win{bits}", ".dll"
    raise OSError(f"unsupported platform {system}")


def extract(fmu: Path, target: Path) -> Path:
    """Unzip ``fmu`` into ``target`` (created) and return it."""
    target = Path(target)
    target.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(fmu) as archive:
        archive.extractall(target)
    return target


class Fmi2Slave:
    """One instance of an extracted FMI 2.0 co-simulation FMU.

    ``messages`` collects ``(instance_name, status, category, message)`` from the FMU's logger.
    Variables are addressed by name; types come from ``modelDescription.xml``.
    """

    def __init__(self, unzipped: Path, instance_name: str = "instance"):
        self.unzipped = Path(unzipped).resolve()
        root = ElementTree.parse(self.unzipped / "modelDescription.xml").getroot()
        self.guid = root.get("guid")
        self.model_identifier = root.find("CoSimulation").get("modelIdentifier")
        self.variables = {}
        for scalar in root.find("ModelVariables"):
            self.variables[scalar.get("name")] = (int(scalar.get("valueReference")), scalar[0].tag)
        folder, extension = _platform_folder()
        self.library_path = self.unzipped / "binaries" / folder / (self.model_identifier + extension)
        self.dll = ctypes.CDLL(str(self.library_path))
        self._declare()
        self.instance_name = instance_name
        self.messages = []
        self.component = None
        self._callbacks = CallbackFunctions()
        # Keep the ctypes callbacks referenced for as long as the instance may call them.
        self._logger = LoggerType(self._log)
        self._allocate = AllocateType(self._calloc)
        self._free = FreeType(self._free_memory)
        self._callbacks.logger = self._logger
        self._callbacks.allocateMemory = self._allocate
        self._callbacks.freeMemory = self._free
        self._callbacks.stepFinished = StepFinishedType()
        self._callbacks.componentEnvironment = None
        self._libc = None

    # --- plumbing -----------------------------------------------------------------------------

    def _declare(self):
        component = c_void_p
        signatures = {
            "fmi2Instantiate": (c_void_p, [c_char_p, c_int, c_char_p, c_char_p, POINTER(CallbackFunctions), c_int, c_int]),
            "fmi2FreeInstance": (None, [component]),
            "fmi2SetupExperiment": (c_int, [component, c_int, c_double, c_double, c_int, c_double]),
            "fmi2EnterInitializationMode": (c_int, [component]),
            "fmi2ExitInitializationMode": (c_int, [component]),
            "fmi2Terminate": (c_int, [component]),
            "fmi2GetReal": (c_int, [component, POINTER(c_uint), c_size_t, POINTER(c_double)]),
            "fmi2SetReal": (c_int, [component, POINTER(c_uint), c_size_t, POINTER(c_double)]),
            "fmi2GetInteger": (c_int, [component, POINTER(c_uint), c_size_t, POINTER(c_int)]),
            "fmi2SetInteger": (c_int, [component, POINTER(c_uint), c_size_t, POINTER(c_int)]),
            "fmi2GetBoolean": (c_int, [component, POINTER(c_uint), c_size_t, POINTER(c_int)]),
            "fmi2DoStep": (c_int, [component, c_double, c_double, c_int]),
        }
        self._functions = {}
        for name, (restype, argtypes) in signatures.items():
            function = getattr(self.dll, name)
            function.restype = restype
            function.argtypes = argtypes
            self._functions[name] = function

    def _log(self, environment, instance_name, status, category, message):
        decode = lambda b: None if b is None else b.decode("utf-8", "replace")  # noqa: E731
        self.messages.append((decode(instance_name), status, decode(category), decode(message)))

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

    def _call(self, name, *args):
        status = self._functions[name](self.component, *args)
        if status > fmi2Warning:
            raise Fmi2CallError(name, status)
        return status

    def _refs(self, names, kind):
        refs = []
        for name in names:
            vr, tag = self.variables[name]
            if tag != kind:
                raise TypeError(f"{name} is {tag}, not {kind}")
            refs.append(vr)
        return (c_uint * len(refs))(*refs)

    # --- FMI 2.0 ------------------------------------------------------------------------------

    def instantiate(self, logging_on: bool = True, visible: bool = False):
        resources = (self.unzipped / "resources").as_uri()
        self.component = self._functions["fmi2Instantiate"](
            self.instance_name.encode(), fmi2CoSimulation, self.guid.encode(), resources.encode(),
            byref(self._callbacks), int(visible), int(logging_on),
        )
        if not self.component:
            self.component = None
            raise Fmi2CallError("fmi2Instantiate", fmi2Fatal)

    def setup_experiment(self, start_time: float = 0.0, stop_time: float | None = None):
        stop_defined = stop_time is not None
        return self._call("fmi2SetupExperiment", 0, 0.0, start_time, int(stop_defined), stop_time or 0.0)

    def enter_initialization_mode(self):
        return self._call("fmi2EnterInitializationMode")

    def exit_initialization_mode(self):
        return self._call("fmi2ExitInitializationMode")

    def set_real(self, names, values):
        values = list(values)
        return self._call("fmi2SetReal", self._refs(names, "Real"), len(values), (c_double * len(values))(*values))

    def get_real(self, names) -> list:
        names = list(names)
        out = (c_double * len(names))()
        self._call("fmi2GetReal", self._refs(names, "Real"), len(names), out)
        return list(out)

    def set_integer(self, names, values):
        values = list(values)
        return self._call("fmi2SetInteger", self._refs(names, "Integer"), len(values), (c_int * len(values))(*values))

    def get_integer(self, names) -> list:
        names = list(names)
        out = (c_int * len(names))()
        self._call("fmi2GetInteger", self._refs(names, "Integer"), len(names), out)
        return list(out)

    def get_boolean(self, names) -> list:
        names = list(names)
        out = (c_int * len(names))()
        self._call("fmi2GetBoolean", self._refs(names, "Boolean"), len(names), out)
        return [bool(v) for v in out]

    def do_step(self, current_time: float, step_size: float, no_set_prior: bool = True):
        return self._call("fmi2DoStep", current_time, step_size, int(no_set_prior))

    def terminate(self):
        return self._call("fmi2Terminate")

    def free_instance(self):
        if self.component is not None:
            self._functions["fmi2FreeInstance"](self.component)
            self.component = None
