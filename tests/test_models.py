"""The plain-Python models against the equations of docs/model.md and the paper, checked independently."""

import math

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp

from dsc_fmu.models.controller import alpha2, control_law, gains, wrap
from dsc_fmu.models.parameters import CONTROLLER_PARAMETERS, PLANT_PARAMETERS, REFERENCE_PARAMETERS, defaults
from dsc_fmu.models.plant import plant_coefficients, plant_derivatives, theta_dot
from dsc_fmu.models.reference import initial_reference_state, min_speed, reference_derivatives, velocity
from dsc_fmu.models.rk4 import rk4_integrate, substeps

SEEDS = range(6)
POSE = ("x0", "y0", "theta0", "max_step")


# ---------------------------------------------------------------- helpers: random cases, the matrices of docs/model.md


def random_plant_parameters(rng) -> dict:
    """The paper's plant with every physical parameter scaled by a random factor in [0.3, 3]."""
    p = defaults(PLANT_PARAMETERS)
    return {name: value if name in POSE else value * rng.uniform(0.3, 3.0) for name, value in p.items()}


def plant_parameters(case: str, seed: int) -> dict:
    return defaults(PLANT_PARAMETERS) if case == "paper" else random_plant_parameters(np.random.default_rng(seed))


def random_gains(rng):
    """The paper's gains (docs/model.md §4), each scaled by its own random factor in [0.2, 5]."""
    return gains({name: value * rng.uniform(0.2, 5.0) for name, value in defaults(CONTROLLER_PARAMETERS).items()})


def random_measurements(rng) -> list:
    """``m`` of models/controller.py with every entry random (vr > 0)."""
    x, y, theta, theta_dot_, v1, v2, i1, i2, xr, yr, thetar = rng.uniform(-3.0, 3.0, 11)
    vr, wr, vr_dot = rng.uniform(0.2, 2.0), rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0)
    return [x, y, theta, theta_dot_, 5 * v1, 5 * v2, 10 * i1, 10 * i2, xr, yr, thetar, vr, wr, vr_dot]


def random_controller_state(rng) -> list:
    return list(rng.uniform(-2.0, 2.0, 20))


def spec_inertia(p: dict) -> tuple:
    """m11, m12 of docs/model.md §1, computed here from the physical parameters."""
    m = p["mc"] + 2 * p["mw"]
    inertia = p["mc"] * p["d"] ** 2 + 2 * p["mw"] * p["R"] ** 2 + p["Ic"] + 2 * p["Im"]
    k = 0.25 * p["r"] ** 2 / p["R"] ** 2
    return k * (m * p["R"] ** 2 + inertia) + p["Iw"], k * (m * p["R"] ** 2 - inertia)


def spec_matrices(p: dict, theta_dot_: float) -> dict:
    """M, C(theta_dot), D, N KT, N KE, Ra, La of docs/model.md §1 as numpy matrices."""
    m11, m12 = spec_inertia(p)
    c = 0.5 * p["r"] ** 2 * p["mc"] * p["d"] / p["R"]
    diag = lambda a, b: np.diag([p[a], p[b]])  # noqa: E731
    return {
        "M": np.array([[m11, m12], [m12, m11]]),
        "C": c * np.array([[0.0, theta_dot_], [-theta_dot_, 0.0]]),
        "D": diag("d11", "d22"),
        "NKT": diag("N1", "N2") @ diag("KT1", "KT2"),
        "NKE": diag("N1", "N2") @ diag("KE1", "KE2"),
        "Ra": diag("Ra1", "Ra2"),
        "La": diag("La1", "La2"),
        "c": c,
        "m11": m11,
        "m12": m12,
    }


# ---------------------------------------------------------------- docs/model.md §1: plant


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("case", ["paper", "random"])
def test_plant_derivatives_match_matrix_form(case, seed):
    """(6)-(8): x1_dot = J(x1) x2, x2_dot = M^-1(-C x2 - D x2 + N KT x3), x3_dot = La^-1(u - Ra x3 - N KE x2)."""
    rng = np.random.default_rng(100 + seed)
    p = plant_parameters(case, seed)
    state = [*rng.uniform(-3, 3, 3), *rng.uniform(-10, 10, 2), *rng.uniform(-20, 20, 2)]
    u = rng.uniform(-300, 300, 2)
    _, _, theta, v1, v2, i1, i2 = state
    z, ia = np.array([v1, v2]), np.array([i1, i2])
    w = 0.5 * p["r"] / p["R"] * (v1 - v2)
    S = spec_matrices(p, w)
    expected = [
        0.5 * p["r"] * math.cos(theta) * (v1 + v2),
        0.5 * p["r"] * math.sin(theta) * (v1 + v2),
        w,
        *np.linalg.solve(S["M"], -S["C"] @ z - S["D"] @ z + S["NKT"] @ ia),
        *np.linalg.solve(S["La"], u - S["Ra"] @ ia - S["NKE"] @ z),
    ]
    k = plant_coefficients(p)
    np.testing.assert_allclose(plant_derivatives(k, 0.0, state, *u), expected, rtol=1e-12, atol=1e-9)
    assert theta_dot(k, v1, v2) == pytest.approx(w, rel=1e-14, abs=1e-15)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("case", ["paper", "random"])
def test_inertia_matrix_is_symmetric_positive_definite(case, seed):
    """docs/model.md §1: M = [[m11, m12], [m12, m11]] from the physical parameters is SPD, det_M > 0."""
    p = plant_parameters(case, seed)
    k = plant_coefficients(p)
    m11, m12 = spec_inertia(p)
    assert (k.m11, k.m12) == pytest.approx((m11, m12), rel=1e-13)
    M = np.array([[k.m11, k.m12], [k.m12, k.m11]])
    assert np.array_equal(M, M.T)
    assert np.all(np.linalg.eigvalsh(M) > 0)
    assert k.det_M > 0
    assert k.det_M == pytest.approx(np.linalg.det(M), rel=1e-10)


# ---------------------------------------------------------------- docs/model.md §3: the regressor identities


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("case", ["paper", "random"])
def test_W1_identity(case, seed):
    """With W1_hat = W1: x3bar + k4 S2 = -Phi1 W1 = (N KT)^-1 (C z + D z + M x2f_dot) (20), (22)."""
    rng = np.random.default_rng(200 + seed)
    p = plant_parameters(case, seed)
    g, m, xc = random_gains(rng), random_measurements(rng), random_controller_state(rng)
    S = spec_matrices(p, m[3])
    n1kt1, n2kt2 = np.diag(S["NKT"])
    c, m11, m12 = S["c"], S["m11"], S["m12"]
    xc[4:12] = [c / n1kt1, c / n2kt2, p["d11"] / n1kt1, p["d22"] / n2kt2,
                m11 / n1kt1, m12 / n1kt1, m11 / n2kt2, m12 / n2kt2]
    law = control_law(g, xc, m)
    z = np.array(m[4:6])
    x2f_dot = np.array(law.derivative[2:4])
    np.testing.assert_allclose(x2f_dot, (np.array(law.x2bar) - xc[2:4]) / g.tau2, rtol=1e-13)
    S2 = z - np.array(xc[2:4])
    expected = np.linalg.solve(S["NKT"], S["C"] @ z + S["D"] @ z + S["M"] @ x2f_dot)
    scale = 1.0 + np.abs(expected).max()
    np.testing.assert_allclose(np.array(law.x3bar) + g.k4 * S2, expected, rtol=0, atol=1e-12 * scale)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("case", ["paper", "random"])
def test_W2_identity(case, seed):
    """With W2_hat = W2: u + k5 S3 = -Phi2 W2 = Ra ia + N KE z + La x3f_dot (26)."""
    rng = np.random.default_rng(300 + seed)
    p = plant_parameters(case, seed)
    g, m, xc = random_gains(rng), random_measurements(rng), random_controller_state(rng)
    S = spec_matrices(p, m[3])
    xc[14:20] = [p["Ra1"], p["Ra2"], *np.diag(S["NKE"]), p["La1"], p["La2"]]
    law = control_law(g, xc, m)
    z, ia = np.array(m[4:6]), np.array(m[6:8])
    x3f_dot = np.array(law.derivative[12:14])
    np.testing.assert_allclose(x3f_dot, (np.array(law.x3bar) - xc[12:14]) / g.tau3, rtol=1e-13)
    S3 = ia - np.array(xc[12:14])
    expected = S["Ra"] @ ia + S["NKE"] @ z + S["La"] @ x3f_dot
    scale = 1.0 + np.abs(expected).max()
    np.testing.assert_allclose(np.array([law.u1, law.u2]) + g.k5 * S3, expected, rtol=0, atol=1e-12 * scale)


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("ahead", [False, True], ids=["behind", "ahead"])
def test_control_law_is_spec_3_in_matrix_form(ahead, seed):
    """u and all 20 state derivatives equal (10)-(27) written with numpy matrices (docs/model.md §3 and 5).

    ``ahead``: the robot is 3 / (k1 vr) ahead of the reference on its heading, so beta = -2 is guarded.
    """
    rng = np.random.default_rng(500 + seed)
    g, m, xc = random_gains(rng), random_measurements(rng), random_controller_state(rng)
    if ahead:
        lead = 3.0 / (g.k1 * m[11])
        m[0:2] = m[8] + lead * math.cos(m[2]), m[9] + lead * math.sin(m[2])
    x, y, theta, theta_dot_, v1, v2, i1, i2, xr, yr, thetar, vr, wr, vr_dot = m
    k1 = g.k1
    rot = np.array([[math.cos(theta), math.sin(theta)], [-math.sin(theta), math.cos(theta)]])
    S11, S12 = rot @ [xr - x, yr - y]
    S13bar = float(np.angle(np.exp(1j * (thetar - theta))))
    a = math.atan(k1 * S12 * vr)
    S13 = S13bar + a
    den = 1 + (k1 * S12 * vr) ** 2
    alpha1 = (k1 * vr**2 * math.sin(S13 - a) + k1 * S12 * vr_dot) / den
    al2 = quad(lambda eta: math.cos(-a + eta * S13), 0.0, 1.0, epsabs=1e-14)[0]
    beta = 1 + k1 * vr * S11 / den
    a1, a2 = xc[0], xc[1]
    h1 = a1 * vr * math.cos(S13 - a) + g.k2 * S11 + 0.5 * (k1 * vr) ** 4 * S11**3
    h2 = (a1 * al2 * vr * S12 + a2 * (wr + alpha1) + g.k3 * S13 + 0.5 * S13**3) / max(beta, g.beta_min)
    x2bar = np.array([h1 + h2, h1 - h2])
    x2f, W1, x3f, W2 = np.array(xc[2:4]), np.array(xc[4:12]), np.array(xc[12:14]), np.array(xc[14:20])
    x2f_dot = (x2bar - x2f) / g.tau2
    S2 = np.array([v1, v2]) - x2f
    Phi1 = np.array([[-theta_dot_ * v2, 0, -v1, 0, -x2f_dot[0], -x2f_dot[1], 0, 0],
                     [0, theta_dot_ * v1, 0, -v2, 0, 0, -x2f_dot[1], -x2f_dot[0]]])
    x3bar = -g.k4 * S2 - Phi1 @ W1
    x3f_dot = (x3bar - x3f) / g.tau3
    S3 = np.array([i1, i2]) - x3f
    Phi2 = np.array([[-i1, 0, -v1, 0, -x3f_dot[0], 0], [0, -i2, 0, -v2, 0, -x3f_dot[1]]])
    u = -g.k5 * S3 - Phi2 @ W2
    G1, G2 = np.diag(g.Gamma1), np.diag(g.Gamma2)
    expected = [
        g.gamma1 * vr * (S11 * math.cos(S13 - a) + al2 * S12 * S13) - g.sigma1 * g.gamma1 * a1,
        g.gamma2 * (wr + alpha1) * S13 - g.sigma2 * g.gamma2 * a2,
        *x2f_dot,
        *(G1 @ Phi1.T @ S2 - g.sigma3 * G1 @ W1),
        *x3f_dot,
        *(G2 @ Phi2.T @ S3 - g.sigma4 * G2 @ W2),
    ]
    law = control_law(g, xc, m)
    assert (law.S11, law.S12, law.S13, law.beta) == pytest.approx((S11, S12, S13, beta), rel=1e-12, abs=1e-12)
    assert law.guarded == (beta < g.beta_min)
    if ahead:
        assert law.guarded and beta == pytest.approx(-2.0, rel=1e-9)
    np.testing.assert_allclose(law.x2bar, x2bar, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(law.x3bar, x3bar, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose([law.u1, law.u2], u, rtol=1e-10, atol=1e-8)
    np.testing.assert_allclose(law.derivative, expected, rtol=1e-10, atol=1e-8)


# ---------------------------------------------------------------- step 1: alpha2, wrap, eq. (11), (13)

S13_VALUES = [0.0, 1e-12, -1e-12, 1e-8, -1e-8, 1e-5, -1e-5, 1.99999e-4, 2e-4, -2.00001e-4, 1e-3, -1e-3, 0.1, 2.5, -2.5]


@pytest.mark.parametrize("a", [-1.4, -0.3, 0.0, 0.7, 1.5])
@pytest.mark.parametrize("S13", S13_VALUES)
def test_alpha2_is_the_integral(S13, a):
    """alpha2 = integral_0^1 cos(-a + eta S13) d eta (14), also across its small-S13 branch."""
    expected, error = quad(lambda eta: math.cos(-a + eta * S13), 0.0, 1.0, epsabs=1e-13, epsrel=0.0)
    assert error < 1e-13
    assert alpha2(S13, a) == pytest.approx(expected, rel=0, abs=1e-12)


@pytest.mark.parametrize("a", [-1.4, -0.3, 0.0, 0.7, 1.5])
def test_alpha2_limit_at_zero(a):
    assert alpha2(0.0, a) == pytest.approx(math.cos(a), rel=1e-15, abs=1e-16)


@pytest.mark.parametrize(
    "angle, expected",
    [(math.pi, math.pi), (-math.pi, math.pi), (3 * math.pi, math.pi), (-3 * math.pi, math.pi),
     (0.0, 0.0), (1.0, 1.0), (-1.0, -1.0), (math.pi - 1e-9, math.pi - 1e-9), (-math.pi + 1e-9, -math.pi + 1e-9)],
    ids=["pi", "-pi", "3pi", "-3pi", "0", "1", "-1", "below_pi", "above_-pi"],
)
def test_wrap_exact_cases(angle, expected):
    assert wrap(angle) == expected


@pytest.mark.parametrize("seed", SEEDS)
def test_wrap_maps_to_half_open_interval(seed):
    """wrap(a) is in (-pi, pi] and differs from a by a whole number of turns (docs/model.md §5)."""
    for angle in np.random.default_rng(seed).uniform(-50.0, 50.0, 1000):
        w = wrap(angle)
        assert -math.pi < w <= math.pi
        turns = (angle - w) / (2 * math.pi)
        assert turns == pytest.approx(round(turns), abs=1e-12)


def _surfaces(g, p_ref, state, t):
    """S11, S12, S13bar (10) and S13 (12) from the pose and reference pose, via control_law."""
    x, y, theta, xr, yr, thetar = state
    vr, wr, vr_dot = velocity(p_ref, t)
    law = control_law(g, [0.0] * 20, [x, y, theta, 0.0, 0.0, 0.0, 0.0, 0.0, xr, yr, thetar, vr, wr, vr_dot])
    return np.array([law.S11, law.S12, law.S13 - math.atan(g.k1 * law.S12 * vr), law.S13]), law


def _reference_parameters(profile: str) -> dict:
    p = defaults(REFERENCE_PARAMETERS)
    p["profile"] = 0 if profile == "constant" else 1
    return p


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("profile", ["constant", "figure_eight"])
def test_error_dynamics_11_and_13(profile, seed):
    """d/dt of (10), (12) along x_dot = J(x) z and (9), by central differences, equals (11) and (13)."""
    rng = np.random.default_rng(400 + seed)
    p, g = defaults(PLANT_PARAMETERS), random_gains(rng)
    p_ref = _reference_parameters(profile)
    r, R = p["r"], p["R"]
    x, y, theta, xr, yr = rng.uniform(-3, 3, 5)
    thetar = theta + rng.uniform(-2.5, 2.5) + 2 * math.pi * rng.integers(-2, 3)  # away from the wrap at pi
    v1, v2 = rng.uniform(-8, 8, 2)
    t = rng.uniform(0, 30)
    vr, wr, vr_dot = velocity(p_ref, t)
    w = 0.5 * r / R * (v1 - v2)
    state = np.array([x, y, theta, xr, yr, thetar])
    rate = np.array([0.5 * r * math.cos(theta) * (v1 + v2), 0.5 * r * math.sin(theta) * (v1 + v2), w,
                     vr * math.cos(thetar), vr * math.sin(thetar), wr])
    h = 1e-5
    d = (_surfaces(g, p_ref, state + h * rate, t + h)[0] - _surfaces(g, p_ref, state - h * rate, t - h)[0]) / (2 * h)
    (S11, S12, S13bar, S13), law = _surfaces(g, p_ref, state, t)
    den = 1 + (g.k1 * S12 * vr) ** 2
    alpha1 = (g.k1 * vr**2 * math.sin(S13bar) + g.k1 * S12 * vr_dot) / den
    expected = [
        w * S12 - 0.5 * r * (v1 + v2) + vr * math.cos(S13bar),
        -w * S11 + vr * math.sin(S13bar),
        wr - w,
        wr - w * law.beta + alpha1,
    ]
    np.testing.assert_allclose(d, expected, rtol=1e-6, atol=1e-6)
    assert law.beta == pytest.approx(1 + g.k1 * vr * S11 / den, rel=1e-14)


# ---------------------------------------------------------------- RK4


def _rk4_error(f, x0, exact, t_end, max_step):
    return np.abs(np.array(rk4_integrate(f, 0.0, x0, t_end, max_step)) - exact).max()


@pytest.mark.parametrize(
    "f, x0, exact, t_end",
    [
        (lambda t, x: [-x[0]], [1.0], [math.exp(-2.0)], 2.0),
        (lambda t, x: [-x[1], x[0]], [1.0, 0.0], [math.cos(3.0), math.sin(3.0)], 3.0),
        (lambda t, x: [math.cos(t)], [0.0], [math.sin(2.0)], 2.0),
    ],
    ids=["decay", "rotation", "time_dependent"],
)
@pytest.mark.parametrize("max_step", [0.1, 0.05])
def test_rk4_is_fourth_order(f, x0, exact, t_end, max_step):
    """Halving the sub-step divides the error by about 2^4 = 16."""
    ratio = _rk4_error(f, x0, exact, t_end, max_step) / _rk4_error(f, x0, exact, t_end, max_step / 2)
    assert 14.0 < ratio < 18.0


@pytest.mark.parametrize(
    "step_size, max_step",
    [(1e-3, 1e-3), (1e-2, 1e-3), (0.3, 0.1), (0.1, 0.03), (1e-3, 1e-2), (0.7, 0.7 / 3), (1.0, 1e-3), (0.123, 0.0101)],
)
def test_substeps_never_longer_than_max_step(step_size, max_step):
    """The sub-step step_size / n is at most max_step (to 1e-12 relative), and n is the smallest such."""
    n = substeps(step_size, max_step)
    assert n >= 1
    assert step_size / n <= max_step * (1 + 1e-12)
    if n > 1:
        assert step_size / (n - 1) > max_step * (1 + 1e-12)


# ---------------------------------------------------------------- reference robot (9) and its profiles


@pytest.mark.parametrize("A, B, T", [(3.0, 1.5, 30.0), (8.0, 1.0, 20.0), (1.0, 2.0, 10.0), (4.0, 1.0, 60.0)])
def test_min_speed_of_figure_eight(A, B, T):
    """min_speed equals the smallest vr of dense sampling over one period (and is a lower bound)."""
    p = {**_reference_parameters("figure_eight"), "eight_A": A, "eight_B": B, "eight_T": T}
    sampled = min(velocity(p, t)[0] for t in np.linspace(0.0, T, 100001))
    lowest = min_speed(p, T)
    assert lowest <= sampled * (1 + 1e-12)
    assert sampled == pytest.approx(lowest, rel=1e-6)


def test_min_speed_of_constant_profile():
    p = {**_reference_parameters("constant"), "vr0": 0.7}
    assert min_speed(p, 30.0) == 0.7


@pytest.mark.parametrize("vr, wr, theta0", [(1.0, 0.2, 0.0), (0.5, -0.7, 1.0), (2.0, 1.5, -2.0)])
def test_reference_robot_follows_the_circle(vr, wr, theta0):
    """(9) with constant vr, wr: the circle of radius vr/|wr| around x0 - vr/wr sin(theta0), y0 + vr/wr cos(theta0)."""
    p = {**_reference_parameters("constant"), "vr0": vr, "wr0": wr, "x0": 1.0, "y0": -2.0, "theta0": theta0}
    state = initial_reference_state(p)
    f = lambda t, x: reference_derivatives(p, t, x)  # noqa: E731
    rho = vr / wr
    centre = (1.0 - rho * math.sin(theta0), -2.0 + rho * math.cos(theta0))
    for k in range(20):
        state = rk4_integrate(f, 0.5 * k, state, 0.5, 1e-2)
        t = 0.5 * (k + 1)
        heading = theta0 + wr * t
        expected = [centre[0] + rho * math.sin(heading), centre[1] - rho * math.cos(heading), heading]
        np.testing.assert_allclose(state, expected, rtol=0, atol=1e-9)
        assert math.hypot(state[0] - centre[0], state[1] - centre[1]) == pytest.approx(abs(rho), abs=1e-9)


@pytest.mark.parametrize("A, B, T", [(3.0, 1.5, 30.0), (2.0, 2.0, 12.0)])
def test_figure_eight_profile_matches_the_curve(A, B, T):
    """vr = |curve'|, wr = d/dt heading of the curve, vr_dot = d/dt vr (central differences)."""
    p = {**_reference_parameters("figure_eight"), "eight_A": A, "eight_B": B, "eight_T": T}
    W = 2 * math.pi / T

    def heading(t):
        return math.atan2(2 * B * W * math.cos(2 * W * t), A * W * math.cos(W * t))

    h = 1e-5
    for t in np.linspace(0.0, T, 37):
        vr, wr, vr_dot = velocity(p, t)
        assert vr == pytest.approx(math.hypot(A * W * math.cos(W * t), 2 * B * W * math.cos(2 * W * t)), rel=1e-13)
        assert vr_dot == pytest.approx((velocity(p, t + h)[0] - velocity(p, t - h)[0]) / (2 * h), abs=1e-8)
        assert wr == pytest.approx(wrap(heading(t + h) - heading(t - h)) / (2 * h), abs=1e-8)


@pytest.mark.parametrize("A, B, T", [(3.0, 1.5, 30.0), (2.0, 2.0, 12.0)])
def test_reference_robot_traces_the_figure_eight(A, B, T):
    """(9) driven by the figure-eight profile from the curve's start pose traces x = A sin(W t), y = B sin(2 W t)."""
    p = {**_reference_parameters("figure_eight"), "eight_A": A, "eight_B": B, "eight_T": T,
         "x0": 0.0, "y0": 0.0, "theta0": math.atan2(2 * B, A)}
    W = 2 * math.pi / T
    times = np.linspace(0.0, T, 61)
    sol = solve_ivp(lambda t, x: reference_derivatives(p, t, x), (0.0, T), initial_reference_state(p),
                    method="DOP853", t_eval=times, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(sol.y[0], A * np.sin(W * times), atol=1e-8)
    np.testing.assert_allclose(sol.y[1], B * np.sin(2 * W * times), atol=1e-8)
