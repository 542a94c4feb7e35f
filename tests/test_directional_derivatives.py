"""Directional and adjoint derivatives of the slaves, in this process, against independent derivatives.

Every Jacobian entry of each slave (model exchange: state derivatives and outputs by states and inputs;
co-simulation: outputs by inputs) against 4th-order central differences of the same slave's own values,
read and set by value reference as the binary does; the model-exchange derivatives also against the
complex step of the slave's ``rates`` on ``cmath``. Points: the paper's loop after 5 s, and on both sides
of the wrap (``thetar - theta`` near +-pi) and of the beta guard (``beta`` near ``beta_min``). Then the
entries the paper gives in closed form ((1), (5)), linearity in the seed, the adjoint as the transpose,
and the refusals.
"""

import cmath
import math
import random
from types import SimpleNamespace

import pytest

from dsc_fmu.models import parameters as P
from dsc_fmu.models.adaptation import E_MODIFICATION, NONE, PROJECTION
from dsc_fmu.models.controller import Switches, control_law, gains
from dsc_fmu.models.dual import DUAL_MATH, Dual
from drives import CONTROLLER, CONTROLLER_IN, NAMES, PLANT, PLANT_OUT
from in_process import InProcess

REFERENCE_OUT = tuple(v.name for v in P.REFERENCE_OUTPUTS)
STEP = 1e-3
RELATIVE = 1e-8
EPS = 2.0 ** -52
# The complex step: cmath's functions where the models take math's (the held switches avoid comparisons).
CMATH = SimpleNamespace(pi=math.pi, sin=cmath.sin, cos=cmath.cos, atan=cmath.atan, sqrt=cmath.sqrt, fsum=sum)
COMPLEX_STEP = 1e-100


def _paper_loop(fmi_version: int, stop: float) -> dict:
    """The FMU states of the three slaves after the paper's loop (Gauss-Seidel, hold) up to ``stop``."""
    ref, plant, ctrl = (InProcess(name, fmi_version).initialize() for name in NAMES)

    def measure():
        ctrl.set(CONTROLLER_IN, plant.get(PLANT_OUT) + ref.get(REFERENCE_OUT))

    measure()
    plant.set(("u1", "u2"), ctrl.get(("u1", "u2")))
    for k in range(round(stop / STEP)):
        t = k * STEP
        ref.step(t, STEP)
        plant.step(t, STEP)
        measure()
        ctrl.step(t, STEP)
        plant.set(("u1", "u2"), ctrl.get(("u1", "u2")))
    return {name: inst.get_state() for name, inst in zip(NAMES, (ref, plant, ctrl))}


@pytest.fixture(scope="module")
def after_5s():
    """FMI version -> the slaves' FMU states 5 s into the paper's run."""
    return {version: _paper_loop(version, 5.0) for version in (2, 3)}


def _slave(name: str, version: int, saved: dict, model_exchange: bool, inputs: dict | None = None,
           held_at: dict | None = None) -> InProcess:
    """A slave at the saved point, with ``inputs`` set; in model exchange its switches chosen at ``held_at``
    (default: at the point) as the end of initialization chooses them."""
    inst = InProcess(name, version).initialize()
    inst.set_state(saved)
    if model_exchange:
        if held_at:
            inst.set(list(held_at), list(held_at.values()))
        inst.slave.start_continuous_time()
    if inputs:
        inst.set(list(inputs), list(inputs.values()))
    return inst


def _unknowns(inst: InProcess, model_exchange: bool) -> list:
    derivatives = [s.derivative.name for s in inst.slave.model.STATES] if model_exchange else []
    return derivatives + [v.name for v in inst.slave.model.OUTPUTS]


def _knowns(inst: InProcess, model_exchange: bool) -> list:
    states = [s.variable.name for s in inst.slave.model.STATES] if model_exchange else []
    return states + [v.name for v in inst.slave.model.INPUTS]


def _jacobian(inst: InProcess, unknowns: list, knowns: list, model_exchange: bool) -> list:
    """J[i][j] by ``directional_derivative`` with unit seeds, one column per call."""
    refs = [inst.vr[n] for n in unknowns]
    columns = [inst.slave.directional_derivative(refs, [inst.vr[k]], [1.0], model_exchange) for k in knowns]
    return [list(row) for row in zip(*columns)]


def _differences(inst: InProcess, unknowns: list, knowns: list) -> tuple:
    """J[i][j] by 4th-order central differences of the slave's values, set and read by value reference, and
    the rounding noise of each: 20 ulp of the largest value differenced over the step."""
    columns, noise = [], []
    for known in knowns:
        base = inst.get1(known)
        h = 1e-5 * max(1.0, abs(base))
        values = []
        for k in (2, 1, -1, -2):
            inst.set([known], [base + k * h])
            values.append(inst.get(unknowns))
        inst.set([known], [base])
        columns.append([(-a + 8.0 * b - 8.0 * c + d) / (12.0 * h) for a, b, c, d in zip(*values)])
        noise.append([20.0 * EPS * max(map(abs, four)) / h for four in zip(*values)])
    return [list(row) for row in zip(*columns)], [list(row) for row in zip(*noise)]


def _assert_close(got: list, expected: list, unknowns: list, knowns: list, relative: float = RELATIVE,
                  noise: list | None = None) -> None:
    """Each entry within ``relative`` of the larger of itself and a thousandth of its row's largest entry
    (a row's large entries carry the rounding of the small ones), plus the reference's own rounding ``noise``."""
    bad = []
    noise = noise or [[0.0] * len(knowns) for _ in unknowns]
    for name, row, reference, rounding in zip(unknowns, got, expected, noise):
        floor = 1e-3 * max(abs(v) for v in reference)
        for known, a, b, e in zip(knowns, row, reference, rounding):
            if abs(a - b) > relative * max(abs(b), floor) + e:
                bad.append(f"d {name} / d {known}: {a!r} vs {b!r}")
    assert not bad, "\n".join(bad[:20])


def _assert_differences(inst: InProcess, jacobian: list, unknowns: list, knowns: list) -> None:
    """``jacobian`` agrees with central differences of the slave's values (``_assert_close``)."""
    expected, noise = _differences(inst, unknowns, knowns)
    _assert_close(jacobian, expected, unknowns, knowns, noise=noise)


def _controller_inputs(saved: dict, **changes) -> dict:
    """The controller's inputs of the saved point with ``changes`` by name."""
    inputs = dict(zip(CONTROLLER_IN, saved["u"]))
    inputs.update(changes)
    return inputs


def _heading_inputs(saved: dict, heading: float) -> dict:
    """Inputs with ``thetar - theta = heading``."""
    inputs = _controller_inputs(saved)
    return _controller_inputs(saved, theta_r=inputs["theta"] + heading)


def _beta_inputs(saved: dict, beta: float) -> dict:
    """Inputs with ``S12 = 0`` and ``beta = 1 + k1 vr S11`` of (13) equal to ``beta``."""
    inputs = _controller_inputs(saved)
    S11 = (beta - 1.0) / (CONTROLLER["k1"] * inputs["v_r"])
    theta = inputs["theta"]
    return _controller_inputs(saved, x=inputs["x_r"] - S11 * math.cos(theta), y=inputs["y_r"] - S11 * math.sin(theta))


BETA_MIN = CONTROLLER["beta_min"]
# Controller points: name -> the inputs that make it (None: the point of the run).
CONTROLLER_POINTS = {
    "after 5 s": lambda saved: None,
    "wrap at +pi, below": lambda saved: _heading_inputs(saved, math.pi - 1e-2),
    "wrap at +pi, above": lambda saved: _heading_inputs(saved, math.pi + 1e-2),
    "wrap at -pi, above": lambda saved: _heading_inputs(saved, -math.pi + 1e-2),
    "wrap at -pi, below": lambda saved: _heading_inputs(saved, -math.pi - 1e-2),
    "beta above beta_min": lambda saved: _beta_inputs(saved, BETA_MIN + 2e-3),
    "beta below beta_min": lambda saved: _beta_inputs(saved, BETA_MIN - 2e-3),
}
CASES = [("ReferenceRobot", "after 5 s"), ("MobileRobot", "after 5 s"),
         *(("DSCController", point) for point in CONTROLLER_POINTS)]


def _at(after_5s, version: int, name: str, point: str, model_exchange: bool) -> InProcess:
    saved = after_5s[version][name]
    inputs = CONTROLLER_POINTS[point](saved) if name == "DSCController" else None
    return _slave(name, version, saved, model_exchange, inputs, held_at=inputs)


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name, point, model_exchange", [
    pytest.param(name, point, model_exchange, id=f"{name}-{point}-{'ME' if model_exchange else 'CS'}")
    for name, point in CASES for model_exchange in (True, False)
    if model_exchange or name != "ReferenceRobot"  # no inputs: no knowns in co-simulation
])
def test_every_entry_equals_central_differences_of_the_slaves_values(after_5s, version, model_exchange, name, point):
    inst = _at(after_5s, version, name, point, model_exchange)
    unknowns, knowns = _unknowns(inst, model_exchange), _knowns(inst, model_exchange)
    jacobian = _jacobian(inst, unknowns, knowns, model_exchange)
    _assert_differences(inst, jacobian, unknowns, knowns)
    feedthrough = {(unknown, known) for i, unknown in enumerate(unknowns) for j, known in enumerate(knowns)
                   if jacobian[i][j]}
    if name == "MobileRobot" and not model_exchange:  # the applied voltages are the plant's only feedthrough
        assert feedthrough == {("u1_applied", "u1"), ("u2_applied", "u2")}
    else:
        assert feedthrough


def test_the_points_are_on_the_sides_of_the_switches_they_name(after_5s):
    saved = after_5s[2]["DSCController"]
    law = {point: control_law(gains(CONTROLLER), saved["state"], list(make(saved).values()))
           for point, make in CONTROLLER_POINTS.items() if make(saved)}
    assert law["wrap at +pi, below"].S13 - law["wrap at +pi, above"].S13 == pytest.approx(2 * math.pi - 2e-2, rel=1e-3)
    assert law["wrap at -pi, below"].S13 - law["wrap at -pi, above"].S13 == pytest.approx(2 * math.pi - 2e-2, rel=1e-3)
    assert not law["beta above beta_min"].guarded and law["beta below beta_min"].guarded


def _rates_complex_step(inst: InProcess) -> list:
    """d rates / d (states, inputs) by the complex step of the slave's own ``rates`` on ``cmath``."""
    slave = inst.slave
    x, u = list(slave.current_state()), list(slave.u)
    columns = []
    for values in (x, u):
        for j in range(len(values)):
            saved = values[j]
            values[j] = complex(saved, COMPLEX_STEP)
            columns.append([complex(r).imag / COMPLEX_STEP for r in slave.model.rates(slave.time, x, u, CMATH)])
            values[j] = saved
    return [list(row) for row in zip(*columns)]


@pytest.mark.parametrize("name, point", CASES)
def test_model_exchange_derivatives_equal_the_complex_step(after_5s, name, point):
    """With the switches held, the right-hand side is analytic: the complex step is exact to rounding."""
    inst = _at(after_5s, 2, name, point, True)
    unknowns = [s.derivative.name for s in inst.slave.model.STATES]
    knowns = _knowns(inst, True)
    expected = _rates_complex_step(inst)
    _assert_close(_jacobian(inst, unknowns, knowns, True), expected, unknowns, knowns, relative=1e-12)


def test_model_exchange_holds_the_wrap_across_pi(after_5s):
    """Switches held below +pi, evaluated above it without an event: the held branch's derivative."""
    saved = after_5s[2]["DSCController"]
    inst = _slave("DSCController", 2, saved, True, _heading_inputs(saved, math.pi + 1e-2),
                  held_at=_heading_inputs(saved, math.pi - 1e-2))
    assert inst.slave.model.held == Switches(0, False)
    unknowns, knowns = _unknowns(inst, True), _knowns(inst, True)
    _assert_differences(inst, _jacobian(inst, unknowns, knowns, True), unknowns, knowns)


def _on_the_boundaries(saved: dict) -> dict:
    """Projection bounds with each estimate of the saved point on its set's boundary, on the side its gradient
    rate points to: the projection acts on all four."""
    x, m = saved["state"], saved["u"]
    rates = control_law(gains({**CONTROLLER, "adaptation": NONE}), x, m).derivative
    bounds = {"adaptation": PROJECTION}
    for name, i in (("a1", 0), ("a2", 1)):
        bounds[f"{name}_min"], bounds[f"{name}_max"] = (x[i] - 5.0, x[i]) if rates[i] > 0 else (x[i], x[i] + 5.0)
    for name, part in (("W1", slice(4, 12)), ("W2", slice(14, 20))):
        bounds[f"{name}_max"] = math.sqrt(math.fsum(w * w for w in x[part]))
    return bounds


# The adaptation laws at the point of the run: name -> (the controller's parameters, the projection's switches).
LAWS = {
    "e": (lambda saved: {"adaptation": E_MODIFICATION}, (False,) * 4),
    "none": (lambda saved: {"adaptation": NONE}, (False,) * 4),
    "projection inside its sets": (lambda saved: {"adaptation": PROJECTION}, (False,) * 4),
    "projection acting on each estimate": (_on_the_boundaries, (True,) * 4),
}


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("law", LAWS)
def test_the_adaptation_laws_entries_equal_central_differences(after_5s, version, law):
    """Model exchange (the laws change only the state derivatives): each law's branch, the projection's held."""
    saved = dict(after_5s[version]["DSCController"])
    parameters, projected = LAWS[law]
    saved["p"] = {**saved["p"], **parameters(saved)}
    inst = _slave("DSCController", version, saved, True)
    assert inst.slave.model.held.projected == projected
    unknowns, knowns = _unknowns(inst, True), _knowns(inst, True)
    _assert_differences(inst, _jacobian(inst, unknowns, knowns, True), unknowns, knowns)


def test_co_simulation_before_the_first_step_follows_the_filters_start(after_5s):
    """Until the first step the filters follow the inputs (docs/model.md §5.2): so do the derivatives."""
    inst = InProcess("DSCController", 2).initialize()
    inst.set(CONTROLLER_IN, list(after_5s[2]["DSCController"]["u"]))
    unknowns, knowns = _unknowns(inst, False), _knowns(inst, False)
    _assert_differences(inst, _jacobian(inst, unknowns, knowns, False), unknowns, knowns)


@pytest.mark.parametrize("version", (2, 3))
def test_the_plant_entries_the_paper_gives(after_5s, version):
    """Kinematics (1) and motors (5): d x_dot / d theta = -v sin(theta), d i1_dot / d u1 = 1 / La1, ..."""
    inst = _at(after_5s, version, "MobileRobot", "after 5 s", True)
    x, y, theta, w1, w2, i1, i2 = inst.slave.current_state()
    r, R = PLANT["r"], PLANT["R"]
    v = 0.5 * r * (w1 + w2)
    expected = {
        ("der(x)", "theta"): -v * math.sin(theta),
        ("der(y)", "theta"): v * math.cos(theta),
        ("der(x)", "omega1"): 0.5 * r * math.cos(theta),
        ("der(y)", "omega2"): 0.5 * r * math.sin(theta),
        ("der(theta)", "omega1"): 0.5 * r / R,
        ("der(theta)", "omega2"): -0.5 * r / R,
        ("theta_dot", "omega1"): 0.5 * r / R,
        ("der(i1)", "u1"): 1.0 / PLANT["La1"],
        ("der(i2)", "u2"): 1.0 / PLANT["La2"],
        ("der(i1)", "i1"): -PLANT["Ra1"] / PLANT["La1"],
        ("der(i2)", "omega2"): -PLANT["N2"] * PLANT["KE2"] / PLANT["La2"],
        ("der(i1)", "u2"): 0.0,
        ("der(x)", "x"): 0.0,
    }
    got = {key: inst.slave.directional_derivative([inst.vr[key[0]]], [inst.vr[key[1]]], [1.0], True)[0]
           for key in expected}
    assert got == pytest.approx(expected, rel=1e-14, abs=1e-300)
    assert inst.slave.directional_derivative([inst.vr["der(i1)"]], [inst.vr["theta"]], [1.0], True) == [0.0]


@pytest.mark.parametrize("model_exchange", (True, False), ids=("ME", "CS"))
@pytest.mark.parametrize("name", ("MobileRobot", "DSCController"))
def test_linear_in_the_seed_and_the_adjoint_is_the_transpose(after_5s, name, model_exchange):
    inst = _at(after_5s, 2, name, "after 5 s", model_exchange)
    slave = inst.slave
    unknowns = [inst.vr[n] for n in _unknowns(inst, model_exchange)]
    knowns = [inst.vr[n] for n in _knowns(inst, model_exchange)]
    rng = random.Random(28)
    s1, s2 = ([rng.uniform(-1, 1) for _ in knowns] for _ in range(2))
    a, b = 0.7, -1.9

    def forward(seed):
        return slave.directional_derivative(unknowns, knowns, seed, model_exchange)

    combined = forward([a * p + b * q for p, q in zip(s1, s2)])
    assert combined == pytest.approx([a * p + b * q for p, q in zip(forward(s1), forward(s2))], rel=1e-12, abs=1e-9)
    jacobian = _jacobian(inst, _unknowns(inst, model_exchange), _knowns(inst, model_exchange), model_exchange)
    # Unit seeds: the adjoint's entry is the forward column's, bit for bit.
    for i in range(len(unknowns)):
        row = slave.adjoint_derivative(unknowns, knowns, [float(k == i) for k in range(len(unknowns))], model_exchange)
        assert row == jacobian[i]
    weights = [rng.uniform(-1, 1) for _ in unknowns]
    expected = [math.fsum(w * jacobian[i][j] for i, w in enumerate(weights)) for j in range(len(knowns))]
    assert slave.adjoint_derivative(unknowns, knowns, weights, model_exchange) == pytest.approx(expected, rel=1e-12,
                                                                                               abs=1e-12)


def test_repeated_knowns_add_their_seeds(after_5s):
    inst = _at(after_5s, 2, "DSCController", "after 5 s", True)
    unknowns = [inst.vr[n] for n in _unknowns(inst, True)]
    theta = inst.vr["theta"]
    twice = inst.slave.directional_derivative(unknowns, [theta, theta], [1.0, 2.0], True)
    assert twice == pytest.approx(inst.slave.directional_derivative(unknowns, [theta], [3.0], True), rel=1e-15)
    adjoint = inst.slave.adjoint_derivative(unknowns[:1], [theta, theta], [1.0], True)
    assert adjoint[0] == adjoint[1]


def test_the_dual_values_are_the_float_values(after_5s):
    """One source of the equations: the law on duals has the values of the law on floats, bit for bit."""
    saved = after_5s[2]["DSCController"]
    g, x, m = gains(CONTROLLER), saved["state"], list(saved["u"])
    floats = control_law(g, x, m)
    duals = control_law(g, [Dual(v, 1.0) for v in x], [Dual(v, 1.0) for v in m], math=DUAL_MATH)
    assert [d.value for d in duals.derivative] == floats.derivative
    assert (duals.u1.value, duals.u2.value, duals.S13.value, duals.beta.value) == (
        floats.u1, floats.u2, floats.S13, floats.beta)


REFUSALS = [
    # (model exchange, unknowns, knowns, seed, message)
    (True, ["x"], ["theta"], [1.0], r"value reference \d+ \(x\) is a (Real|Float64) input, not an unknown of model "
     r"exchange; allowed unknowns: state derivatives and Real outputs"),
    (True, ["u1"], ["beta_guard_count"], [1.0], r"\(beta_guard_count\) is an? (Integer|Int32) output, not a known of "
     r"model exchange; allowed knowns: continuous states and Real inputs"),
    (True, ["u1"], ["k1"], [1.0], r"\(k1\) is a (Real|Float64) parameter, not a known"),
    (True, ["x2f1"], ["theta"], [1.0], r"\(x2f1\) is a continuous state, not an unknown of model exchange"),
    (True, ["wrap_indicator"], ["theta"], [1.0], r"\(wrap_indicator\) is a (Real|Float64) local, not an unknown"),
    (False, ["der(a1_hat)"], ["theta"], [1.0], r"\(der\(a1_hat\)\) is a state derivative, not an unknown of "
     r"co-simulation; allowed unknowns: Real outputs"),
    (False, ["u1"], ["a1_hat"], [1.0], r"\(a1_hat\) is a continuous state and a (Real|Float64) output, not a known of "
     r"co-simulation; allowed knowns: Real inputs"),
    (True, ["u1"], [99999], [1.0], r"value reference 99999 is not a variable of DSCController; allowed knowns"),
    (True, ["u1"], ["theta", "x"], [1.0], r"the seed has 1 entry for 2 knowns; allowed: one per known"),
]


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("model_exchange, unknowns, knowns, seed, message", REFUSALS)
def test_what_is_not_allowed_is_refused_in_one_line(version, model_exchange, unknowns, knowns, seed, message):
    inst = InProcess("DSCController", version).initialize()
    refs = [[inst.vr.get(n, n) for n in names] for names in (unknowns, knowns)]
    with pytest.raises(ValueError, match=message) as raised:
        inst.slave.directional_derivative(*refs, seed, model_exchange)
    assert "\n" not in str(raised.value)


def test_the_adjoint_takes_one_seed_per_unknown():
    inst = InProcess("MobileRobot").initialize()
    refs = [inst.vr[n] for n in ("der(x)", "der(y)")], [inst.vr["theta"]]
    with pytest.raises(ValueError, match=r"^the seed has 1 entry for 2 unknowns; allowed: one per unknown$"):
        inst.slave.adjoint_derivative(*refs, [1.0], True)
    assert inst.slave.adjoint_derivative(*refs, [1.0, 0.0], True) == pytest.approx(
        inst.slave.directional_derivative(refs[0][:1], refs[1], [1.0], True), rel=0)


def test_a_norm_at_a_zero_estimate_has_entries_zero():
    """||W|| has no derivative at W = 0 (docs/model.md §5.13): its entries there are 0, not a division by 0."""
    inst = InProcess("DSCController").initialize()
    inst.slave.start_continuous_time()
    assert inst.get(["W1_hat_norm", "W2_hat_norm"]) == [0.0, 0.0]
    knowns = [inst.vr[f"W1_hat_{i}"] for i in range(1, 9)] + [inst.vr[f"W2_hat_{i}"] for i in range(1, 7)]
    for name in ("W1_hat_norm", "W2_hat_norm"):
        got = inst.slave.directional_derivative([inst.vr[name]], knowns, [1.0] * len(knowns), True)
        assert got == [0.0]


def _expression(x, math):
    """Every operator of ``Dual`` with floats on either side, and every function of ``DUAL_MATH``."""
    y = (x * 2.0 - 1.0) / (x + 3.0) + 1.0 / x - (2.0 - x) + x * x / x - -x
    return math.atan(y) ** 3.0 + math.sqrt(x * x + 1.0) * math.cos(x) + math.sin(y) + math.fsum([x, y, 0.5])


@pytest.mark.parametrize("x", (0.3, -1.7, 2.9))
def test_the_dual_rules_equal_the_complex_step(x):
    dual = _expression(Dual(x, 1.0), DUAL_MATH)
    step = _expression(complex(x, COMPLEX_STEP), CMATH)
    assert dual.value == _expression(x, math)
    assert dual.tangent == pytest.approx(step.imag / COMPLEX_STEP, rel=1e-14)


def test_the_dual_switches_take_the_branch_of_the_value():
    assert (abs(Dual(-2.0, 1.0)).tangent, abs(Dual(2.0, 1.0)).tangent) == (-1.0, 1.0)
    wrapped = DUAL_MATH.remainder(Dual(3.0 * math.pi / 2, 1.0), 2.0 * math.pi)
    assert (wrapped.value, wrapped.tangent) == (math.remainder(3.0 * math.pi / 2, 2.0 * math.pi), 1.0)
    assert Dual(1.0, 5.0) < 2.0 and Dual(1.0, 5.0) == Dual(1.0, -5.0) and not Dual(1.0) > Dual(1.0)
    with pytest.raises(TypeError):
        math.sin(Dual(1.0, 1.0))  # no conversion to float: the tangent is never lost silently
