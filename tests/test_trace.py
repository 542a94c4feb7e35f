"""The models traced to C (dsc_fmu.fmubuild.trace, emit_c, traced_models): compiled with Zig, called through ctypes,
bit for bit equal to CPython on thousands of random points per function (``traced_cases``), each branch of the law
counted (docs/traced-c.md)."""

from __future__ import annotations

import ctypes
import math
import random

import pytest

import traced_cases
from dsc_fmu.fmu.robot_models import MobileRobotModel, ReferenceRobotModel
from dsc_fmu.fmubuild.local import merged_locally
from dsc_fmu.fmubuild.specialise import specialise
from dsc_fmu.fmubuild.trace import TRACE_MATH, Untraceable, trace
from dsc_fmu.fmubuild.traced_models import compile_library, trace_models
from dsc_fmu.models.adaptation import E_MODIFICATION, NONE, PROJECTION, SIGMA
from dsc_fmu.models.controller import control_law
from dsc_fmu.models.parameters import ADAPTATIONS
from dsc_fmu.models.reference import velocity
from elf_symbols import imported_functions
from traced_cases import call, model, same

pytestmark = pytest.mark.xdist_group("traced")  # one worker compiles the library, once


@pytest.fixture(scope="module")
def traced():
    return trace_models()


@pytest.fixture(scope="module")
def library(traced, tmp_path_factory):
    return ctypes.CDLL(str(compile_library(traced.source, tmp_path_factory.mktemp("traced"))))


def test_the_library_takes_its_math_from_the_c_library(library):
    """sin, cos, atan, fmod and sqrt imported from the C library, as CPython's math module calls them: compiled at
    ``-O0`` Zig links its own compiler-rt versions instead, whose ``sin`` is one unit in the last place off."""
    assert {"sin", "cos", "atan", "fmod", "sqrt"} <= imported_functions(library._name)


@pytest.mark.parametrize("held", [False, True], ids=["cosimulation", "model-exchange"])
def test_plant_rates_outputs_and_indicators_bit_for_bit(library, held):
    """The limit on in every other case, loads on or off."""
    differing, counts = traced_cases.plant(library, held)
    assert differing is None
    assert counts["cases"] == 2000 and counts["limited"] >= 600 and counts["loaded"] >= 600, counts


@pytest.mark.parametrize("profile", [0, 1])
def test_reference_rates_and_outputs_bit_for_bit_both_profiles(library, profile):
    assert traced_cases.reference(library, profile) == (None, {"cases": 1000})


@pytest.mark.parametrize("adaptation", [SIGMA, E_MODIFICATION, PROJECTION, NONE], ids=ADAPTATIONS)
@pytest.mark.parametrize("held", [False, True], ids=["cosimulation", "model-exchange"])
def test_controller_bit_for_bit_on_every_branch(library, held, adaptation):
    differing, branches = traced_cases.controller(library, held, adaptation)
    assert differing is None
    assert min(branches.values()) >= (60 if held else 70), branches
    assert branches["series"] >= 700 and branches["guarded"] >= 750 and branches["wrap"] >= 1300, branches
    if adaptation == PROJECTION:
        estimates = [key for key in branches if key.endswith(("projected", "free"))]
        assert len(estimates) == 8 and min(branches[key] for key in estimates) >= 500, branches


def test_derivative_code_equals_the_dual_numbers(library):
    assert traced_cases.tangents(library) == (None, {"cases": 1500})


def test_the_controllers_initial_state_and_its_tangents_bit_for_bit(library):
    assert traced_cases.start(library) == (None, {"cases": 1000})


@pytest.mark.parametrize("kind, line", traced_cases.RK4)
def test_rk4_loops_bit_for_bit(library, kind, line):
    """Against the FMU model's ``integrate``: the controller's guard and projection, the plant's limit counted."""
    differing, counts = traced_cases.rk4(library, kind, line)
    assert differing is None
    assert kind != "controller" or (counts["guarded"] >= 100 and counts["projected"] >= 20), counts
    assert kind != "plant" or counts["limited"] >= 100, counts


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


def test_every_model_function_traced_behind_its_exported_name(traced):
    """All but the controller's step under ``discretization = euler``, which is not RK4: reported per law."""
    assert set(traced.untraceable) == {f"dsc_controller_rk4{line}__adaptation_{law}__discretization_euler"
                                       for law in ADAPTATIONS for line in ("", "_line")}
    assert all("discretization = euler takes one Euler step" in reason for reason in traced.untraceable.values())
    for name in ("plant_rates", "plant_rates_held", "plant_outputs", "plant_indicators_held", "plant_rk4",
                 "plant_rk4_line", "reference_rates", "reference_outputs", "reference_rk4", "controller_rates",
                 "controller_rates_held", "controller_outputs_held", "controller_indicators", "controller_rk4",
                 "controller_rk4_line", "controller_initial_state_tangent"):
        assert f"DSC_TRACED_API int dsc_{name}(" in traced.source, name
    rk4 = {f"dsc_controller_rk4__adaptation_{law}__discretization_rk4" for law in ADAPTATIONS}
    assert rk4 <= set(traced.functions)


def test_a_function_that_cannot_be_traced_is_reported_by_name(monkeypatch):
    """The figure eight's outputs without ``math`` passed on: that specialisation is named with the reason, the
    constant profile (which never calls the math) still traces."""
    monkeypatch.setattr(ReferenceRobotModel, "outputs", lambda self, t, x, u, math=math: [*x, *velocity(self.p, t)])
    traced = trace_models()
    untraceable = {name: reason for name, reason in traced.untraceable.items() if "reference" in name}
    assert untraceable == {"dsc_reference_outputs__profile_figure_eight": "dsc_reference_outputs__profile_"
                           "figure_eight: calls what a traced value cannot enter (TypeError: must be real number, "
                           "not Symbol)"}
    assert "dsc_reference_outputs__profile_constant" in traced.functions


def test_decisions_merged_locally_do_not_multiply():
    """Twenty independent ``max`` each merged where it is called: two runs each, one path for the caller."""
    local_max = merged_locally(max)
    traced = trace(lambda x: [local_max(x[i], 0.0) for i in range(20)], {"x": 20}, "maxima")
    assert traced.paths == 1 and len({traced.graph.nodes[n][0] for n in traced.outputs}) == 1


def test_choices_specialise_only_on_the_values_used():
    def make(fixed, name):
        return name, fixed["law"] == 2

    found = specialise("f", {"law": ("a", "b", "c"), "unused": ("x", "y")}, make)
    assert [(values, name, result) for values, name, result in found] == [
        ({"law": 0}, "f__law_a", ("f__law_a", False)), ({"law": 1}, "f__law_b", ("f__law_b", False)),
        ({"law": 2}, "f__law_c", ("f__law_c", True))]


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
