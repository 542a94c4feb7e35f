"""The models traced to C (dsc_fmu.fmubuild.trace, emit_c, traced_models): compiled with Zig, called through ctypes,
bit for bit equal to CPython on thousands of random points per function, each branch of the law counted
(docs/traced-c.md)."""

from __future__ import annotations

import ctypes
import math
import random
import struct
from types import SimpleNamespace

import pytest

from dsc_fmu.fmu.controller_model import DSCControllerModel
from dsc_fmu.fmu.directional import seeded
from dsc_fmu.fmu.robot_models import MobileRobotModel, ReferenceRobotModel
from dsc_fmu.fmu.slave import ModelSlave
from dsc_fmu.fmubuild.trace import TRACE_MATH, Untraceable, trace
from dsc_fmu.fmubuild.traced_models import compile_library, trace_models
from dsc_fmu.models.controller import Switches, control_law, switches
from dsc_fmu.models.dual import DUAL_MATH, tangent
from dsc_fmu.models.rk4 import rk4_integrate

MODELS = {"plant": MobileRobotModel, "reference": ReferenceRobotModel, "controller": DSCControllerModel}
P = ctypes.POINTER(ctypes.c_double)


@pytest.fixture(scope="module")
def traced():
    return trace_models()


@pytest.fixture(scope="module")
def library(traced, tmp_path_factory):
    return ctypes.CDLL(str(compile_library(traced.source, tmp_path_factory.mktemp("traced"))))


def _array(values):
    return (ctypes.c_double * max(1, len(values)))(*values)


def _call(library, name, arguments, outputs):
    """``name(*arguments, out)``: arrays for lists, doubles for floats; the outputs and the fault flag."""
    out = _array([0.0] * outputs)
    fault = getattr(library, name)(*(_array(a) if isinstance(a, list) else ctypes.c_double(a) for a in arguments), out)
    return list(out), fault


def _bits(value) -> bytes:
    value = float(value)
    return b"nan" if value != value else struct.pack("<d", value)


def _same(c_values, python_values) -> bool:
    return [_bits(v) for v in c_values] == [_bits(v) for v in python_values]


def _parameters(kind, rng, spread=0.2):
    """The model's parameters by name, the Real ones each scaled by a random factor in [1 - spread, 1 + spread]."""
    model = MODELS[kind]()
    return {v.name: v.start if v.integer else v.start * rng.uniform(1 - spread, 1 + spread) + (0.0 if v.start else
            rng.uniform(-0.1, 0.1)) for v in model.PARAMETERS}


def _model(kind, p, held=None):
    model = MODELS[kind]()
    model.p = dict(p)
    model.held = held if kind == "controller" else None
    return model


def _measurements(rng, case):
    """Controller inputs: ``case`` 0 anywhere (wraps), 1 on the reference (alpha2's series), 2 behind it (beta guard),
    3 the heading error exactly -pi."""
    theta, thetar = rng.uniform(-8, 8), rng.uniform(-8, 8)
    x, y = rng.uniform(-5, 5), rng.uniform(-5, 5)
    xr, yr = x + rng.uniform(-2, 2), y + rng.uniform(-2, 2)
    vr = rng.uniform(0.1, 2.0)
    if case == 1:
        xr, yr, thetar = x, y, theta + rng.uniform(-1.5e-4, 1.5e-4)
    elif case == 2:
        d = rng.uniform(0.5, 3.0)
        xr, yr = x - d * math.cos(theta), y - d * math.sin(theta)
    elif case == 3:
        theta, thetar = math.pi, 0.0
    return [x, y, theta, rng.uniform(-2, 2), rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(-3, 3),
            rng.uniform(-3, 3), xr, yr, thetar, vr, rng.uniform(-1, 1), rng.uniform(-1, 1)]


def test_plant_rates_and_outputs_bit_for_bit(library):
    rng = random.Random(1)
    for _ in range(2000):
        p = _parameters("plant", rng)
        x = [rng.uniform(-10, 10) for _ in range(7)]
        u = [rng.uniform(-12, 12) for _ in range(2)]
        t = rng.uniform(0, 30)
        model = _model("plant", p)
        for hook, count in (("rates", 7), ("outputs", 8)):
            values, fault = _call(library, f"dsc_plant_{hook}", [list(p.values()), t, x, u], count)
            assert fault == 0 and _same(values, getattr(model, hook)(t, x, u)), (hook, p, x, u)


@pytest.mark.parametrize("profile", [0, 1])
def test_reference_rates_bit_for_bit_both_profiles(library, profile):
    rng = random.Random(2 + profile)
    for _ in range(1000):
        p = {**_parameters("reference", rng), "profile": profile}
        x, t = [rng.uniform(-10, 10) for _ in range(3)], rng.uniform(0, 100)
        values, fault = _call(library, "dsc_reference_rates", [list(p.values()), t, x], 3)
        assert fault == 0 and _same(values, _model("reference", p).rates(t, x, None)), (p, x, t)


def _controller_cases(rng, count):
    for i in range(count):
        p = _parameters("controller", rng, spread=0.1)
        xc = [rng.uniform(-2, 2) for _ in range(20)]
        case = i % 4 if i % 4 != 3 or i % 40 == 3 else 0
        yield case, p, xc, _measurements(rng, case)


@pytest.mark.parametrize("held", [False, True], ids=["cosimulation", "model-exchange"])
def test_controller_bit_for_bit_on_every_branch(library, held):
    rng = random.Random(4 + held)
    branches = {"wrap": 0, "wrap to pi": 0, "series": 0, "guarded": 0, "unguarded": 0}
    suffix = "_held" if held else ""
    for case, p, xc, m in _controller_cases(rng, 3000):
        model = _model("controller", p)
        chosen = switches(model.constants, m)
        turns = chosen.turns + (0 if case == 1 else rng.choice((-1, 0, 1)))
        s = Switches(turns, rng.random() < 0.5) if held else None
        model.held = s
        law = control_law(model.constants, xc, m, s)
        branches["wrap"] += abs(m[10] - m[2]) > math.pi
        branches["wrap to pi"] += m[10] - m[2] == -math.pi
        branches["series"] += abs(0.5 * law.S13) < 1e-4
        branches["guarded" if law.guarded else "unguarded"] += 1
        arguments = [list(p.values()), 0.0, xc, m, *([[float(s.turns), float(s.guarded)]] if held else [])]
        for hook, count in (("rates", 20), ("outputs", 24)):
            values, fault = _call(library, f"dsc_controller_{hook}{suffix}", arguments, count)
            assert fault == 0 and _same(values, getattr(model, hook)(0.0, xc, m)), (hook, p, xc, m, s)
    assert min(branches.values()) >= (60 if held else 70), branches
    assert branches["series"] >= 700 and branches["guarded"] >= 300 and branches["wrap"] >= 900, branches


def test_derivative_code_equals_the_dual_numbers(library):
    rng = random.Random(6)
    for i in range(1500):
        kind = ("plant", "reference", "controller")[i % 3]
        model = _model(kind, _parameters(kind, rng, spread=0.1))
        states = {"plant": 7, "reference": 3, "controller": 20}[kind]
        x = [rng.uniform(-3, 3) for _ in range(states)]
        u = {"plant": [rng.uniform(-3, 3) for _ in range(2)], "controller": _measurements(rng, i % 3),
             "reference": None}[kind]
        dx = [0.0 if rng.random() < 0.3 else rng.uniform(-1, 1) for _ in x]
        du = None if u is None else [0.0 if rng.random() < 0.3 else rng.uniform(-1, 1) for _ in u]
        xs = seeded(x, dict(enumerate(dx)))
        us = None if u is None else seeded(u, dict(enumerate(du)))
        for hook in ("rates", "outputs") if kind != "reference" else ("rates",):
            python = getattr(model, hook)(0.5, xs, us, DUAL_MATH)
            count = len(python)
            out, dout = _array([0.0] * count), _array([0.0] * count)
            arguments = [_array(list(model.p.values())), ctypes.c_double(0.5), _array(x)]
            arguments += [] if u is None else [_array(u)]
            arguments += [_array(dx)] + ([] if u is None else [_array(du)])
            fault = getattr(library, f"dsc_{kind}_{hook}_tangent")(*arguments, out, dout)
            assert fault == 0
            assert _same(list(out), [v.value if hasattr(v, "value") else v for v in python]), (kind, hook)
            assert _same(list(dout), [tangent(v) for v in python]), (kind, hook, x, u, dx, du)


def _python_rk4(kind, p, t0, x, inputs, step_size, count):
    """``models.rk4.rk4_integrate`` of the model's rates at the inputs ``inputs(t)``, and for the controller the first
    guarded (t, beta), as ``DSCControllerModel.integrate`` records it."""
    model, seen = _model(kind, p), []

    def rates(t, x):
        if kind != "controller":
            return model.rates(t, x, inputs(t))
        law = control_law(model.constants, x, inputs(t))
        if law.guarded and not seen:
            seen.append((t, law.beta))
        return law.derivative

    return rk4_integrate(rates, t0, x, step_size, step_size / count), seen


@pytest.mark.parametrize("kind, line", [("plant", False), ("plant", True), ("controller", False), ("controller", True),
                                        ("reference", False)])
def test_rk4_loops_bit_for_bit(library, kind, line):
    rng = random.Random(7)
    states = {"plant": 7, "reference": 3, "controller": 20}[kind]
    guarded = 0
    for i in range(600):
        p = _parameters(kind, rng, spread=0.1)
        if kind == "reference":
            p["profile"] = i % 2
        x = [rng.uniform(-2, 2) for _ in range(states)]
        u = {"plant": [rng.uniform(-12, 12) for _ in range(2)], "controller": _measurements(rng, i % 3),
             "reference": None}[kind]
        t0, step_size = rng.uniform(0, 30), rng.choice((1e-3, 0.01, 0.05))
        slope = [rng.uniform(-0.5, 0.5) for _ in u] if line else None
        stamp = t0 + rng.choice((0.0, step_size))
        held = SimpleNamespace(u=u, _slope=slope, _stamp=stamp)
        expected, seen = _python_rk4(kind, p, t0, x, lambda t: ModelSlave.inputs(held, t), step_size, 10)
        state, watch = _array(x), _array([0.0, 0.0, 0.0])
        arguments = [_array(list(p.values()))] + ([] if u is None else [_array(u)])
        arguments += [_array(slope), ctypes.c_double(stamp)] if line else []
        arguments += [ctypes.c_double(t0), ctypes.c_double(step_size), ctypes.c_long(10), state]
        function = getattr(library, f"dsc_{kind}_rk4{'_line' if line else ''}")
        function.argtypes = [P] * (1 + (u is not None)) + ([P, ctypes.c_double] if line else [])
        function.argtypes += [ctypes.c_double, ctypes.c_double, ctypes.c_long, P]
        function.argtypes += [P] if kind == "controller" else []
        fault = function(*arguments, *([watch] if kind == "controller" else []))
        assert fault == 0 and _same(list(state), expected), (kind, p, x, u, t0, step_size)
        if kind == "controller":
            assert _same(list(watch), [1.0, *seen[0]] if seen else [0.0, 0.0, 0.0])
            guarded += bool(seen)
    assert kind != "controller" or guarded >= 100


def test_raising_in_python_is_flagged(library):
    p = {v.name: v.start for v in MobileRobotModel.PARAMETERS}
    p["La1"] = 0.0
    with pytest.raises(ZeroDivisionError):
        _model("plant", p).rates(0.0, [0.0] * 7, [1.0, 1.0])
    _, fault = _call(library, "dsc_plant_rates", [list(p.values()), 0.0, [0.0] * 7, [1.0, 1.0]], 7)
    assert fault == 1


@pytest.mark.parametrize("body, reason", [
    (lambda x: [math.floor(x[0])], "TypeError"),
    (lambda x: [float(x[0]) * 2.0], "TypeError"),
    (lambda x: [TRACE_MATH.sin(x[0]) if x[0] < i else x[0] for i in range(10)], "combinations"),
], ids=["math module", "float()", "too many decisions"])
def test_untraceable_functions_are_named_with_the_reason(body, reason, monkeypatch):
    monkeypatch.setattr("dsc_fmu.fmubuild.trace.MAX_PATHS", 8)
    with pytest.raises(Untraceable, match=f"^my_function: .*{reason}"):
        trace(lambda x: body(x), {"x": 1}, "my_function")


def test_the_untraceable_model_functions_are_reported_by_name(traced):
    for name, reason in traced.untraceable.items():
        assert reason.startswith(f"{name}: ")
    assert {"dsc_plant_rates", "dsc_controller_rates", "dsc_controller_rates_held", "dsc_controller_rk4",
            "dsc_plant_rk4", "dsc_reference_rates", "dsc_controller_rk4_line"} <= set(traced.functions)
