"""The models traced to C (dsc_fmu.fmubuild.trace, emit_c, traced_models): compiled with Zig, called through ctypes,
bit for bit equal to CPython on thousands of random points per function (``traced_cases``), each branch of the law
counted (docs/traced-c.md)."""

from __future__ import annotations

import ctypes
import math
import random

import pytest

import traced_cases
from dsc_fmu.fmu.robot_models import MobileRobotModel
from dsc_fmu.fmubuild.trace import TRACE_MATH, Untraceable, trace
from dsc_fmu.fmubuild.traced_models import compile_library, trace_models
from dsc_fmu.models.controller import control_law
from traced_cases import call, model, same


@pytest.fixture(scope="module")
def traced():
    return trace_models()


@pytest.fixture(scope="module")
def library(traced, tmp_path_factory):
    return ctypes.CDLL(str(compile_library(traced.source, tmp_path_factory.mktemp("traced"))))


def test_plant_rates_and_outputs_bit_for_bit(library):
    assert traced_cases.plant(library) == (None, {"cases": 2000})


@pytest.mark.parametrize("profile", [0, 1])
def test_reference_rates_bit_for_bit_both_profiles(library, profile):
    assert traced_cases.reference(library, profile) == (None, {"cases": 1000})


@pytest.mark.parametrize("held", [False, True], ids=["cosimulation", "model-exchange"])
def test_controller_bit_for_bit_on_every_branch(library, held):
    differing, branches = traced_cases.controller(library, held)
    assert differing is None
    assert min(branches.values()) >= (60 if held else 70), branches
    assert branches["series"] >= 700 and branches["guarded"] >= 800 and branches["wrap"] >= 1300, branches


def test_derivative_code_equals_the_dual_numbers(library):
    assert traced_cases.tangents(library) == (None, {"cases": 1500})


def test_the_controllers_initial_state_and_its_tangents_bit_for_bit(library):
    assert traced_cases.start(library) == (None, {"cases": 1000})


@pytest.mark.parametrize("kind, line", traced_cases.RK4)
def test_rk4_loops_bit_for_bit(library, kind, line):
    differing, counts = traced_cases.rk4(library, kind, line)
    assert differing is None
    assert kind != "controller" or counts["guarded"] >= 100, counts


def test_raising_in_python_is_flagged(library):
    p = {v.name: v.start for v in MobileRobotModel.PARAMETERS}
    p["La1"] = 0.0
    with pytest.raises(ZeroDivisionError):
        model("plant", p).rates(0.0, [0.0] * 7, [1.0, 1.0])
    _, fault = call(library, "dsc_plant_rates", [list(p.values()), 0.0, [0.0] * 7, [1.0, 1.0]], 7)
    assert fault == 1


def test_the_side_not_taken_may_divide_by_zero(library):
    """On the reference with no heading error, S13 = 0: Python takes alpha2's series, C also computes sin(0) / 0 on
    the other side of the select, gets NaN and discards it; no fault, Python's bits."""
    p = {v.name: v.start for v in model("controller", {}).PARAMETERS}
    m = [1.0, 2.0, 0.5, 0.1, 3.0, 2.0, 0.5, 0.4, 1.0, 2.0, 0.5, 1.0, 0.2, 0.0]
    xc = [0.1] * 20
    values, fault = call(library, "dsc_controller_rates", [list(p.values()), 0.0, xc, m], 20)
    assert control_law(model("controller", p).constants, xc, m).S13 == 0.0
    assert fault == 0 and same(values, model("controller", p).rates(0.0, xc, m))


@pytest.mark.parametrize("body, reason", [
    (lambda x: [math.floor(x[0])], "TypeError"),
    (lambda x: [float(x[0]) * 2.0], "TypeError"),
    (lambda x: [TRACE_MATH.sin(x[0]) if x[0] < i else x[0] for i in range(10)], "combinations"),
], ids=["math module", "float()", "too many decisions"])
def test_untraceable_functions_are_named_with_the_reason(body, reason):
    with pytest.raises(Untraceable, match=f"^my_function: .*{reason}"):
        trace(body, {"x": 1}, "my_function", max_paths=8)


def test_the_untraceable_model_functions_are_reported_by_name(traced):
    for name, reason in traced.untraceable.items():
        assert reason.startswith(f"{name}: ")
    assert {"dsc_plant_rates", "dsc_controller_rates", "dsc_controller_rates_held", "dsc_controller_rk4",
            "dsc_plant_rk4", "dsc_reference_rates", "dsc_controller_rk4_line"} <= set(traced.functions)


PORTED = """#include "traced_math.h"
double hypot_(double x, double y) { return dsc_hypot(x, y); }
double remainder_(double x, double y) { return dsc_remainder(x, y); }
double fsum_(int n, const double *values, int *raised) { return dsc_fsum(n, values, raised); }
"""
SPECIAL = [0.0, -0.0, math.inf, -math.inf, math.nan, 5e-324, 1e-310, 1e308, -1e308, 1.0, math.pi, 2 * math.pi]


def test_cpythons_own_algorithms_ported_bit_for_bit(tmp_path):
    """``traced_math.h``'s hypot, remainder and fsum against CPython's: specials, subnormals, wide exponents, and
    fsum's errors (intermediate overflow, -inf + inf) as the raised flag."""
    library = ctypes.CDLL(str(compile_library(PORTED, tmp_path)))
    double = ctypes.c_double
    for name in ("hypot_", "remainder_", "fsum_"):
        getattr(library, name).restype = double
    library.hypot_.argtypes = library.remainder_.argtypes = [double, double]
    rng = random.Random(8)
    pairs = [(a, b) for a in SPECIAL for b in SPECIAL]
    pairs += [(rng.uniform(-1, 1) * 10 ** rng.uniform(-30, 30), rng.uniform(-1, 1) * 10 ** rng.uniform(-30, 30))
              for _ in range(30000)]
    pairs += [(rng.uniform(-1, 1) * 1e-315, rng.uniform(-1, 1) * 1e-318) for _ in range(2000)]
    for x, y in pairs:
        assert same([library.hypot_(x, y)], [math.hypot(x, y)]), (x, y)
        try:
            expected = math.remainder(x, y)
        except ValueError:
            expected = math.nan
        assert same([library.remainder_(x, y)], [expected]), (x, y)
    for _ in range(5000):
        values = [rng.uniform(-1, 1) * 10 ** rng.uniform(-20, 20) * rng.choice((1, 1, 1e300))
                  for _ in range(rng.randint(1, 20))]
        raised = ctypes.c_int()
        result = library.fsum_(len(values), (double * len(values))(*values), ctypes.byref(raised))
        try:
            expected = math.fsum(values)
        except (OverflowError, ValueError):
            assert raised.value == 1, values
        else:
            assert raised.value == 0 and same([result], [expected]), values
