"""The FMI state machines to the letter: every function of the API, FMI 2.0 and 3.0, called in every
state these FMUs reach, allowed exactly where the standard's state tables allow it; and the rules that
come with them (logging, discarded steps, start values, input derivatives before initialisation).

The tables below are the standards' (FMI 2.0.4, sections 3.2.3 and 4.2.4, the model-exchange and
co-simulation state tables; FMI 3.0.2, sections 2.3, 3.2 and 4.2, the allowed calls of each state),
written out for the states these FMUs reach: instantiated (I), initialization mode (N), step mode /
stepComplete (S), FMI 2.0 stepFailed (F), event mode (V), continuous-time mode (C), terminated (T) and
FMI 2.0 error (E). A call the standard does not allow, or a function of the other interface, returns
fmiError, logs why, and leaves the instance in the error state (FMI 2.0 error, FMI 3.0 terminated). A
function these FMUs do not offer (co-simulation's event mode, clocks, output derivatives) is fmiError in
every state. The walk runs the FMUs' binary through ctypes, in this process (a Python host).
"""

import ctypes
import math
import re
from ctypes import byref, c_bool, c_char_p, c_double, c_int, c_size_t, c_void_p
from pathlib import Path

import pytest
from fmpy import extract, read_model_description

from fmi_ctypes import Fmi2Slave, Fmi3Slave, FmiCallError
from dsc_fmu.fmubuild.binary import LINUX, NATIVE_DIR

ERROR, DISCARD = 3, 2
FMI2_STATES = "INSFTE"
FMI3_STATES = "INST"
FMI2_ME_STATES = "INVCTE"
FMI3_ME_STATES = "INVCT"
STATE_NAMES = {"I": "instantiated", "N": "initialization mode", "S": "step mode", "F": "step failed",
               "V": "event mode", "C": "continuous-time mode", "T": "terminated", "E": "error"}


# FMI 2.0.4, co-simulation (section 4.2.4): the states each function is allowed in.
FMI2_ALLOWED = {
    "fmi2SetDebugLogging": "INSFTE", "fmi2SetupExperiment": "I", "fmi2EnterInitializationMode": "I",
    "fmi2ExitInitializationMode": "N", "fmi2Terminate": "SF", "fmi2Reset": "INSFTE",
    **{f"fmi2Get{t}": "NSFTE" for t in ("Real", "Integer", "Boolean", "String")},
    **{f"fmi2Set{t}": "INS" for t in ("Real", "Integer", "Boolean", "String")},
    **{f: "INSFTE" for f in ("fmi2GetFMUstate", "fmi2SetFMUstate", "fmi2FreeFMUstate", "fmi2SerializedFMUstateSize",
                             "fmi2SerializeFMUstate", "fmi2DeSerializeFMUstate")},
    "fmi2GetDirectionalDerivative": "NSFTE", "fmi2SetRealInputDerivatives": "INS",
    "fmi2GetRealOutputDerivatives": "SFTE", "fmi2DoStep": "S", "fmi2CancelStep": "",
    **{f"fmi2Get{t}Status": "SFT" for t in ("", "Real", "Integer", "Boolean", "String")},
}
# FMI 2.0.4, model exchange (section 3.2.3); the co-simulation functions are allowed nowhere.
FMI2_ME_ALLOWED = {
    "fmi2SetDebugLogging": "INVCTE", "fmi2SetupExperiment": "I", "fmi2EnterInitializationMode": "I",
    "fmi2ExitInitializationMode": "N", "fmi2Terminate": "VC", "fmi2Reset": "INVCTE",
    **{f"fmi2Get{t}": "NVCTE" for t in ("Real", "Integer", "Boolean", "String")},
    "fmi2SetReal": "INVC", **{f"fmi2Set{t}": "INV" for t in ("Integer", "Boolean", "String")},
    **{f: "INVCTE" for f in ("fmi2GetFMUstate", "fmi2SetFMUstate", "fmi2FreeFMUstate", "fmi2SerializedFMUstateSize",
                             "fmi2SerializeFMUstate", "fmi2DeSerializeFMUstate")},
    "fmi2GetDirectionalDerivative": "NVCTE", "fmi2EnterEventMode": "VC", "fmi2NewDiscreteStates": "V",
    "fmi2EnterContinuousTimeMode": "V", "fmi2CompletedIntegratorStep": "C", "fmi2SetTime": "VC",
    "fmi2SetContinuousStates": "C", "fmi2GetDerivatives": "NVCTE", "fmi2GetEventIndicators": "NVCTE",
    "fmi2GetContinuousStates": "NVCTE", "fmi2GetNominalsOfContinuousStates": "INVCTE",
}
# FMI 3.0.2, co-simulation without event mode (sections 2.3, 4.2): every function not named here
# belongs to a capability these FMUs do not declare and is allowed in none of these states.
FMI3_TYPES = ("Float32", "Float64", "Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64",
              "Boolean", "String", "Binary")
FMI3_ALLOWED = {
    "fmi3SetDebugLogging": "INST", "fmi3Reset": "INST", "fmi3EnterInitializationMode": "I",
    "fmi3ExitInitializationMode": "N", "fmi3Terminate": "S", "fmi3DoStep": "S",
    "fmi3GetDirectionalDerivative": "NST", "fmi3GetAdjointDerivative": "NST",
    **{f"fmi3Get{t}": "INST" for t in FMI3_TYPES}, **{f"fmi3Set{t}": "INS" for t in FMI3_TYPES},
    **{f: "INST" for f in ("fmi3GetFMUState", "fmi3SetFMUState", "fmi3FreeFMUState", "fmi3SerializedFMUStateSize",
                           "fmi3SerializeFMUState", "fmi3DeserializeFMUState")},
}
# FMI 3.0.2, model exchange (sections 2.3, 3.2).
FMI3_ME_ALLOWED = {
    "fmi3SetDebugLogging": "INVCT", "fmi3Reset": "INVCT", "fmi3EnterInitializationMode": "I",
    "fmi3ExitInitializationMode": "N", "fmi3Terminate": "VC",
    **{f"fmi3Get{t}": "INVCT" for t in FMI3_TYPES},
    **{f"fmi3Set{t}": "INVC" if t in ("Float32", "Float64") else "INV" for t in FMI3_TYPES},
    **{f: "INVCT" for f in ("fmi3GetFMUState", "fmi3SetFMUState", "fmi3FreeFMUState", "fmi3SerializedFMUStateSize",
                            "fmi3SerializeFMUState", "fmi3DeserializeFMUState", "fmi3GetNumberOfContinuousStates",
                            "fmi3GetNumberOfEventIndicators")},
    "fmi3EnterEventMode": "C", "fmi3UpdateDiscreteStates": "V", "fmi3EnterContinuousTimeMode": "V",
    "fmi3CompletedIntegratorStep": "C", "fmi3SetTime": "C", "fmi3SetContinuousStates": "C",
    "fmi3GetDirectionalDerivative": "NVCT", "fmi3GetAdjointDerivative": "NVCT",
    **{f: "NVCT" for f in ("fmi3GetContinuousStateDerivatives", "fmi3GetEventIndicators", "fmi3GetContinuousStates",
                           "fmi3GetNominalsOfContinuousStates")},
}
TABLES = {(2, False): (FMI2_ALLOWED, FMI2_STATES), (3, False): (FMI3_ALLOWED, FMI3_STATES),
          (2, True): (FMI2_ME_ALLOWED, FMI2_ME_STATES), (3, True): (FMI3_ME_ALLOWED, FMI3_ME_STATES)}
# What an allowed call with valid arguments returns where it is not fmiOK: these FMUs provide no output
# derivatives, and have no status to give but the last successful time and "not terminated".
ANSWERS = {"fmi2GetRealOutputDerivatives": ERROR,
           "fmi2GetStatus": DISCARD, "fmi2GetIntegerStatus": DISCARD, "fmi2GetStringStatus": DISCARD}
NOT_CALLED = {"fmi2GetTypesPlatform", "fmi2GetVersion", "fmi2Instantiate", "fmi2FreeInstance", "fmi3GetVersion",
              "fmi3InstantiateModelExchange", "fmi3InstantiateCoSimulation", "fmi3InstantiateScheduledExecution",
              "fmi3FreeInstance"}


def api(version: int) -> list[str]:
    """Every function the FMI standard's header declares (as FMPy ships it)."""
    import fmpy

    header = Path(fmpy.__file__).parent / "c-code" / f"fmi{version}Functions.h"
    names = re.findall(rf"^#define (fmi{version}\w+) +fmi{version}FullName", header.read_text(), flags=re.M)
    return [name for name in names if name not in NOT_CALLED and not name.endswith("Version")]


class Walk:
    """One instance of ReferenceRobot (FMI 2.0 or 3.0, co-simulation or model exchange), driven into a
    state, and its raw calls."""

    STATES = (2.0, 2.0, 0.0)  # ReferenceRobot's initial state

    def __init__(self, folder: Path, version: int, state: str, logging_on: bool = True, model_exchange: bool = False):
        self.version, self.model_exchange = version, model_exchange
        self.fmu = (Fmi3Slave if version == 3 else Fmi2Slave)(folder, f"walk_{state}")
        self.fmu.instantiate(logging_on=logging_on, model_exchange=model_exchange)
        self.saved = c_void_p()
        self.raw(f"fmi{version}GetFMUState" if version == 3 else "fmi2GetFMUstate", byref(self.saved))
        self.bytes = self._serialized()
        self.enter(state)

    def raw(self, name: str, *args) -> int:
        function = self.fmu.dll[name]  # a function object of its own, without the driver's argtypes
        function.restype = c_int
        return function(c_void_p(self.fmu.instance), *args)

    def _serialized(self):
        size = c_size_t()
        prefix = "fmi3SerializedFMUStateSize" if self.version == 3 else "fmi2SerializedFMUstateSize"
        assert self.raw(prefix, self.saved, byref(size)) == 0
        buffer = ctypes.create_string_buffer(size.value)
        name = "fmi3SerializeFMUState" if self.version == 3 else "fmi2SerializeFMUstate"
        assert self.raw(name, self.saved, buffer, size) == 0
        return buffer

    def enter(self, state: str, stop: float | None = None) -> None:
        """Drive the instance from instantiated into ``state``, in an experiment stopping at ``stop``."""
        v = self.version
        if state == "E":
            self.raw("fmi2CancelStep")
            return
        if state in "NSFTVC":
            if v == 2:
                assert self.raw("fmi2SetupExperiment", c_int(0), c_double(0), c_double(0), c_int(stop is not None),
                                c_double(stop or 0)) == 0
            assert self.raw(f"fmi{v}EnterInitializationMode", *self._experiment(stop)) == 0
        if state in "SFTVC":
            assert self.raw(f"fmi{v}ExitInitializationMode") == 0
        if state == "C":
            assert self.raw(f"fmi{v}EnterContinuousTimeMode") == 0
        if state == "F":
            assert self.step(1e9) == DISCARD  # more sub-steps than a step may take
        if state == "T":
            assert self.raw(f"fmi{v}Terminate") == 0
        self.fmu.messages.clear()

    def _experiment(self, stop: float | None = None):
        """The arguments of fmi3EnterInitializationMode (FMI 2.0: none)."""
        if self.version == 2:
            return ()
        return c_bool(False), c_double(0), c_double(0), c_bool(stop is not None), c_double(stop or 0)

    def step(self, h: float = 1e-3) -> int:
        if self.version == 2:
            return self.raw("fmi2DoStep", c_double(0), c_double(h), c_int(1))
        flags = [c_bool() for _ in range(3)]
        return self.raw("fmi3DoStep", c_double(0), c_double(h), c_bool(True), *map(byref, flags), byref(c_double()))

    def call(self, name: str) -> int:
        """``name`` with valid arguments (no variables, the state saved at instantiation)."""
        none, zero, n = c_void_p(), c_size_t(0), c_size_t(len(self.STATES))
        vector = (c_double * len(self.STATES))(*self.STATES)
        flags = [byref(c_bool()) for _ in range(5)]
        special = {
            "fmi2NewDiscreteStates": (ctypes.create_string_buffer(64),),
            "fmi2CompletedIntegratorStep": (c_int(1), byref(c_int()), byref(c_int())),
            "fmi3UpdateDiscreteStates": (*flags, byref(c_double())),
            "fmi3CompletedIntegratorStep": (c_bool(True), *flags[:2]),
            "fmi2SetTime": (c_double(0),), "fmi3SetTime": (c_double(0),),
            **{f: (vector, n) for f in ("fmi2SetContinuousStates", "fmi2GetDerivatives", "fmi2GetContinuousStates",
                                        "fmi2GetNominalsOfContinuousStates", "fmi3SetContinuousStates",
                                        "fmi3GetContinuousStateDerivatives", "fmi3GetContinuousStates",
                                        "fmi3GetNominalsOfContinuousStates")},
            "fmi2GetEventIndicators": (none, zero), "fmi3GetEventIndicators": (none, zero),
            "fmi3GetNumberOfContinuousStates": (byref(c_size_t()),),
            "fmi3GetNumberOfEventIndicators": (byref(c_size_t()),),
            "fmi2SetDebugLogging": (c_int(1), zero, none), "fmi3SetDebugLogging": (c_bool(True), zero, none),
            "fmi2SetupExperiment": (c_int(0), c_double(0), c_double(0), c_int(0), c_double(0)),
            "fmi3EnterInitializationMode": self._experiment(), "fmi2SetRealInputDerivatives": (none, zero, none, none),
            "fmi2GetDirectionalDerivative": (none, zero, none, zero, none, none),
            **{f: (none, zero, none, zero, none, zero, none, zero)
               for f in ("fmi3GetDirectionalDerivative", "fmi3GetAdjointDerivative")},
            "fmi2GetStatus": (c_int(0), byref(c_int())), "fmi2GetRealStatus": (c_int(2), byref(c_double())),
            "fmi2GetIntegerStatus": (c_int(0), byref(c_int())), "fmi2GetBooleanStatus": (c_int(3), byref(c_int())),
            "fmi2GetStringStatus": (c_int(0), byref(c_char_p())),
            "fmi2GetFMUstate": (byref(c_void_p()),), "fmi3GetFMUState": (byref(c_void_p()),),
            "fmi2SetFMUstate": (self.saved,), "fmi3SetFMUState": (self.saved,),
            "fmi2FreeFMUstate": (byref(c_void_p()),), "fmi3FreeFMUState": (byref(c_void_p()),),
            "fmi2SerializedFMUstateSize": (self.saved, byref(c_size_t())),
            "fmi3SerializedFMUStateSize": (self.saved, byref(c_size_t())),
            "fmi2SerializeFMUstate": (self.saved, self.bytes, c_size_t(len(self.bytes))),
            "fmi3SerializeFMUState": (self.saved, self.bytes, c_size_t(len(self.bytes))),
            "fmi2DeSerializeFMUstate": (self.bytes, c_size_t(len(self.bytes)), byref(c_void_p())),
            "fmi3DeserializeFMUState": (self.bytes, c_size_t(len(self.bytes)), byref(c_void_p())),
        }
        if name in ("fmi2DoStep", "fmi3DoStep"):
            return self.step()
        if name in special:
            return self.raw(name, *special[name])
        if name.startswith(("fmi2Get", "fmi2Set")) and name[7:] in ("Real", "Integer", "Boolean", "String"):
            return self.raw(name, none, zero, none)
        if name in ("fmi3GetBinary", "fmi3SetBinary"):
            return self.raw(name, none, zero, none, none, zero)
        if name.startswith(("fmi3Get", "fmi3Set")) and name[7:] in FMI3_TYPES:
            return self.raw(name, none, zero, none, zero)
        return self.raw(name)  # a function these FMUs do not offer, or refused, reads none of its arguments

    def refusals(self, name: str) -> list[str]:
        return [m for m in self.messages() if f"{name} is not allowed in state" in m]

    def messages(self) -> list[str]:
        return [m[-1] for m in self.fmu.messages]

    def in_error_state(self) -> bool:
        """Whether the instance is in the standard's error state (FMI 2.0 error, FMI 3.0 terminated)."""
        probe = "fmi3EnterInitializationMode" if self.version == 3 else (
            "fmi2EnterEventMode" if self.model_exchange else "fmi2CancelStep")
        before = len(self.fmu.messages)
        self.call(probe)
        expected = "error" if self.version == 2 else "terminated"
        return any(f"{probe} is not allowed in state {expected}" in m for m in self.messages()[before:])

    def close(self):
        self.fmu.free_instance()


@pytest.fixture(scope="module")
def folders(fmu_paths, fmu3_paths, tmp_path_factory):
    root = tmp_path_factory.mktemp("states")
    return {2: Path(extract(str(fmu_paths["ReferenceRobot"]), unzipdir=root / "fmi2")),
            3: Path(extract(str(fmu3_paths["ReferenceRobot"]), unzipdir=root / "fmi3"))}


def test_the_tables_name_every_function_the_binary_exports(folders):
    """The walk covers the whole API: every function of the standard's header is exported, and the
    tables name only functions of the header (FMI 2.0: every one, in one interface or the other)."""
    for version in (2, 3):
        library = ctypes.CDLL(str(folders[version] / LINUX.file(version, "ReferenceRobot")))
        names = set(api(version))
        assert [name for name in sorted(names) if not hasattr(library, name)] == []
        cosimulation, model_exchange = TABLES[version, False][0], TABLES[version, True][0]
        assert set(cosimulation) | set(model_exchange) <= names
        if version == 2:
            assert set(cosimulation) | set(model_exchange) == names


@pytest.mark.parametrize("version", (2, 3))
def test_every_function_is_defined_under_its_own_name(version):
    """Greppable: each function of the standard's header has its signature written out in
    native/fmi<version>Functions.c (the return type, then the name at the start of a line)."""
    import fmpy

    header = (Path(fmpy.__file__).parent / "c-code" / f"fmi{version}Functions.h").read_text()
    names = re.findall(rf"^#define (fmi{version}\w+) +fmi{version}FullName", header, flags=re.M)
    source = (NATIVE_DIR / f"fmi{version}Functions.c").read_text()
    assert len(names) > 40
    assert [name for name in names if not re.search(rf"^[\w ]+\*?{name}\(", source, flags=re.M)] == []


@pytest.mark.parametrize("model_exchange", (False, True), ids=("co-simulation", "model-exchange"))
@pytest.mark.parametrize("version", (2, 3))
def test_every_function_in_every_state_is_allowed_exactly_where_the_standard_allows_it(folders, version,
                                                                                       model_exchange):
    table, states = TABLES[version, model_exchange]
    wrong = []
    for name in api(version):
        for state in states:
            walk = Walk(folders[version], version, state, model_exchange=model_exchange)
            try:
                status = walk.call(name)
                if state in table.get(name, ""):
                    expected = ANSWERS.get(name, 0)
                    # FMI 3.0's error state is terminated, which fmi3Terminate enters without an error.
                    probe = expected == 0 and state not in "ET" and name != "fmi3Terminate"
                    if walk.refusals(name) or status != expected or (probe and walk.in_error_state()):
                        wrong.append(f"{name} in {STATE_NAMES[state]}: status {status}, not {expected} (allowed)")
                elif status != ERROR or not walk.in_error_state():
                    wrong.append(f"{name} in {STATE_NAMES[state]}: status {status}, not fmiError and the error state")
                elif not any(name in m for m in walk.messages()):
                    wrong.append(f"{name} in {STATE_NAMES[state]}: refused without a message naming it")
            finally:
                walk.close()
    assert wrong == []


@pytest.mark.parametrize("version", (2, 3))
def test_an_error_leaves_a_way_back_through_a_saved_state(folders, version):
    """After fmiError, the state saved before leads on (the standard's way to continue)."""
    walk = Walk(folders[version], version, "S")
    saved = c_void_p()
    get, put = ("fmi3GetFMUState", "fmi3SetFMUState") if version == 3 else ("fmi2GetFMUstate", "fmi2SetFMUstate")
    assert walk.raw(get, byref(saved)) == 0
    assert walk.call(f"fmi{version}EnterInitializationMode") == ERROR and walk.in_error_state()
    assert walk.step() == ERROR
    assert walk.raw(put, saved) == 0
    assert walk.step() == 0
    walk.close()


def test_a_discarded_fmi2_step_leaves_the_slave_in_step_failed(folders):
    """FMI 2.0.4: after fmi2Discard only getters, status, termination, reset and FMU states; another
    step only after fmi2SetFMUstate. The discard is logged with its status."""
    walk = Walk(folders[2], 2, "S")
    assert walk.step() == 0
    saved = c_void_p()
    assert walk.raw("fmi2GetFMUstate", byref(saved)) == 0
    assert walk.raw("fmi2DoStep", c_double(1e-3), c_double(1e9), c_int(1)) == DISCARD
    assert [m for m in walk.fmu.messages if m[1] == DISCARD and "discarded" in m[3]]
    last = c_double()
    assert walk.raw("fmi2GetRealStatus", c_int(2), byref(last)) == 0 and last.value == 1e-3
    assert walk.raw("fmi2DoStep", c_double(1e-3), c_double(1e-3), c_int(1)) == ERROR and walk.refusals("fmi2DoStep")
    assert walk.raw("fmi2SetFMUstate", saved) == 0
    assert walk.raw("fmi2DoStep", c_double(1e-3), c_double(1e-3), c_int(1)) == 0
    walk.close()


def test_a_discarded_fmi3_step_leaves_the_fmu_as_before_the_call(folders):
    """FMI 3.0: "the FMU is in the same state as before the call": step mode, another step allowed;
    the discard is logged with the status fmi3Discard."""
    walk = Walk(folders[3], 3, "S")
    assert walk.step(1e9) == DISCARD
    assert [m for m in walk.fmu.messages if m[0] == DISCARD and "discarded" in m[2]]
    assert walk.step() == 0
    walk.close()


def test_fmi3_start_values_are_readable_before_initialisation(fmu3_paths, folders):
    md = read_model_description(str(fmu3_paths["ReferenceRobot"]))
    parameters = [v for v in md.modelVariables if v.causality == "parameter" and v.type == "Float64"]
    walk = Walk(folders[3], 3, "I")
    values = walk.fmu.get_float64([v.name for v in parameters])
    assert values == [float(v.start) for v in parameters]
    walk.close()


@pytest.mark.parametrize("version", (2, 3))
def test_logging_off_is_silent_as_the_standard_says(folders, version):
    """FMI 3.0.2: loggingOn = fmi3False, logMessage is never called, not even for errors or a refused
    instantiation. FMI 2.0: only debug logging is off; warnings and errors are still shown, OK and
    discard messages are not."""
    walk = Walk(folders[version], version, "S", logging_on=False)
    assert walk.step(1e9) == DISCARD
    assert walk.call(f"fmi{version}EnterInitializationMode") == ERROR
    statuses = [m[0] if version == 3 else m[1] for m in walk.fmu.messages]
    assert statuses == ([] if version == 3 else [ERROR])  # FMI 2.0: the illegal call, not the discard
    walk.close()
    if version == 3:
        walk.fmu.description.set("instantiationToken", "{wrong}")
        with pytest.raises(FmiCallError):
            walk.fmu.instantiate(logging_on=False)
        assert walk.fmu.messages == []


@pytest.mark.parametrize("version", (2, 3))
def test_categories_switched_off_are_not_logged(folders, version):
    walk = Walk(folders[version], version, "S")
    names = (c_char_p * 1)(b"logStatusError")
    assert walk.raw(f"fmi{version}SetDebugLogging", c_bool(False) if version == 3 else c_int(0), c_size_t(1),
                    names) == 0
    assert walk.step(1e9) == DISCARD
    assert walk.call(f"fmi{version}EnterInitializationMode") == ERROR
    statuses = [m[0] if version == 3 else m[1] for m in walk.fmu.messages]
    # The discard is logged; the error only by FMI 2.0, which shows errors whatever the categories.
    assert statuses == ([DISCARD] if version == 3 else [DISCARD, ERROR])
    walk.close()


def test_input_derivatives_set_before_initialisation_shape_the_first_step(fmu_paths, tmp_path):
    """fmi2SetRealInputDerivatives is allowed in instantiated (FMI 2.0.4, 4.2.4) and its slopes act on
    the first step as if set just before it."""
    folder = Path(extract(str(fmu_paths["MobileRobot"]), unzipdir=tmp_path / "plant"))
    rows = []
    for when in ("instantiated", "step mode", "never"):
        walk = Walk(folder, 2, "I")
        refs = (ctypes.c_uint * 2)(*(walk.fmu.variables[n][0] for n in ("u1", "u2")))
        derivative = lambda: walk.raw("fmi2SetRealInputDerivatives", refs, c_size_t(2),  # noqa: E731
                                      (c_int * 2)(1, 1), (c_double * 2)(40.0, -20.0))
        if when == "instantiated":
            assert derivative() == 0
        walk.enter("N")
        walk.fmu.set_real(["u1", "u2"], [6.0, 5.0])
        assert walk.raw("fmi2ExitInitializationMode") == 0
        if when == "step mode":
            assert derivative() == 0
        assert walk.step(0.05) == 0
        rows.append(walk.fmu.get_real(["x", "y", "theta", "i1", "i2"]))
        walk.close()
    assert rows[0] == rows[1] != rows[2]
    assert all(math.isfinite(v) for v in rows[0])


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("end,status", [(1.0 + 1e-10, 0), (1.0 + 1e-8, ERROR)], ids=("rounding", "past"))
def test_no_step_may_end_after_the_stop_time(folders, version, end, status):
    """Both standards: computing past the stop time set up for the experiment is fmiError; a step
    that ends on it give or take rounding (1e-9 of the stop time) is not."""
    walk = Walk(folders[version], version, "I")
    walk.enter("S", stop=1.0)
    assert walk.step(end) == status
    assert any("ends after the stop time" in m for m in walk.messages()) == (status == ERROR)
    walk.close()


@pytest.mark.parametrize("name", ("fmi3GetClock", "fmi3SetClock"))
def test_the_clock_functions_say_that_these_fmus_have_no_clocks(folders, name):
    """In every state: fmi3Error, the error state, and why (not a state refusal)."""
    for state in FMI3_STATES:
        walk = Walk(folders[3], 3, state)
        refs = (ctypes.c_uint * 1)(walk.fmu.variables["x_r"][0])
        assert walk.raw(name, refs, c_size_t(1), (c_bool * 1)()) == ERROR and walk.in_error_state()
        assert f"{name} is not supported: these FMUs have no clocks" in walk.messages()[0], walk.messages()
        walk.close()


@pytest.mark.parametrize("version", (2, 3))
def test_the_string_getter_and_setter_know_these_fmus_have_no_string_variables(folders, version):
    """In initialization mode, where both are allowed. No variable is a String: no value references is
    fmiOK with nothing touched; a Real's value reference is fmiError naming its type, and so is one of
    no variable."""
    strings = (c_char_p * 1)(b"untouched")
    count = lambda n: () if version == 2 else (c_size_t(n),)  # noqa: E731 (FMI 3.0: nValues)
    for function in (f"fmi{version}GetString", f"fmi{version}SetString"):
        walk = Walk(folders[version], version, "N")
        real = walk.fmu.variables["x_r"][0]
        assert walk.raw(function, (ctypes.c_uint * 1)(real), c_size_t(0), strings, *count(0)) == 0
        assert strings[0] == b"untouched"
        assert walk.raw(function, (ctypes.c_uint * 1)(real), c_size_t(1), strings, *count(1)) == ERROR
        kind = "Real" if version == 2 else "Float64"
        assert f"{function}: value reference {real} is a {kind} variable, not String" in walk.messages()[0]
        walk.close()
        walk = Walk(folders[version], version, "N")
        assert walk.raw(function, (ctypes.c_uint * 1)(99999), c_size_t(1), strings, *count(1)) == ERROR
        assert "value reference 99999 is not a variable of this FMU" in walk.messages()[0]
        walk.close()
