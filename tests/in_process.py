"""The slaves of ``fmu_sources`` in this process, without the binary: what tests of the slaves' behaviour drive.

An ``InProcess`` makes the slave class of an FMU's script (FMI 2.0 on pythonfmu, FMI 3.0 on pythonfmu3) and
calls it as the binary does (``setup_experiment``, ``enter_initialization_mode``, the getters and
setters of the FMI library, ``do_step``, ``_get_fmu_state``), with value references by name.
"""

import importlib.util
import itertools
from pathlib import Path

import pytest

import dsc_fmu
from dsc_fmu.registry import FMUS

__all__ = ["Discarded", "InProcess", "SOURCES", "slave_class"]

# The scripts beside the package imported (a tree's own, also for benchmarks run on another tree's package).
SOURCES = Path(dsc_fmu.__file__).resolve().parents[1] / "fmu_sources"
# The FMI library's getters and setters by type, for each FMI version.
ACCESS = {
    2: {"Real": ("get_real", "set_real"), "Integer": ("get_integer", "set_integer"), "Boolean": ("get_boolean", None)},
    3: {"Float64": ("get_float64", "set_float64"), "Int32": ("get_int32", "set_int32"),
        "Boolean": ("get_boolean", None)},
}
_classes = {}
_serial = itertools.count()


def slave_class(name: str, fmi_version: int = 2):
    """The slave class of the FMU ``name``, from its script in ``fmu_sources``, imported once."""
    key = (name, fmi_version)
    if key not in _classes:
        script = SOURCES / FMUS[name].script_for(fmi_version)
        spec = importlib.util.spec_from_file_location(f"in_process_{script.stem}", script)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        _classes[key] = getattr(module, name)
    return _classes[key]


class Discarded(Exception):
    """``do_step`` returned False: the binary's fmiDiscard."""


class InProcess:
    """A slave of the FMU ``name`` with value references by name; the API of ``test_fmus.Instance``."""

    def __init__(self, name: str, fmi_version: int = 2, label: str = ""):
        self.name = f"{name}_{label}{next(_serial)}"
        self.slave = slave_class(name, fmi_version)(instance_name=self.name, resources=None, visible=False)
        self.variables = {v.name: v for v in self.slave.vars.values()}
        self.vr = {v.name: vr for vr, v in self.slave.vars.items()}
        self.access = ACCESS[fmi_version]
        self.real = next(iter(self.access))
        self.integer = list(self.access)[1]

    def _call(self, kind, which, names, *values):
        return getattr(self.slave, self.access[kind][which])([self.vr[n] for n in names], *values)

    def initialize(self, real=None, integer=None, start_time=0.0):
        self.slave.setup_experiment(start_time)
        self.slave.enter_initialization_mode()
        for kind, values in ((self.real, real or {}), (self.integer, integer or {})):
            if values:
                self._call(kind, 1, list(values), list(values.values()))
        self.slave.exit_initialization_mode()
        return self

    def set(self, names, values):
        self._call(self.real, 1, list(names), list(values))

    def set_integer(self, names, values):
        self._call(self.integer, 1, list(names), list(values))

    def get(self, names):
        return self._call(self.real, 0, list(names))

    def get_integer(self, names):
        return self._call(self.integer, 0, list(names))

    def get1(self, name):
        return self.get([name])[0]

    def outputs(self) -> dict:
        """Every output by name, read with the getter of its type."""
        result = {}
        for kind in self.access:
            names = [n for n, v in self.variables.items()
                     if v.causality.name == "output" and type(v).__name__ == kind]
            if names:
                result.update(zip(names, self._call(kind, 0, names)))
        return result

    def step(self, t, h):
        if not self.slave.do_step(t, h):
            raise Discarded(f"{self.name}: the step from t = {t} s of {h} s is discarded")

    def messages(self):
        """``(status, message)`` of every message logged, the status as the FMI status code."""
        return [(int(m.status), m.msg) for m in self.slave.log_queue]

    def get_state(self):
        return self.slave._get_fmu_state()

    def set_state(self, state):
        self.slave._set_fmu_state(state)


@pytest.fixture()
def new():
    """Factory of initialized in-process slaves: ``new(name, real=None, integer=None, label="", fmi_version=2)``."""

    def make(name, real=None, integer=None, label="", fmi_version=2):
        return InProcess(name, fmi_version, label).initialize(real, integer)

    return make
