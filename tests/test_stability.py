"""Tests of the predicted stability boundary (dsc_fmu/study/stability.py): hand-checkable cases first."""

import dataclasses
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from dsc_fmu.study import stability as st
from dsc_fmu.models.controller import control_law, gains
from dsc_fmu.models.plant import plant_coefficients, plant_derivatives, theta_dot
from dsc_fmu.models.reference import reference_derivatives
from dsc_fmu.models.rk4 import rk4_integrate
from dsc_fmu.scenario import load_scenario

ORDERS = ("gauss-seidel", "jacobi")
GRID = np.logspace(-3.0, 1.0, 81)  # a coarser scan than the default for the small hand cases


def scalar_loop(a, b, Ac, Bc, Cc, Dc):
    """Plant x' = -a x + b u, y = x, with the given controller matrices."""
    return st.LinearLoop([[-a]], [[b]], [[1.0]], Ac, Bc, Cc, Dc)


# --- Hand-checkable cases ---------------------------------------------------------------------------

def test_static_gain_jacobi_pole_and_boundary_by_hand():
    """u = -k y: the discrete pole is e^{-ah} - (1 - e^{-ah}) k b / a, equal to -1 at h = ln((kb + a)/(kb - a)) / a."""
    a, b, k = 2.0, 3.0, 4.0
    loop = scalar_loop(a, b, [], [], [], [[-k]])
    for h in (0.01, 0.1, 0.3):
        pole = math.exp(-a * h) - (1.0 - math.exp(-a * h)) * k * b / a
        for order in ORDERS:  # no controller state: both orders give the same 1x1 matrix
            M = st.transition_matrix(loop, h, order, "rk4")
            assert M.shape == (1, 1)
            assert M[0, 0] == pytest.approx(pole, rel=1e-12)
            assert st.spectral_radius(loop, h, order, "rk4") == pytest.approx(abs(pole), rel=1e-12)
    exact = math.log((k * b + a) / (k * b - a)) / a
    for order in ORDERS:
        assert st.predicted_boundary(loop, order, "rk4", steps=GRID, rtol=1e-10) == pytest.approx(exact, rel=1e-6)


def test_integrator_controller_gauss_seidel_and_jacobi_differ_as_derived_by_hand():
    """xc' = y, u = -k xc. With phi = e^{-ah}, g = b (1 - phi) / a (ZOH; the integrator's ZOH is exact: 1, h):
    Jacobi M = [[phi, -g k], [h, 1]], det = phi + h g k: unstable when h g k = 1 - phi, i.e. h = a / (k b);
    Gauss-Seidel M = [[phi, -g k], [h phi, 1 - h g k]], det = phi: unstable at the eigenvalue -1,
    1 + tr + det = 0, i.e. h g k = 2 (1 + phi), i.e. h tanh(a h / 2) = 2 a / (k b)."""
    a, b, k = 1.0, 1.0, 10.0
    loop = scalar_loop(a, b, [[0.0]], [[1.0]], [[-k]], [[0.0]])
    h = 0.05
    phi = math.exp(-a * h)
    g = b * (1.0 - phi) / a
    np.testing.assert_allclose(st.transition_matrix(loop, h, "jacobi"), [[phi, -g * k], [h, 1.0]], rtol=1e-12)
    np.testing.assert_allclose(st.transition_matrix(loop, h, "gauss-seidel"),
                               [[phi, -g * k], [h * phi, 1.0 - h * g * k]], rtol=1e-12)
    jacobi = a / (k * b)
    gauss_seidel = brentq(lambda x: x * math.tanh(a * x / 2.0) - 2.0 * a / (k * b), 1e-6, 10.0, xtol=1e-14)
    for discretization in ("rk4", "euler"):  # Euler of an integrator is exact too
        for order, exact in (("jacobi", jacobi), ("gauss-seidel", gauss_seidel)):
            found = st.predicted_boundary(loop, order, discretization, steps=GRID, rtol=1e-10)
            assert found == pytest.approx(exact, rel=1e-6)
    assert gauss_seidel > 6.0 * jacobi


def test_euler_controller_is_one_explicit_step_and_rk4_is_the_zoh():
    """xc' = -c xc + y: ZOH Phi_c = e^{-ch}, Gamma_c = (1 - e^{-ch}) / c; Euler Phi_c = 1 - c h, Gamma_c = h."""
    c, h = 30.0, 0.02
    loop = scalar_loop(1.0, 1.0, [[-c]], [[1.0]], [[-2.0]], [[-0.5]])
    _, _, Phi, Gamma = st.sampled_pieces(loop, h, "rk4")
    assert Phi[0, 0] == pytest.approx(math.exp(-c * h), rel=1e-12)
    assert Gamma[0, 0] == pytest.approx((1.0 - math.exp(-c * h)) / c, rel=1e-12)
    Phi_p, Gamma_p, Phi, Gamma = st.sampled_pieces(loop, h, "euler")
    assert (Phi[0, 0], Gamma[0, 0]) == pytest.approx((1.0 - c * h, h), rel=1e-14)
    assert (Phi_p[0, 0], Gamma_p[0, 0]) == pytest.approx((math.exp(-h), 1.0 - math.exp(-h)), rel=1e-12)


def test_bad_arguments_are_refused():
    loop = scalar_loop(1.0, 1.0, [], [], [], [[-1.0]])
    with pytest.raises(ValueError, match="order"):
        st.spectral_radius(loop, 0.1, "parallel")
    with pytest.raises(ValueError, match="discretization"):
        st.spectral_radius(loop, 0.1, "jacobi", "trapezoid")
    with pytest.raises(ValueError, match="constant"):
        st.linearise(load_scenario("figure_eight"))


# --- Error coordinates ------------------------------------------------------------------------------

def test_control_law_sees_the_pose_only_through_the_error_coordinates():
    """u and the controller derivative are the same for a world configuration and its error-coordinate
    equivalent (robot at the origin heading 0, reference at (S11, S12, S13bar)), eq. (10)."""
    scenario = load_scenario("paper")
    k, g = plant_coefficients(scenario.plant), gains(scenario.controller)
    rng = np.random.default_rng(1)
    for _ in range(50):
        plant = [*rng.uniform(-5, 5, 2), rng.uniform(-7, 7), *rng.uniform(-10, 10, 2), *rng.uniform(-5, 5, 2)]
        reference = [*rng.uniform(-5, 5, 2), rng.uniform(-7, 7)]
        vr, wr = rng.uniform(0.2, 2.0), rng.uniform(-0.5, 0.5)
        xc = list(rng.uniform(-2, 2, 20))
        world = [*plant[:3], theta_dot(k, *plant[3:5]), *plant[3:], *reference, vr, wr, 0.0]
        xp = st.error_coordinates(plant, reference)
        local = st.error_measurements(st.error_outputs(k, xp), vr, wr)
        a, b = control_law(g, xc, world), control_law(g, xc, local)
        assert a.guarded == b.guarded
        np.testing.assert_allclose([a.u1, a.u2, *a.derivative], [b.u1, b.u2, *b.derivative], rtol=1e-9, atol=1e-9)


def test_error_dynamics_are_the_time_derivative_of_the_error_coordinates():
    """Eq. (11): d/dt of error_coordinates along plant (6)-(8) and reference (9) = error_plant_derivatives."""
    scenario = load_scenario("paper")
    k, ref = plant_coefficients(scenario.plant), scenario.reference
    rng = np.random.default_rng(2)
    for _ in range(10):
        plant = [*rng.uniform(-5, 5, 2), rng.uniform(-3, 3), *rng.uniform(-10, 10, 2), *rng.uniform(-5, 5, 2)]
        reference, u = list(rng.uniform(-3, 3, 3)), rng.uniform(-50, 50, 2)
        dp, dr = plant_derivatives(k, 0.0, plant, *u), reference_derivatives(ref, 0.0, reference)
        eps = 1e-6
        def moved(e):
            return np.array(st.error_coordinates(list(np.add(plant, e * np.array(dp))),
                                                 list(np.add(reference, e * np.array(dr)))))

        expected = (moved(eps) - moved(-eps)) / (2 * eps)
        got = st.error_plant_derivatives(k, ref["vr0"], ref["wr0"], st.error_coordinates(plant, reference), u)
        np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-6)


# --- The real loop ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def scenario():
    return load_scenario("on_reference")


@pytest.fixture(scope="module")
def loop(scenario):
    return st.linearise(scenario)


def test_linearisation_shapes_and_operating_point(loop):
    assert [m.shape for m in (loop.Ap, loop.Bp, loop.Cp, loop.Ac, loop.Bc, loop.Cc, loop.Dc)] == [
        (7, 7), (7, 2), (8, 7), (20, 20), (20, 8), (2, 20), (2, 8)]
    z = loop.operating_point
    assert loop.at_time == 30.0
    assert abs(z[0]) < 0.1 and abs(z[1]) < 0.1 and abs(z[2]) < 0.02  # tracking: S11, S12, S13bar small
    assert z[3] > z[4] > 0  # turning left at wr > 0: right wheel faster
    assert loop.drift < 0.2  # only the frozen estimates drift, slowly


def test_continuous_closed_loop_poles_are_in_the_left_half_plane(loop):
    poles = loop.poles
    assert poles.size == 27
    assert np.all(poles.real < 0)
    np.testing.assert_allclose(np.sort_complex(poles), np.sort_complex(np.linalg.eigvals(loop.closed_loop_matrix)),
                               rtol=1e-6, atol=1e-10)


def test_pieces_assemble_the_jacobian_of_the_closed_loop(scenario, loop):
    """The assembled [[Ap + Bp Dc Cp, Bp Cc], [Bc Cp, Ac]] is the finite-difference Jacobian of closed_loop_derivative,
    and a second finite-difference step gives the same to 1e-5 (relative to the largest entry)."""
    k, g = plant_coefficients(scenario.plant), gains(scenario.controller)
    vr, wr = scenario.reference["vr0"], scenario.reference["wr0"]
    J = st.jacobian(lambda z: st.closed_loop_derivative(k, g, vr, wr, z), loop.operating_point, 1e-5)
    A = loop.closed_loop_matrix
    np.testing.assert_allclose(A, J, rtol=1e-5, atol=1e-5 * np.abs(A).max())
    other = st.linearise(scenario, rel=1e-5)
    for name in ("Ap", "Bp", "Cp", "Ac", "Bc", "Cc", "Dc"):
        a, b = getattr(loop, name), getattr(other, name)
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5 * max(1.0, np.abs(a).max()), err_msg=name)


def test_spectral_radius_tends_to_one_from_below_as_the_continuous_loop(loop):
    poles = loop.poles
    for h in (1e-5, 1e-4):
        for order in ORDERS:
            M = st.transition_matrix(loop, h, order)
            rho = st.spectral_radius(loop, h, order)
            assert rho < 1.0
            assert rho == pytest.approx(math.exp(h * poles.real.max()), abs=1e-12)
            assert np.sort(np.abs(np.linalg.eigvals(M))) == pytest.approx(np.sort(np.abs(np.exp(h * poles))), rel=1e-4)


def _sampled_step(scenario, z, h, order, discretization):
    """One communication step of the nonlinear loop with master.cosimulate's semantics (RK4 sub-steps of 1e-3)."""
    k, g = plant_coefficients(scenario.plant), gains(scenario.controller)
    vr, wr = scenario.reference["vr0"], scenario.reference["wr0"]
    xp, xc = list(z[:7]), list(z[7:])
    y = st.error_outputs(k, xp)
    law = control_law(g, xc, st.error_measurements(y, vr, wr))
    xp1 = rk4_integrate(lambda t, x: st.error_plant_derivatives(k, vr, wr, x, (law.u1, law.u2)), 0.0, xp, h, 1e-3)
    m = st.error_measurements(y if order == "jacobi" else st.error_outputs(k, xp1), vr, wr)
    f = lambda t, x: control_law(g, x, m).derivative  # noqa: E731
    if discretization == "euler":
        xc1 = [x + h * d for x, d in zip(xc, f(0.0, xc))]
    else:
        xc1 = rk4_integrate(f, 0.0, xc, h, 1e-3)
    return np.array([*xp1, *xc1])


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("discretization", ("rk4", "euler"))
def test_transition_matrix_is_the_jacobian_of_one_nonlinear_communication_step(scenario, order, discretization):
    """At the equilibrium of the whole adaptive loop (no drift), the Jacobian of one co-simulation step
    (held inputs, RK4 sub-steps, Gauss-Seidel or Jacobi) is the transition matrix."""
    loop = st.linearise(scenario, frozen=False)
    assert loop.drift < 1e-9
    h = 0.01
    J = st.jacobian(lambda z: _sampled_step(scenario, z, h, order, discretization), loop.operating_point, 1e-6)
    M = st.transition_matrix(loop, h, order, discretization)
    np.testing.assert_allclose(M, J, atol=1e-5 * np.abs(M).max())


def test_the_equilibrium_of_the_whole_adaptive_loop_is_unstable(scenario):
    """Surprise, kept as a regression: with sigma-modification the equilibrium is unique, but for the paper's gains
    the estimate ra_hat settles at ~3.47 > Ra + k5 = 2.6, so the frozen current loop has negative resistance."""
    loop = st.linearise(scenario, frozen=False)
    assert loop.operating_point[7 + 14] == pytest.approx(3.47, abs=0.01)
    assert loop.poles.real.max() > 1.0
    assert st.predicted_boundary(loop, "jacobi") == 0.0


def test_predicted_boundaries_of_on_reference(loop):
    """Euler is limited by the explicit step of the 1/tau = 100 1/s filters (h < ~0.02 s); with RK4 the
    boundary is larger and Jacobi's (one step of extra delay) is below Gauss-Seidel's."""
    b = {(o, d): st.predicted_boundary(loop, o, d) for o in ORDERS for d in ("rk4", "euler")}
    for order in ORDERS:
        assert 0.018 < b[order, "euler"] < 0.021
        assert b[order, "euler"] < b[order, "rk4"] < 0.1
    assert b["jacobi", "rk4"] < b["gauss-seidel", "rk4"]
    for (order, discretization), h in b.items():
        assert st.spectral_radius(loop, h * 0.999, order, discretization) < 1.0
        assert st.spectral_radius(loop, h * 1.001, order, discretization) > 1.0
    curve = st.spectral_radius_curve(loop, [1e-3, b["jacobi", "rk4"] * 1.01], "jacobi")
    assert curve.shape == (2,) and curve[0] < 1.0 < curve[1]


def test_predicted_boundary_accepts_a_scenario_and_uses_its_discretization(scenario, loop):
    euler = dataclasses.replace(scenario, controller={**scenario.controller, "discretization": 1})
    assert st.predicted_boundary(euler, "jacobi") == pytest.approx(st.predicted_boundary(loop, "jacobi", "euler"),
                                                                   rel=1e-9)


def test_no_operating_point_is_a_clear_error(scenario):
    with pytest.raises(st.OperatingPointError, match="no operating point"):
        st.operating_point(scenario, state=np.full(27, np.nan))


# --- The linear coupling --------------------------------------------------------------------------------

def _sampled_run(loop, h, order, steps, s0, discretization="rk4"):
    """The loop with the linear coupling stepped here with solve_ivp (ramp inputs built by hand from
    the stored previous values), from ``s0 = [xp; xc; u_prev; y_prev]``: the state after ``steps`` steps."""
    n_p, nc = loop.Ap.shape[0], loop.Ac.shape[0]
    nu = loop.Bp.shape[1]
    xp, xc = s0[:n_p], s0[n_p:n_p + nc]
    u_prev, y_prev = s0[n_p + nc:n_p + nc + nu], s0[n_p + nc + nu:]
    for _ in range(steps):
        y = loop.Cp @ xp
        u = loop.Cc @ xc + loop.Dc @ y
        plant = solve_ivp(lambda s, x: loop.Ap @ x + loop.Bp @ (u + (s / h) * (u - u_prev)), (0, h), xp,
                          rtol=1e-12, atol=1e-14).y[:, -1]
        y_next = loop.Cp @ plant
        if order == "jacobi":
            y_at = lambda s: y + (s / h) * (y - y_prev)  # noqa: E731
        else:
            y_at = lambda s: y + (s / h) * (y_next - y)  # noqa: E731
        if discretization == "euler":  # one explicit Euler step with the inputs at the step's start
            xc = xc + h * (loop.Ac @ xc + loop.Bc @ y_at(0.0))
        else:
            xc = solve_ivp(lambda s, x: loop.Ac @ x + loop.Bc @ y_at(s), (0, h), xc, rtol=1e-12, atol=1e-14).y[:, -1]
        xp, u_prev, y_prev = plant, u, y
    return np.concatenate([xp, xc, u_prev, y_prev])


@pytest.mark.parametrize("discretization", ["rk4", "euler"])
@pytest.mark.parametrize("order", ORDERS)
def test_linear_transition_matrix_is_one_step_with_ramp_inputs(order, discretization):
    """The matrix of the linear coupling maps the augmented state as the ramps integrated here do."""
    loop = st.LinearLoop([[-1.0, 0.5], [0.0, -3.0]], [[0.0], [2.0]], [[1.0, 0.0]], [[-0.5]], [[1.0]], [[-2.0]],
                         [[-1.5]])
    rng = np.random.default_rng(7)
    s0 = rng.normal(size=2 + 1 + 1 + 1)
    h = 0.2
    M = st.linear_transition_matrix(loop, h, order, discretization)
    np.testing.assert_allclose(M @ M @ s0, _sampled_run(loop, h, order, 2, s0, discretization), rtol=1e-8, atol=1e-10)


def test_linear_coupling_predicted_boundaries_of_on_reference(loop):
    """The linear coupling is stable to a smaller step than the hold (extrapolation amplifies)."""
    for order in ORDERS:
        hold = st.predicted_boundary(loop, order)
        linear = st.predicted_boundary(loop, order, coupling="linear")
        assert 0.01 < linear < hold
    with pytest.raises(ValueError, match="coupling = 'cubic' is not allowed; allowed: hold, linear"):
        st.spectral_radius(loop, 1e-3, "jacobi", coupling="cubic")


# --- The drivers' limit and the disturbance torques (docs/model.md §5.14) ----------------------------------


def _with_plant(scenario, **values):
    return dataclasses.replace(scenario, plant={**scenario.plant, **values})


def test_a_limit_that_does_not_act_leaves_the_loop_and_one_that_acts_is_refused(scenario, loop):
    unacting = st.linearise(_with_plant(scenario, voltage_limit=1, u_max1=150.0, u_max2=150.0))
    for name in ("Ap", "Bp", "Cp", "Ac", "Bc", "Cc", "Dc", "operating_point"):
        assert np.array_equal(getattr(unacting, name), getattr(loop, name)), name
    with pytest.raises(ValueError, match=r"^on_reference: the voltage limit acts at the .*u_max\d = 60 V"):
        st.linearise(_with_plant(scenario, voltage_limit=1, u_max1=60.0, u_max2=60.0), at_time=1.0)


def test_a_constant_load_moves_the_operating_point_and_a_sinusoid_is_refused(scenario, loop):
    """A constant load of 5 N.m on each wheel: the motors carry it with about tau_d / (N KT) more current (eq. (2)
    with z_dot = 0, the speeds those of the circle); a sinusoid leaves no operating point."""
    loaded = st.linearise(_with_plant(scenario, tau_dc1=5.0, tau_dc2=5.0, f_d1=2.0))
    k = plant_coefficients(scenario.plant)
    current = [loaded.operating_point[j] - loop.operating_point[j] for j in (5, 6)]
    assert current == pytest.approx([5.0 / k.nkt1, 5.0 / k.nkt2], rel=0.05)
    np.testing.assert_allclose(loaded.Ap[3:5, 5:7], loop.Ap[3:5, 5:7], rtol=1e-6)  # d z_dot / d ia = M^-1 N KT
    with pytest.raises(ValueError, match=r"^on_reference: the disturbance torque of wheel 2 is a sinusoid .*= 1 Hz"):
        st.linearise(_with_plant(scenario, tau_da2=1.0, f_d2=1.0))
