"""Predicted stability boundary of the sampled-data co-simulation: linearised loop, ZOH sampling, spectral radius."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import control
import numpy as np
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from ..models.controller import W1_SLICE, W2_SLICE, Gains, control_law, gains, initial_controller_state, start_filters
from ..models.plant import PlantCoefficients, initial_plant_state, plant_coefficients
from ..models.parameters import DISCRETIZATIONS, PROFILES
from ..models.reference import initial_reference_state
from ..errors import DscFmuError
from ..scenario import Coupling, Order, Scenario, one_of
from .tracking import error_coordinates, error_measurements, error_outputs, error_plant_derivatives

__all__ = ["LinearLoop", "OperatingPointError", "ESTIMATES", "SOURCES", "operating_point", "linearise", "spectral_radius",
           "predicted_boundary"]

# Indices, in the stacked state z = [xp (7); xc (20)], of the parameter estimates a1_hat, a2_hat, W1_hat, W2_hat.
ESTIMATES = (7, 8, *range(7 + W1_SLICE.start, 7 + W1_SLICE.stop), *range(7 + W2_SLICE.start, 7 + W2_SLICE.stop))
_FREE = tuple(i for i in range(27) if i not in ESTIMATES)  # S11, S12, S13bar, v1, v2, i1, i2, x2f, x3f
DEFAULT_STEPS = np.logspace(-5.0, 0.0, 201)
SOURCES = ("model", "fmus")  # where ``linearise`` takes the matrices from: differences of the model, the FMUs


class OperatingPointError(DscFmuError, RuntimeError):
    """No operating point of steady tracking was found (Newton's method did not converge)."""


@dataclass
class LinearLoop:
    """The loop linearised about an operating point, in deviations from it.

    Plant ``xp' = Ap xp + Bp u, y = Cp xp``, controller ``xc' = Ac xc + Bc y, u = Cc xc + Dc y``. For the
    DSC loop (``linearise``) xp has 7 entries, xc 20, y 8 and u 2. Any small system can be built
    directly, e.g. ``LinearLoop([[-a]], [[b]], [[1]], [], [], [], [[-k]])`` (static u = -k y); matrices
    are converted to 2-D float arrays.

    Parameters
    ----------
    Ap, Bp, Cp : array_like
        The plant's matrices, shapes (np, np), (np, nu), (ny, np).
    Ac, Bc, Cc, Dc : array_like
        The controller's matrices, shapes (nc, nc), (nc, ny), (nu, nc), (nu, ny); Ac, Bc, Cc empty for
        a static controller.
    operating_point : numpy.ndarray or None, optional
        ``[xp; xc]`` (27) in error coordinates (``operating_point``). Default None.
    drift : float, optional
        The largest |derivative| at the operating point: 0 at an equilibrium, the frozen estimates'
        slow drift otherwise. Default 0.
    at_time : float or None, optional
        The time the operating point was taken at, in s. Default None.
    discretization : {"rk4", "euler"}, optional
        The controller's discretization (``models.parameters.DISCRETIZATIONS``). Default "rk4".
    """

    Ap: np.ndarray
    Bp: np.ndarray
    Cp: np.ndarray
    Ac: np.ndarray
    Bc: np.ndarray
    Cc: np.ndarray
    Dc: np.ndarray
    operating_point: np.ndarray | None = None
    drift: float = 0.0
    at_time: float | None = None
    discretization: str = "rk4"

    def __post_init__(self):
        for name in ("Ap", "Bp", "Cp", "Ac", "Bc", "Cc", "Dc"):
            setattr(self, name, np.atleast_2d(np.asarray(getattr(self, name), float)))
        if self.Ac.size == 0:  # a static controller: shapes (0, 0), (0, ny), (nu, 0)
            self.Ac = np.zeros((0, 0))
            self.Bc = np.zeros((0, self.Cp.shape[0]))
            self.Cc = np.zeros((self.Bp.shape[1], 0))

    @property
    def plant(self) -> control.StateSpace:
        """The linearised plant as a python-control system (Dp = 0)."""
        return control.ss(self.Ap, self.Bp, self.Cp, np.zeros((self.Cp.shape[0], self.Bp.shape[1])))

    @property
    def controller(self) -> control.StateSpace:
        """The linearised controller as a python-control system (direct feedthrough Dc)."""
        return control.ss(self.Ac, self.Bc, self.Cc, self.Dc)

    @property
    def closed_loop_matrix(self) -> np.ndarray:
        """Continuous closed-loop matrix ``[[Ap + Bp Dc Cp, Bp Cc], [Bc Cp, Ac]]`` of ``[xp; xc]``."""
        return np.block([[self.Ap + self.Bp @ self.Dc @ self.Cp, self.Bp @ self.Cc], [self.Bc @ self.Cp, self.Ac]])

    @property
    def poles(self) -> np.ndarray:
        """Continuous closed-loop poles, u = Cc xc + Dc y fed back with sign +1, sorted by real part."""
        p = control.poles(control.feedback(self.plant, self.controller, sign=1))
        return p[np.argsort(p.real)]


def _check_constant(scenario: Scenario) -> tuple[float, float]:
    """``(vr0, wr0)``; ValueError unless the profile is constant (the only one with steady tracking) and the
    disturbance torques are (a sinusoid makes the loop time-varying: no operating point)."""
    if PROFILES[int(scenario.reference["profile"])] != "constant":
        raise ValueError(f"{scenario.name}: the reference profile must be 'constant' for an operating point "
                         f"of steady tracking; got {PROFILES[int(scenario.reference['profile'])]!r}")
    plant = scenario.plant
    for i in (1, 2):
        if plant[f"tau_da{i}"] and plant[f"f_d{i}"]:
            raise ValueError(f"{scenario.name}: the disturbance torque of wheel {i} is a sinusoid (tau_da{i} = "
                             f"{plant[f'tau_da{i}']:g} N.m at f_d{i} = {plant[f'f_d{i}']:g} Hz): the loop has no "
                             "operating point of steady tracking; "
                             f"allowed: tau_da{i} = 0 or f_d{i} = 0 (a constant load)")
    return scenario.reference["vr0"], scenario.reference["wr0"]


def _check_unlimited(k: PlantCoefficients, g: Gains, vr: float, wr: float, z, name: str) -> None:
    """ValueError if a motor driver limits its voltage at ``z`` (27, error coordinates): no linear loop there."""
    if k.u_max is None:
        return
    law = control_law(g, list(z[7:]), error_measurements(error_outputs(k, list(z[:7])), vr, wr))
    for i, (u, limit) in enumerate(zip((law.u1, law.u2), k.u_max), start=1):
        if abs(u) > limit:
            raise ValueError(f"{name}: the voltage limit acts at the operating point of steady tracking or on the "
                             f"way to it (u{i} = {u:.6g} V, u_max{i} = {limit:g} V): the loop is not linear there; "
                             "allowed: a limit above the operating point's voltages, or voltage_limit = off")


def closed_loop_derivative(k: PlantCoefficients, g: Gains, vr: float, wr: float, z) -> np.ndarray:
    """The 27 derivatives (per s) of ``z = [xp; xc]`` in error coordinates (``error_coordinates``, the
    controller's 20 states): the plant (11), (7), (8) driven by u of (26), the controller (15)-(27);
    ``vr`` in m/s, ``wr`` in rad/s."""
    xp, xc = list(z[:7]), list(z[7:])
    law = control_law(g, xc, error_measurements(error_outputs(k, xp), vr, wr))
    return np.array([*error_plant_derivatives(k, vr, wr, xp, (law.u1, law.u2)), *law.derivative])


def jacobian(f, x, rel: float = 1e-6) -> np.ndarray:
    """The central finite-difference Jacobian (m, n) of ``f`` at ``x``, entry j perturbed by ``rel * max(1, |x_j|)``."""
    x = np.asarray(x, float)
    columns = []
    for j in range(x.size):
        d = rel * max(1.0, abs(x[j]))
        e = np.zeros_like(x)
        e[j] = d
        columns.append((np.asarray(f(x + e), float) - np.asarray(f(x - e), float)) / (2.0 * d))
    return np.array(columns).T.reshape(-1, x.size)


def _newton(f, z, free, tol: float = 1e-12, iterations: int = 50) -> np.ndarray:
    """Newton's method on ``f(z)[free] = 0`` over ``z[free]`` (other entries held); OperatingPointError if it fails."""
    z = np.array(z, float)
    free = list(free)
    for _ in range(iterations):
        def restricted(v, z=z):
            w = z.copy()
            w[free] = v
            return f(w)[free]

        try:
            dz = np.linalg.solve(jacobian(restricted, z[free]), -f(z)[free])
        except np.linalg.LinAlgError:
            break
        z[free] += dz
        if not np.all(np.isfinite(z)):
            break
        if np.max(np.abs(dz)) <= tol * max(1.0, np.max(np.abs(z[free]))):
            return z
    residual = np.max(np.abs(f(z)[free]))
    raise OperatingPointError(f"no operating point of steady tracking found: Newton's method did not converge "
                              f"(last residual {residual:.3g})")


def operating_point(scenario: Scenario, at_time: float | None = None, frozen: bool = True,
                    state=None) -> tuple[np.ndarray, float]:
    """The operating point of steady tracking in error coordinates.

    The continuous closed loop is integrated from the scenario's initial state (docs/model.md §5) to
    ``at_time``, or ``state`` is taken instead; then it is polished by Newton's method. With ``frozen``
    the adaptation is slow enough to freeze: the leakage poles are -sigma gamma, down to -1e-8 1/s, so a
    30 s run stays far from the equilibrium of the whole adaptive loop. That equilibrium, unique thanks
    to sigma-modification (15), (16), (21), (27), is unstable for the paper's gains (e.g. ra_hat = 3.47 >
    Ra + k5 there: the current loop (26) has negative resistance) and reached only after ~1e4 s.

    Parameters
    ----------
    scenario : Scenario
        A scenario with the constant reference profile.
    at_time : float or None, optional
        Where to take the point, in s. Default None: the scenario's stop time.
    frozen : bool, optional
        True (default): the 16 estimates (a1_hat, a2_hat, W1_hat, W2_hat) keep the values reached and
        the derivatives of the 11 other states vanish. False: all 27 derivatives vanish.
    state : array_like or None, optional
        ``[xp; xc]`` (27) in error coordinates to start Newton's method from (e.g. from a
        co-simulation at ``at_time``) instead of integrating. Default None.

    Returns
    -------
    z : numpy.ndarray
        The operating point ``[xp; xc]`` (27) in error coordinates.
    at_time : float
        The time it was taken at, in s.

    Raises
    ------
    ValueError
        If the scenario's reference profile is not constant, a disturbance torque is a sinusoid, or a motor
        driver limits its voltage where Newton's method starts or ends (docs/model.md §5.14).
    OperatingPointError
        If the integration or Newton's method fails.
    """
    vr, wr = _check_constant(scenario)
    k, g = plant_coefficients(scenario.plant), gains(scenario.controller)
    T = scenario.simulation.stop_time if at_time is None else float(at_time)
    f = lambda z: closed_loop_derivative(k, g, vr, wr, z)  # noqa: E731
    if state is None:
        xp0 = error_coordinates(initial_plant_state(scenario.plant), initial_reference_state(scenario.reference))
        xc0 = start_filters(g, initial_controller_state(scenario.controller), error_measurements(error_outputs(k, xp0), vr, wr))
        solution = solve_ivp(lambda t, z: f(z), (0.0, T), [*xp0, *xc0], method="LSODA", rtol=1e-10, atol=1e-10)
        if not solution.success:
            raise OperatingPointError(f"{scenario.name}: the continuous closed loop failed: {solution.message}")
        state = solution.y[:, -1]
    _check_unlimited(k, g, vr, wr, state, scenario.name)
    z = _newton(f, state, _FREE if frozen else range(27))
    _check_unlimited(k, g, vr, wr, z, scenario.name)
    return z, T


def linearise(scenario: Scenario, at_time: float | None = None, frozen: bool = True, rel: float = 1e-6,
              state=None, *, source: str = "model", fmu_paths: dict | None = None,
              workdir: Path | None = None) -> LinearLoop:
    """Linearise the plant and the controller about the operating point of steady tracking.

    At ``operating_point(scenario, at_time, frozen, state)``, either by central differences
    (``jacobian``) of ``error_plant_derivatives``, ``error_outputs`` and the control law (``source`` =
    "model"), or from the FMUs' exact directional derivatives there (``source`` = "fmus":
    ``study.fmu_loop.fmu_matrices``). The two agree to the differences' error: within 1e-9 of each
    matrix's largest entry for on_reference (tests/test_stability_fmus.py).

    Parameters
    ----------
    scenario : Scenario
        A scenario with the constant reference profile.
    at_time : float or None, optional
        Where to take the operating point, in s. Default None: the scenario's stop time.
    frozen : bool, optional
        Freeze the 16 estimates at the operating point (see ``operating_point``). Default True.
    rel : float, optional
        Relative finite-difference step of the model route. Default 1e-6.
    state : array_like or None, optional
        ``[xp; xc]`` (27) in error coordinates to start from instead of integrating. Default None.
    source : {"model", "fmus"}, optional
        Where the matrices come from (``SOURCES``). Default "model".
    fmu_paths : dict or None, optional
        The three FMU files by name (``registry.ORDER``), built with model exchange; needed for "fmus".
    workdir : pathlib.Path or None, optional
        Where the FMUs are extracted for "fmus". Default None: the system's temporary folder.

    Returns
    -------
    LinearLoop
        Plant (7 states, 2 inputs, 8 outputs) and controller (20 states), with the operating point,
        its drift, its time and the scenario's discretization.

    Raises
    ------
    ValueError
        If the scenario's reference profile is not constant, a disturbance torque is a sinusoid, a motor
        driver limits its voltage at the operating point, ``source`` is not one of ``SOURCES``, or "fmus" is
        asked for without ``fmu_paths``.
    OperatingPointError
        If no operating point is found.
    """
    source = one_of(SOURCES, source, "source")
    if source == "fmus" and fmu_paths is None:
        raise ValueError("source 'fmus' needs fmu_paths: the three FMU files by name")
    vr, wr = _check_constant(scenario)
    k, g = plant_coefficients(scenario.plant), gains(scenario.controller)
    z, T = operating_point(scenario, at_time, frozen, state)
    if source == "model":
        matrices = _model_matrices(k, g, vr, wr, z, rel)
    else:
        from .fmu_loop import fmu_matrices  # fmpy only when the FMUs are asked for

        matrices = fmu_matrices(scenario, fmu_paths, z, T, workdir)
    drift = float(np.max(np.abs(closed_loop_derivative(k, g, vr, wr, z))))
    return LinearLoop(*matrices, operating_point=z, drift=drift, at_time=T,
                      discretization=DISCRETIZATIONS[int(scenario.controller["discretization"])])


def _model_matrices(k: PlantCoefficients, g: Gains, vr: float, wr: float, z, rel: float) -> tuple:
    """``(Ap, Bp, Cp, Ac, Bc, Cc, Dc)`` at ``z`` by central differences of the Python model (``jacobian``)."""
    xp, xc = z[:7], z[7:]
    y = np.array(error_outputs(k, xp))
    law = control_law(g, list(xc), error_measurements(y, vr, wr))
    u = np.array([law.u1, law.u2])
    fp = lambda v: error_plant_derivatives(k, vr, wr, v[:7], v[7:])  # noqa: E731

    def fc(v):
        c = control_law(g, list(v[:20]), error_measurements(v[20:], vr, wr))
        return [*c.derivative, c.u1, c.u2]

    P = jacobian(fp, np.concatenate([xp, u]), rel)
    Cp = jacobian(lambda v: error_outputs(k, v), xp, rel)
    K = jacobian(fc, np.concatenate([xc, y]), rel)
    return P[:, :7], P[:, 7:], Cp, K[:20, :20], K[:20, 20:], K[20:, :20], K[20:, 20:]


def sampled_pieces(loop: LinearLoop, h: float, discretization: str) -> tuple[np.ndarray, ...]:
    """The plant and the controller sampled over one communication step.

    The plant by zero-order hold (``control.c2d``, exact with u held); the controller by zero-order hold
    for "rk4" (its RK4 sub-steps are nearly exact with y held) or by one explicit Euler step for "euler"
    (``Phi_c = I + h Ac``, ``Gamma_c = h Bc``).
    """
    one_of(DISCRETIZATIONS, discretization, "discretization")
    plant = control.c2d(loop.plant, h, method="zoh")
    if discretization == "euler":
        return plant.A, plant.B, np.eye(loop.Ac.shape[0]) + h * loop.Ac, h * loop.Bc
    if loop.Ac.shape[0] == 0:
        return plant.A, plant.B, loop.Ac, loop.Bc
    ctl = control.c2d(loop.controller, h, method="zoh")
    return plant.A, plant.B, ctl.A, ctl.B


def transition_matrix(loop: LinearLoop, h: float, order: str, discretization: str | None = None) -> np.ndarray:
    """The transition matrix M of ``[xp; xc]`` over one communication step ``h`` (s) with held inputs
    (as ``cosim.master`` steps); ValueError for an ``order`` or ``discretization`` not allowed
    (None: the loop's).

    At t_k the controller's inputs hold y_k = Cp xp_k and u_k = Cc xc_k + Dc y_k is read (feedthrough), so
    ``xp_{k+1} = Phi_p xp_k + Gamma_p u_k = Kp xp_k + Kc xc_k``, ``Kp = Phi_p + Gamma_p Dc Cp``, ``Kc = Gamma_p Cc``.

    - Jacobi: the controller integrates with y_k held, ``xc_{k+1} = Gamma_c Cp xp_k + Phi_c xc_k``, so
      ``M = [[Kp, Kc], [Gamma_c Cp, Phi_c]]``.
    - Gauss-Seidel: the plant steps first and the controller holds ``y_{k+1} = Cp xp_{k+1}``, so
      ``xc_{k+1} = Gamma_c Cp Kp xp_k + (Phi_c + Gamma_c Cp Kc) xc_k`` and
      ``M = [[Kp, Kc], [Gamma_c Cp Kp, Phi_c + Gamma_c Cp Kc]]``
      (u_{k+1} = Cc xc_{k+1} + Dc y_{k+1} then uses the same y_{k+1}: no further term).
    """
    order = one_of(Order, order, "order")
    Phi_p, Gamma_p, Phi_c, Gamma_c = sampled_pieces(loop, h, discretization or loop.discretization)
    Kp = Phi_p + Gamma_p @ loop.Dc @ loop.Cp
    Kc = Gamma_p @ loop.Cc
    if not order.sequential:
        bottom = [Gamma_c @ loop.Cp, Phi_c]
    else:
        bottom = [Gamma_c @ loop.Cp @ Kp, Phi_c + Gamma_c @ loop.Cp @ Kc]
    return np.block([[Kp, Kc], bottom])


def ramp_pieces(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A linear system sampled over one step with its input a ramp.

    For ``x' = A x + B w`` with ``w(s) = w0 + (s / h) d``: ``x(h) = Phi x(0) + G0 w0 + G1 d``, from the
    exponential of ``[[A, B, 0], [0, 0, I/h], [0, 0, 0]] h``.
    """
    n, m = B.shape
    F = np.zeros((n + 2 * m, n + 2 * m))
    F[:n, :n], F[:n, n:n + m], F[n:n + m, n + m:] = A, B, np.eye(m) / h
    E = expm(F * h)
    return E[:n, :n], E[:n, n:n + m], E[:n, n + m:]


def linear_transition_matrix(loop: LinearLoop, h: float, order: str, discretization: str | None = None) -> np.ndarray:
    """The transition matrix of ``s_k = [xp_k; xc_k; u_{k-1}; y_{k-1}]`` over one communication step ``h``
    (s) with the linear coupling (docs/model.md §5.10); ValueError for an ``order`` not allowed.

    The plant sees the ramp through ``u_{k-1}`` and ``u_k = Cc xc_k + Dc y_k``:
    ``xp_{k+1} = Phi_p xp_k + G0_p u_k + G1_p (u_k - u_{k-1})`` (``ramp_pieces``). The controller sees its
    inputs extrapolated through ``y_{k-1}`` and ``y_k`` (Jacobi), ``xc_{k+1} = Phi_c xc_k + G0_c y_k +
    G1_c (y_k - y_{k-1})``, or interpolated from ``y_k`` to ``y_{k+1} = Cp xp_{k+1}`` (Gauss-Seidel),
    ``xc_{k+1} = Phi_c xc_k + G0_c y_k + G1_c (y_{k+1} - y_k)``. With ``discretization`` = euler the
    controller takes ``xc + h (Ac xc + Bc y(t_k))``: ``G1_c = 0``.
    """
    order = one_of(Order, order, "order")
    Phi_p, G0_p, G1_p = ramp_pieces(loop.Ap, loop.Bp, h)
    nc, ny = loop.Bc.shape
    if (discretization or loop.discretization) == "euler":
        Phi_c, G0_c, G1_c = np.eye(nc) + h * loop.Ac, h * loop.Bc, np.zeros((nc, ny))
    else:
        Phi_c, G0_c, G1_c = ramp_pieces(loop.Ac, loop.Bc, h)
    Cp, Cc, Dc = loop.Cp, loop.Cc, loop.Dc
    n_p, nu = loop.Ap.shape[0], loop.Bp.shape[1]
    U = np.hstack([Dc @ Cp, Cc, np.zeros((nu, nu + ny))])  # u_k from s_k
    Y = np.hstack([Cp, np.zeros((ny, nc + nu + ny))])  # y_k from s_k
    U_before = np.hstack([np.zeros((nu, n_p + nc)), np.eye(nu), np.zeros((nu, ny))])
    Y_before = np.hstack([np.zeros((ny, n_p + nc + nu)), np.eye(ny)])
    Xp = np.hstack([Phi_p, np.zeros((n_p, nc + nu + ny))]) + (G0_p + G1_p) @ U - G1_p @ U_before
    Xc = np.hstack([np.zeros((nc, n_p)), Phi_c, np.zeros((nc, nu + ny))])
    if not order.sequential:
        Xc = Xc + (G0_c + G1_c) @ Y - G1_c @ Y_before
    else:
        Xc = Xc + (G0_c - G1_c) @ Y + G1_c @ Cp @ Xp
    return np.vstack([Xp, Xc, U, Y])


_TRANSITION = {Coupling.HOLD: transition_matrix, Coupling.LINEAR: linear_transition_matrix}


def spectral_radius(loop: LinearLoop, h: float, order: str, discretization: str | None = None,
                    coupling: str = "hold") -> float:
    """The spectral radius of the sampled loop: it is stable where this is below 1.

    Parameters
    ----------
    loop : LinearLoop
        The linearised loop.
    h : float
        The communication step, in s.
    order : {"gauss-seidel", "jacobi"}
        The coupling order (``scenario.ORDERS``).
    discretization : {"rk4", "euler"} or None, optional
        The controller's discretization. Default None: the loop's.
    coupling : {"hold", "linear"}, optional
        The coupling (``scenario.COUPLINGS``): ``transition_matrix`` for "hold" (default),
        ``linear_transition_matrix`` for "linear".

    Returns
    -------
    float
        The largest |eigenvalue| of the transition matrix.

    Raises
    ------
    ValueError
        If ``coupling`` or ``order`` is not one of the allowed names, or ``discretization`` with the
        hold coupling.
    """
    matrix = _TRANSITION[one_of(Coupling, coupling, "coupling")](loop, h, order, discretization)
    return float(np.max(np.abs(np.linalg.eigvals(matrix))))


def spectral_radius_curve(loop: LinearLoop, steps, order: str, discretization: str | None = None,
                          coupling: str = "hold") -> np.ndarray:
    """The spectral radius at each of several communication steps, for plotting against h."""
    return np.array([spectral_radius(loop, h, order, discretization, coupling) for h in np.asarray(steps, float)])


def predicted_boundary(loop: LinearLoop | Scenario, order: str, discretization: str | None = None, *,
                       steps=DEFAULT_STEPS, rtol: float = 1e-3, tol: float = 1e-9, coupling: str = "hold") -> float:
    """The predicted stability boundary: the smallest step at which the spectral radius reaches 1.

    The first crossing of ``1 + tol`` on the ascending grid ``steps``, bisected geometrically to ``rtol``.
    Only the first crossing counts: the curve need not be monotonic (stable windows can follow).

    Parameters
    ----------
    loop : LinearLoop or Scenario
        The linearised loop; a Scenario is linearised first (``linearise``).
    order : {"gauss-seidel", "jacobi"}
        The coupling order (``scenario.ORDERS``).
    discretization : {"rk4", "euler"} or None, optional
        The controller's discretization. Default None: the loop's.
    steps : array_like, optional
        Ascending communication steps to scan, in s. Default 201 steps from 1e-5 s to 1 s, log-spaced.
    rtol : float, optional
        Relative width to bisect the crossing to. Default 1e-3.
    tol : float, optional
        Margin above 1, above the rounding of the slow adaptation modes (|lambda| = 1 - O(1e-8 h)).
        Default 1e-9.
    coupling : {"hold", "linear"}, optional
        The coupling (``scenario.COUPLINGS``). Default "hold".

    Returns
    -------
    float
        The boundary h*, in s; 0.0 if unstable at ``steps[0]``, inf if stable on the whole grid.

    Raises
    ------
    ValueError
        If ``coupling`` or ``order`` is not one of the allowed names, or ``discretization`` with the
        hold coupling, or a Scenario's reference profile is not constant.
    OperatingPointError
        If a Scenario has no operating point.
    """
    if isinstance(loop, Scenario):
        loop = linearise(loop)
    unstable = lambda h: spectral_radius(loop, h, order, discretization, coupling) >= 1.0 + tol  # noqa: E731
    steps = np.asarray(steps, float)
    previous = None
    for h in steps:
        if unstable(h):
            break
        previous = h
    else:
        return math.inf
    if previous is None:
        return 0.0
    lo, hi = previous, h
    while hi / lo - 1.0 > rtol:
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if unstable(mid) else (mid, hi)
    return math.sqrt(lo * hi)
