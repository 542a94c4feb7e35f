"""Random FMI 2.0 call sequences against each FMU, each in a process of its own, counting crashes.

Every call is drawn at random with arguments good and bad (unknown value references, wrong types,
NaN, infinite, zero and negative step sizes, huge values, damaged serialized states, a '%' in the
instance name, input derivatives of any order, states and times of model exchange, vectors of any
length) in any order, on instances of either interface (co-simulation or model exchange), but for what the standard leaves
undefined (using a freed instance or a freed FMU state). No process may die of a signal and no call
may return fmi2Fatal. The figures of one run of the full seed range are in the README.
"""

import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import pytest
from fmpy import read_model_description

NAMES = ("ReferenceRobot", "MobileRobot", "DSCController")
# The suite runs TRIALS sequences; DSC_FMU_FUZZ_TRIALS runs more (the README quotes 900).
TRIALS = int(os.environ.get("DSC_FMU_FUZZ_TRIALS", "120"))
CALLS = 120

DRIVER = r'''
import ctypes, json, random, sys
from ctypes import CFUNCTYPE, POINTER, Structure, byref, c_char, c_char_p, c_double, c_int, c_size_t, c_uint, c_void_p

seed, folder, model, guid = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4]
rng = random.Random(seed)
lib = ctypes.CDLL(f"{folder}/binaries/linux64/{model}.so")
LOGGER = CFUNCTYPE(None, c_void_p, c_char_p, c_int, c_char_p, c_char_p)
messages = []
logger = LOGGER(lambda env, name, status, category, message: messages.append(message))
class Callbacks(Structure):
    _fields_ = [("logger", LOGGER), ("allocate", c_void_p), ("free", c_void_p), ("step", c_void_p), ("env", c_void_p)]
callbacks = Callbacks(logger, None, None, None, None)
lib.fmi2Instantiate.restype = c_void_p
lib.fmi2Instantiate.argtypes = [c_char_p, c_int, c_char_p, c_char_p, POINTER(Callbacks), c_int, c_int]
for name in ("fmi2SetupExperiment", "fmi2EnterInitializationMode", "fmi2ExitInitializationMode", "fmi2Terminate",
             "fmi2Reset", "fmi2DoStep", "fmi2GetReal", "fmi2GetInteger", "fmi2GetBoolean", "fmi2GetString",
             "fmi2SetReal", "fmi2SetInteger", "fmi2SetBoolean", "fmi2SetString", "fmi2GetFMUstate", "fmi2SetFMUstate",
             "fmi2FreeFMUstate", "fmi2SerializedFMUstateSize", "fmi2SerializeFMUstate", "fmi2DeSerializeFMUstate",
             "fmi2SetDebugLogging", "fmi2CancelStep", "fmi2GetRealStatus", "fmi2GetBooleanStatus", "fmi2GetStatus",
             "fmi2SetRealInputDerivatives", "fmi2GetRealOutputDerivatives", "fmi2SetTime", "fmi2SetContinuousStates",
             "fmi2GetDerivatives", "fmi2GetEventIndicators", "fmi2GetContinuousStates",
             "fmi2GetNominalsOfContinuousStates", "fmi2EnterEventMode", "fmi2NewDiscreteStates",
             "fmi2EnterContinuousTimeMode", "fmi2CompletedIntegratorStep"):
    getattr(lib, name).restype = c_int
lib.fmi2FreeInstance.argtypes = [c_void_p]
lib.fmi2DoStep.argtypes = [c_void_p, c_double, c_double, c_int]
lib.fmi2SetupExperiment.argtypes = [c_void_p, c_int, c_double, c_double, c_int, c_double]
lib.fmi2SetTime.argtypes = [c_void_p, c_double]
for name in ("fmi2EnterInitializationMode", "fmi2ExitInitializationMode", "fmi2Terminate", "fmi2Reset", "fmi2CancelStep",
             "fmi2EnterEventMode", "fmi2EnterContinuousTimeMode"):
    getattr(lib, name).argtypes = [c_void_p]
NUMBERS = [0.0, 1.0, -1.0, 1e-3, 1e-12, 1e6, 1e300, -1e300, 1e-320, float("nan"), float("inf"), float("-inf"), 2.5]
resources = f"file://{folder}/resources".encode()
component = None
states = []
statuses = {}

def new():
    name = rng.choice([model, "a%sb%n", "%%%d", "x" * 300])
    kind = rng.choice([0, 1])  # fmi2ModelExchange, fmi2CoSimulation
    return lib.fmi2Instantiate(name.encode(), kind, guid.encode(), resources, byref(callbacks), 0, rng.random() < 0.5)

def model_exchange(c, action):
    n = c_size_t(rng.choice([0, 1, 3, 7, 20, 21, 2**40]))
    vector = (c_double * 32)(*[rng.choice(NUMBERS) for _ in range(32)])
    if action == 21:
        return lib.fmi2SetTime(c, rng.choice(NUMBERS))
    if action == 22:
        return lib.fmi2SetContinuousStates(c, rng.choice([vector, None]), n)
    if action == 23:
        getter = rng.choice([lib.fmi2GetDerivatives, lib.fmi2GetEventIndicators, lib.fmi2GetContinuousStates,
                             lib.fmi2GetNominalsOfContinuousStates])
        return getter(c, rng.choice([vector, vector, None]), n)
    if action == 24:
        return rng.choice([lib.fmi2EnterEventMode, lib.fmi2EnterContinuousTimeMode])(c)
    if action == 25:
        return lib.fmi2NewDiscreteStates(c, rng.choice([ctypes.create_string_buffer(64), None]))
    flags = [byref(c_int()), None]
    return lib.fmi2CompletedIntegratorStep(c, 1, rng.choice(flags), rng.choice(flags))

def refs():
    n = rng.choice([0, 1, 2, 3])
    return n, (c_uint * max(n, 1))(*[rng.choice([0, 1, 2, 3, 5, 10, 12, 20, 40, 90, 9999, 2**32 - 1]) for _ in range(max(n, 1))])

def call():
    global component
    action = rng.randrange(27)
    c = c_void_p(component)
    if action == 0:
        return lib.fmi2SetupExperiment(c, rng.random() < 0.5, rng.choice(NUMBERS), rng.choice(NUMBERS), rng.random() < 0.5, rng.choice(NUMBERS))
    if action == 1:
        return lib.fmi2EnterInitializationMode(c)
    if action == 2:
        return lib.fmi2ExitInitializationMode(c)
    if action in (3, 4, 5):
        return lib.fmi2DoStep(c, c_double(rng.choice([0.0, 1e-3, 5.0])), c_double(rng.choice(NUMBERS)), 1)
    if action in (6, 7):
        n, vr = refs()
        kind = rng.choice(["Real", "Integer", "Boolean", "String"])
        values = (c_double * 4)() if kind == "Real" else (c_int * 4)() if kind != "String" else (c_char_p * 4)()
        return getattr(lib, f"fmi2Get{kind}")(c, vr, c_size_t(n), values)
    if action in (8, 9, 10):
        n, vr = refs()
        kind = rng.choice(["Real", "Real", "Integer", "Boolean", "String"])
        if kind == "Real":
            values = (c_double * 4)(*[rng.choice(NUMBERS) for _ in range(4)])
        elif kind == "String":
            values = (c_char_p * 4)(*[b"%s%n" for _ in range(4)])
        else:
            values = (c_int * 4)(*[rng.choice([0, 1, -1, 7, 2**31 - 1]) for _ in range(4)])
        return getattr(lib, f"fmi2Set{kind}")(c, vr, c_size_t(n), values)
    if action == 11:
        state = c_void_p()
        status = lib.fmi2GetFMUstate(c, byref(state))
        if status == 0:
            states.append(state.value)
        return status
    if action == 12 and states:
        return lib.fmi2SetFMUstate(c, c_void_p(rng.choice(states)))
    if action == 13 and states:
        state = c_void_p(states.pop(rng.randrange(len(states))))
        return lib.fmi2FreeFMUstate(c, byref(state))
    if action == 14 and states:
        size = c_size_t()
        status = lib.fmi2SerializedFMUstateSize(c, c_void_p(rng.choice(states)), byref(size))
        if status != 0:
            return status
        buffer = (c_char * size.value)()
        status = lib.fmi2SerializeFMUstate(c, c_void_p(rng.choice(states)), buffer, size)
        data = bytearray(buffer.raw)
        for _ in range(rng.choice([0, 1, 5])):
            data[rng.randrange(len(data))] = rng.randrange(256)
        if rng.random() < 0.3:
            data = data[: rng.randrange(len(data) + 1)]
        state = c_void_p()
        status = lib.fmi2DeSerializeFMUstate(c, (c_char * max(len(data), 1)).from_buffer_copy(bytes(data) or b"\0"), c_size_t(len(data)), byref(state))
        if status == 0:
            states.append(state.value)
        return status
    if action == 15:
        return lib.fmi2Terminate(c)
    if action == 16:
        return lib.fmi2Reset(c)
    if action == 17:
        categories = (c_char_p * 2)(rng.choice([b"logAll", b"nonsense%s", b"logStatusError"]), b"logAll")
        return lib.fmi2SetDebugLogging(c, rng.random() < 0.5, c_size_t(rng.choice([0, 1, 2])), categories)
    if action == 18:
        value = c_double()
        return rng.choice([lambda: lib.fmi2CancelStep(c), lambda: lib.fmi2GetRealStatus(c, rng.randrange(4), byref(value)),
                           lambda: lib.fmi2GetStatus(c, rng.randrange(4), byref(c_int()))])()
    if action == 19:
        n, vr = refs()
        orders = (c_int * 4)(*[rng.choice([1, 1, 0, 2, -1, 2**31 - 1]) for _ in range(4)])
        values = (c_double * 4)(*[rng.choice(NUMBERS) for _ in range(4)])
        derivatives = rng.choice([lib.fmi2SetRealInputDerivatives, lib.fmi2SetRealInputDerivatives,
                                  lib.fmi2GetRealOutputDerivatives])
        return derivatives(c, vr, c_size_t(n), orders, values)
    if 21 <= action <= 26:
        return model_exchange(c, action)
    for state in states:
        lib.fmi2FreeFMUstate(c, byref(c_void_p(state)))
    states.clear()
    lib.fmi2FreeInstance(c)
    component = new()
    return "free"

component = new()
calls = int(sys.argv[5])
for _ in range(calls):
    if component is None:
        component = new()
        continue
    status = call()
    statuses[str(status)] = statuses.get(str(status), 0) + 1
print(json.dumps({"statuses": statuses, "messages": len(messages)}), flush=True)
'''


def _trial(seed, folder, md, name):
    run = subprocess.run([sys.executable, "-c", DRIVER, str(seed), str(folder), name, md.guid, str(CALLS)],
                         capture_output=True, text=True, timeout=300)
    return seed, name, run


@pytest.mark.slow
def test_random_call_sequences_never_crash_and_never_return_fatal(fmu_unzipped):
    md = {name: read_model_description(str(folder)) for name, folder in fmu_unzipped.items()}
    jobs = [(seed, fmu_unzipped[NAMES[seed % 3]], md[NAMES[seed % 3]], NAMES[seed % 3]) for seed in range(TRIALS)]
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 2) as pool:
        runs = list(pool.map(lambda job: _trial(*job), jobs))
    crashed = [(seed, name, run.returncode, run.stderr[-300:]) for seed, name, run in runs if run.returncode != 0]
    assert not crashed, crashed
    totals = {}
    for _, _, run in runs:
        for status, count in json.loads(run.stdout.splitlines()[-1])["statuses"].items():
            totals[status] = totals.get(status, 0) + count
    assert "4" not in totals, totals  # fmi2Fatal
    assert totals.get("3", 0) > 0 and totals.get("0", 0) > 0, totals  # the sequences did reach errors and successes
    print(f"{len(runs)} sequences of {CALLS} calls, statuses {dict(sorted(totals.items()))}, no signal")
