"""The adaptation laws (docs/model.md §3): e-modification against sigma-modification and the formula, ``none``
against sigma = 0, the projection operator's properties, its sets kept by the FMUs (co-simulation, model
exchange, FMI 2.0 and 3.0) and the reference solution, and the parameters that make no projection."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from fmpy import simulate_fmu

from dsc_fmu.cosim.master import cosimulate
from dsc_fmu.cosim.model_exchange import simulate_model_exchange
from dsc_fmu.cosim.reference_solution import reference_solution
from dsc_fmu.models import parameters as P
from dsc_fmu.models.adaptation import E_MODIFICATION, NONE, PROJECTION, SIGMA, project_estimates, project_rates
from dsc_fmu.models.controller import control_law, gains
from dsc_fmu.scenario import ScenarioError, load_scenario
from drives import CONTROLLER, CONTROLLER_IN
from in_process import InProcess

SEEDS = range(4)
W1, W2 = slice(4, 12), slice(14, 20)
# Bounds the paper's run reaches within 2.2 s (the reference solution: a1_hat 2.1 s, a2_hat 1.0 s, |W1_hat|
# 2.0 s, |W2_hat| 1.8 s); a1_hat goes below zero at first, so its interval starts below.
TIGHT = {"adaptation": PROJECTION, "a1_min": -0.05, "a1_max": 5.0, "a2_min": 0.0, "a2_max": 4.0,
         "W1_max": 0.05, "W2_max": 10.0}
SETS = {"a1_hat": (-0.05, 5.0), "a2_hat": (0.0, 4.0), "W1_hat_norm": (0.0, 0.05), "W2_hat_norm": (0.0, 10.0)}
ROUNDING = 1e-12
# Constant measurements that drive the estimates steadily (the robot's wheels turning beside the reference).
STEADY = {**{v.name: v.start for v in P.CONTROLLER_INPUTS}, "omega1": 3.0, "omega2": 2.0, "i1": 1.5}


def _gains(**changes):
    return dataclasses.replace(gains(CONTROLLER), **changes)


def _random_point(seed: int) -> tuple:
    """A controller state and measurements with every entry random (vr > 0)."""
    rng = np.random.default_rng(3600 + seed)
    x, y, theta, theta_dot, v1, v2, i1, i2, xr, yr, thetar = rng.uniform(-3.0, 3.0, 11)
    m = [x, y, theta, theta_dot, 5 * v1, 5 * v2, 10 * i1, 10 * i2, xr, yr, thetar, rng.uniform(0.2, 2.0),
         rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0)]
    return list(rng.uniform(-2.0, 2.0, 20)), [float(v) for v in m]


def _unit_norm_point(seed: int) -> tuple:
    """A point where every surface that drives a law has norm 1 exactly: the robot on the reference's position
    (S11 = S12 = 0) heading 1 rad away from it (S13 = 1), S21 = 1, S22 = 0, S31 = 1, S32 = 0."""
    xc, m = _random_point(seed)
    m[0], m[1], m[2], m[10] = m[8], m[9], 0.0, 1.0
    m[4], m[6] = 3.0, 3.0
    xc[2], xc[3], xc[12], xc[13] = 2.0, m[5], 2.0, m[7]
    return xc, m


@pytest.mark.parametrize("seed", SEEDS)
def test_e_modification_is_sigma_modification_where_each_surface_has_norm_one(seed):
    xc, m = _unit_norm_point(seed)
    sigma = control_law(_gains(adaptation=SIGMA), xc, m)
    assert (sigma.S11, sigma.S12, sigma.S13) == (0.0, 0.0, 1.0)
    assert (m[4] - xc[2], m[5] - xc[3], m[6] - xc[12], m[7] - xc[13]) == (1.0, 0.0, 1.0, 0.0)
    e = control_law(_gains(adaptation=E_MODIFICATION), xc, m)
    assert e.derivative == sigma.derivative
    assert e.derivative != control_law(_gains(adaptation=NONE), xc, m).derivative


@pytest.mark.parametrize("seed", SEEDS)
def test_e_modification_leakage_is_sigma_times_the_surface_norm(seed):
    """e - none = -gamma sigma |S| theta_hat entry by entry, |S| of (15): (S11, S12, S13); (16): S13; (21):
    (S21, S22); (27): (S31, S32), written out here."""
    xc, m = _random_point(seed)
    g = _gains(sigma1=0.3, sigma2=0.4, sigma3=0.5, sigma4=0.6)
    e = control_law(dataclasses.replace(g, adaptation=E_MODIFICATION), xc, m)
    none = control_law(dataclasses.replace(g, adaptation=NONE), xc, m)
    S2 = math.hypot(m[4] - xc[2], m[5] - xc[3])
    S3 = math.hypot(m[6] - xc[12], m[7] - xc[13])
    leak = [g.gamma1 * g.sigma1 * math.sqrt(e.S11 ** 2 + e.S12 ** 2 + e.S13 ** 2), g.gamma2 * g.sigma2 * abs(e.S13),
            0.0, 0.0, *(G * g.sigma3 * S2 for G in g.Gamma1), 0.0, 0.0, *(G * g.sigma4 * S3 for G in g.Gamma2)]
    for i, (a, b, k) in enumerate(zip(e.derivative, none.derivative, leak)):
        expected = -k * xc[i]
        assert a - b == pytest.approx(expected, rel=1e-9, abs=1e-15 * (abs(a) + abs(b))), f"entry {i}"


@pytest.mark.parametrize("seed", SEEDS)
def test_none_is_sigma_modification_with_every_sigma_zero(seed):
    xc, m = _random_point(seed)
    zero = _gains(adaptation=SIGMA, sigma1=0.0, sigma2=0.0, sigma3=0.0, sigma4=0.0)
    none = control_law(_gains(adaptation=NONE), xc, m)
    assert none.derivative == control_law(zero, xc, m).derivative
    assert none.derivative != control_law(_gains(), xc, m).derivative


def _bounds(xc: list, rates: list, outward: bool) -> dict:
    """Bounds that put each estimate of ``xc`` on its set's boundary, on the side its rate points to (``outward``)
    or away from it."""
    bounds = {}
    for name, i in (("a1", 0), ("a2", 1)):
        up = (rates[i] > 0) == outward
        bounds[f"{name}_min"], bounds[f"{name}_max"] = (xc[i] - 5.0, xc[i]) if up else (xc[i], xc[i] + 5.0)
    for name, part in (("W1", W1), ("W2", W2)):
        bounds[f"{name}_max"] = math.sqrt(math.fsum(w * w for w in xc[part]))
    return bounds


@pytest.mark.parametrize("seed", SEEDS)
def test_projection_inside_its_sets_is_the_gradient_law(seed):
    xc, m = _random_point(seed)
    rates = control_law(_gains(adaptation=NONE), xc, m).derivative
    g = _gains(adaptation=PROJECTION, a1_min=-9.0, a1_max=9.0, a2_min=-9.0, a2_max=9.0, W1_max=9.0, W2_max=9.0)
    law = control_law(g, xc, m)
    assert law.derivative == rates
    assert law.projected == (False, False, False, False)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("Gamma", ["paper", "scalar"])
def test_projection_on_its_boundary(seed, Gamma):
    """The operator on random rates at a random state. Pointing inward: the rates unchanged. Pointing
    outward: an interval's rate zero; a ball's rate the gradient's less ``Gamma W (W^T r) / (W^T Gamma W)`` (Ioannou and Sun §4.4), tangent to the sphere; with a
    scalar Gamma that is the gradient less its normal component."""
    xc, m = _random_point(seed)
    rates, _ = _random_point(seed + 100)
    g = _gains(adaptation=PROJECTION)
    if Gamma == "scalar":
        g = dataclasses.replace(g, Gamma1=(0.3,) * 8, Gamma2=(0.7,) * 6)
    for part in (W1, W2):  # each weight vector's rate pointing out of its ball
        if math.fsum(w * r for w, r in zip(xc[part], rates[part])) < 0:
            rates[part] = [-r for r in rates[part]]
    g_out = dataclasses.replace(g, **_bounds(xc, rates, outward=True))
    projected, active, margins = project_rates(g_out, xc, rates)
    assert active == (True, True, True, True) and min(margins) > 0
    assert projected[0] == projected[1] == 0.0
    assert projected[2:4] == rates[2:4] and projected[12:14] == rates[12:14]
    for part, G in ((W1, g.Gamma1), (W2, g.Gamma2)):
        W, r, p = xc[part], rates[part], projected[part]
        scale = math.fsum(w * x for w, x in zip(W, r)) / math.fsum(Gi * w * w for Gi, w in zip(G, W))
        np.testing.assert_allclose(p, [x - Gi * w * scale for x, Gi, w in zip(r, G, W)], rtol=1e-12, atol=1e-15)
        assert abs(math.fsum(w * x for w, x in zip(W, p))) <= 1e-12 * math.fsum(abs(w * x) for w, x in zip(W, r))
        if Gamma == "scalar":
            normal = math.fsum(w * x for w, x in zip(W, r)) / math.fsum(w * w for w in W)
            np.testing.assert_allclose(p, [x - normal * w for x, w in zip(r, W)], rtol=1e-12, atol=1e-15)
    # The intervals on the side their rates point away from; the balls' rates turned inward.
    inward = list(rates)
    for part in (W1, W2):
        inward[part] = [-x for x in rates[part]]
    g_in = dataclasses.replace(g, **_bounds(xc, inward, outward=False))
    assert project_rates(g_in, xc, inward)[:2] == (inward, (False, False, False, False))


def test_estimates_outside_their_sets_are_moved_onto_them():
    g = _gains(a1_min=-1.0, a1_max=1.0, a2_min=0.0, a2_max=2.0, W1_max=0.5, W2_max=3.0)
    inside = [0.5, 1.0, 7.0, 8.0, *([0.1] * 8), 9.0, 10.0, *([1.0] * 6)]
    assert project_estimates(g, inside) is inside
    outside = [3.0, -1.0, 7.0, 8.0, *([1.0] * 8), 9.0, 10.0, *([2.0] * 6)]
    moved = project_estimates(g, outside)
    assert moved[:4] == [1.0, 0.0, 7.0, 8.0] and moved[12:14] == [9.0, 10.0]
    assert moved[W1] == pytest.approx([0.5 / math.sqrt(8)] * 8, rel=1e-15)
    assert moved[W2] == pytest.approx([3.0 / math.sqrt(6)] * 6, rel=1e-15)


def _within(rows, ball_tolerance: float) -> None:
    """Every recorded estimate in its set (``SETS``): the intervals exactly, the balls to ``ball_tolerance``
    (relative); and each estimate reached its set's boundary (the projection acted)."""
    for name, (low, high) in SETS.items():
        values = rows[name]
        slack = (ball_tolerance if name.endswith("norm") else 0.0) * high
        assert values.min() >= low - slack and values.max() <= high + slack, (name, values.min(), values.max())
        assert values.max() >= high * (1.0 - 1e-9) or values.min() <= low + 1e-9, (name, "never on the boundary")


def _tight_paper() -> object:
    scenario = load_scenario("paper")
    return dataclasses.replace(scenario, controller={**scenario.controller, **TIGHT})


@pytest.fixture(scope="module")
def tight_reference():
    return reference_solution(_tight_paper(), times=np.linspace(0.0, 4.0, 401))


def test_the_reference_solution_keeps_the_sets(tight_reference):
    _within(tight_reference, ROUNDING)


@pytest.mark.parametrize("version", (2, 3))
def test_co_simulation_never_leaves_the_sets(fmu_paths, fmu3_paths, version, tight_reference):
    """Every step (output_interval = step): the estimates projected after each RK4 sub-step."""
    paths = fmu_paths if version == 2 else fmu3_paths
    rows = cosimulate(_tight_paper(), paths, stop_time=4.0, step_size=1e-3, output_interval=1e-3).result
    _within(rows, ROUNDING)
    every_10 = rows[::10]
    for name in SETS:
        np.testing.assert_allclose(every_10[name], tight_reference[name], rtol=0, atol=2e-3 * SETS[name][1])


@pytest.mark.parametrize("version", (2, 3))
def test_model_exchange_never_leaves_the_sets(fmu_paths, fmu3_paths, version, tight_reference):
    """The project's route (events, the state projected at each): the intervals exact, the balls to the
    solver's tolerance between events (docs/model.md §5.13)."""
    paths = fmu_paths if version == 2 else fmu3_paths
    run = simulate_model_exchange(_tight_paper(), paths, stop_time=4.0, output_interval=1e-2, tolerance=1e-6)
    assert run.settings["events"] > 0
    _within(run.result, 1e-6)
    for name in SETS:
        np.testing.assert_allclose(run.result[name], tight_reference[name], rtol=0, atol=1e-4 * SETS[name][1])


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("interface", ["ModelExchange", "CoSimulation"])
def test_fmpy_keeps_the_controller_alone_in_its_sets(fmu_paths, fmu3_paths, version, interface):
    """fmpy's own routes with constant measurements (the estimates drift steadily to their bounds): model
    exchange through the state changes the FMU reports at its events."""
    path = str((fmu_paths if version == 2 else fmu3_paths)["DSCController"])
    signal = np.zeros(2, dtype=[("time", float), *((name, float) for name in STEADY)])
    for name, value in STEADY.items():
        signal[name] = value
    signal["time"] = (0.0, 3.0)
    sets = {"adaptation": PROJECTION, "a1_min": -0.5, "a1_max": 0.5, "a2_min": -0.2, "a2_max": 0.2,
            "W1_max": 1e-3, "W2_max": 0.5}
    rows = simulate_fmu(path, fmi_type=interface, stop_time=3.0, output_interval=1e-2, step_size=1e-2,
                        input=signal, start_values=sets, relative_tolerance=1e-8)
    for name, low, high in (("a1_hat", -0.5, 0.5), ("a2_hat", -0.2, 0.2), ("W1_hat_norm", 0.0, 1e-3),
                            ("W2_hat_norm", 0.0, 0.5)):
        slack = 1e-6 * high if name.endswith("norm") and interface == "ModelExchange" else ROUNDING * high
        assert rows[name].min() >= low - slack and rows[name].max() <= high + slack, name
        assert rows[name][-1] in (pytest.approx(low, abs=slack), pytest.approx(high, rel=1e-6)), name


@pytest.mark.parametrize("discretization", P.DISCRETIZATIONS)
def test_every_step_of_the_controller_alone_stays_in_the_sets(discretization):
    """Constant measurements drive the estimates to their bounds; after every step (RK4's sub-steps or
    Euler's step projected) each lies in its set, and each ends on its boundary."""
    sets = {"a1_min": -0.5, "a1_max": 0.5, "a2_min": -0.2, "a2_max": 0.2, "W1_max": 1e-3, "W2_max": 0.5}
    inst = InProcess("DSCController").initialize(
        sets, {"adaptation": PROJECTION, "discretization": P.DISCRETIZATIONS.index(discretization)})
    inst.set(CONTROLLER_IN, [STEADY[name] for name in CONTROLLER_IN])
    names = ("a1_hat", "a2_hat", "W1_hat_norm", "W2_hat_norm")
    bounds = ((-0.5, 0.5), (-0.2, 0.2), (0.0, 1e-3), (0.0, 0.5))
    for k in range(300):
        inst.step(k * 1e-2, 1e-2)
        for name, value, (low, high) in zip(names, inst.get(names), bounds):
            assert low <= value <= high * (1.0 + ROUNDING), (k, name, value)
    for value, (low, high) in zip(inst.get(names), bounds):
        assert value in (low, pytest.approx(high, rel=ROUNDING))


@pytest.mark.parametrize("changes, message", [
    ({"a1_min": 2.0, "a1_max": 1.0}, "a1_min = 2 is not below a1_max = 1"),
    ({"adaptation": PROJECTION, "a2_hat0": 30.0}, r"a2_hat0 = 30 is outside \[a2_min, a2_max\] = \[0, 20\]"),
    ({"adaptation": PROJECTION, "W2_hat0_1": 50.0}, r"\|W2_hat0\| = 50 is outside the ball W2_max = 40"),
])
def test_parameters_that_make_no_projection_fail_in_one_line(tmp_path, changes, message):
    integers = {k: v for k, v in changes.items() if k == "adaptation"}
    reals = {k: v for k, v in changes.items() if k != "adaptation"}
    with pytest.raises(ValueError, match=message):
        InProcess("DSCController").initialize(reals, integers)
    lines = ['adaptation = "projection"' if k == "adaptation" else f"{k} = {v}" for k, v in changes.items()]
    (tmp_path / "bad.toml").write_text("\n".join(["[controller]", *lines, ""]))
    with pytest.raises(ScenarioError, match=f"bad.toml: \\[controller\\] {message}"):
        load_scenario(Path(tmp_path / "bad.toml"))


def test_the_other_laws_ignore_an_initial_estimate_outside_the_sets():
    inst = InProcess("DSCController").initialize({"a2_hat0": 30.0}, {"adaptation": E_MODIFICATION})
    assert inst.get1("a2_hat") == 30.0
