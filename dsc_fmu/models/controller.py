"""The adaptive dynamic surface control law, steps 1-3: equations (10)-(27).

Controller state ``xc`` (20 entries, docs/model.md §3):
``[a1_hat, a2_hat, x2f1, x2f2, W1_hat (8), x3f1, x3f2, W2_hat (6)]``.
Measurements ``m`` (14 entries, the controller FMU's inputs in order):
``[x, y, theta, theta_dot, omega1, omega2, i1, i2, x_r, y_r, theta_r, v_r, omega_r, v_r_dot]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from .adaptation import E_MODIFICATION, PROJECTION, SIGMA, project_rates

# The helpers of the law (weight_norm, wrap, alpha2, switches, event_indicators, initial_controller_state,
# start_filters) serve the FMUs' models and the reference solution.
__all__ = ["Gains", "gains", "ControlLaw", "control_law", "Switches", "W1_SLICE", "W2_SLICE"]


def weight_norm(values, math=math) -> float:
    """The Euclidean norm of a weight estimate (``W1_hat_norm``, ``W2_hat_norm``; eqs. 21, 27), its sum of
    squares exactly rounded (``math.fsum``): every CPython gives the same bits (``sum`` of floats rounds
    differently from 3.12 on)."""
    return math.sqrt(math.fsum(v * v for v in values))

W1_SLICE = slice(4, 12)
W2_SLICE = slice(14, 20)
_UNPROJECTED = (False, False, False, False)


@dataclass(frozen=True)
class Gains:
    """The design parameters of Section III (names as the controller FMU's parameters).

    Parameters
    ----------
    k1, k2, k3, k4, k5 : float
        The gains of (12), (14), (14), (20) and (26).
    gamma1, gamma2 : float
        The adaptation gains of (15) and (16).
    sigma1, sigma2, sigma3, sigma4 : float
        The sigma-modifications of (15), (16), (21) and (27); the gains of e-modification.
    tau2, tau3 : float
        The filter time constants of (17) and (23), in s.
    Gamma1 : tuple of float
        The diagonal of the adaptation gain matrix of (21), 8 entries.
    Gamma2 : tuple of float
        The diagonal of the adaptation gain matrix of (27), 6 entries.
    beta_min : float
        The guard of beta (docs/model.md §5.6).
    adaptation : int
        The adaptation law, an index of ``parameters.ADAPTATIONS`` (``adaptation.SIGMA``, ...).
    a1_min, a1_max, a2_min, a2_max : float
        The intervals of ``a1_hat`` (1/m) and ``a2_hat`` of the projection.
    W1_max, W2_max : float
        The bounds of ``|W1_hat|`` and ``|W2_hat|`` of the projection.
    """

    k1: float
    k2: float
    k3: float
    k4: float
    k5: float
    gamma1: float
    gamma2: float
    sigma1: float
    sigma2: float
    sigma3: float
    sigma4: float
    tau2: float
    tau3: float
    Gamma1: tuple
    Gamma2: tuple
    beta_min: float
    adaptation: int
    a1_min: float
    a1_max: float
    a2_min: float
    a2_max: float
    W1_max: float
    W2_max: float


def gains(p: dict) -> Gains:
    """Gains from the controller FMU's parameter values by name.

    Parameters
    ----------
    p : dict
        The DSCController FMU's parameter values by name (``Gamma1_1`` ... ``Gamma1_8`` and so on).

    Returns
    -------
    Gains
        The design parameters.
    """
    return Gains(
        **{name: p[name] for name in Gains.__dataclass_fields__ if not name.startswith("Gamma")},
        Gamma1=tuple(p[f"Gamma1_{i}"] for i in range(1, 9)),
        Gamma2=tuple(p[f"Gamma2_{i}"] for i in range(1, 7)),
    )


class ControlLaw(NamedTuple):
    """One evaluation of the law: the voltages, the state derivative and what is shown of it.

    Parameters
    ----------
    u1, u2 : float
        The motor voltages of (26), right and left wheel, in V.
    derivative : list of float
        The time derivative of the controller state ``xc`` (20 entries).
    S11, S12 : float
        The tracking errors in the robot frame of (10), in m.
    S13 : float
        The transformed heading error of (12), in rad.
    beta : float
        ``1 + k1 vr S11 / (1 + (k1 S12 vr)^2)`` of (13), before the guard.
    guarded : bool
        Whether ``h2`` divided by ``beta_min`` instead of ``beta`` (docs/model.md §5.6).
    x2bar : tuple of float
        The virtual wheel speeds of (14), in rad/s.
    x3bar : tuple of float
        The virtual currents of (20), in A.
    projected : tuple of bool
        Whether the projection acts on ``a1_hat``, ``a2_hat``, ``W1_hat``, ``W2_hat`` (adaptation = projection).
    margins : tuple of float
        The projection's margins (``adaptation.project_rates``), empty for the other laws.
    """

    u1: float
    u2: float
    derivative: list
    S11: float
    S12: float
    S13: float
    beta: float
    guarded: bool
    x2bar: tuple
    x3bar: tuple
    projected: tuple
    margins: tuple


class Switches(NamedTuple):
    """The discrete choices of the law (docs/model.md §5.13), held between events in model exchange.

    Parameters
    ----------
    turns : int
        The wrap of (5.4): ``S13bar = (thetar - theta) - 2 pi turns``.
    guarded : bool
        Whether ``h2`` divides by ``beta_min`` (5.6).
    projected : tuple of bool
        Whether the projection acts on ``a1_hat``, ``a2_hat``, ``W1_hat``, ``W2_hat`` (5.13; adaptation =
        projection).
    """

    turns: int
    guarded: bool
    projected: tuple = _UNPROJECTED


def wrap(angle: float, math=math) -> float:
    """``angle`` (rad) less the nearest multiple of 2 pi, in (-pi, pi] (docs/model.md §5.4; -pi becomes pi)."""
    wrapped = math.remainder(angle, 2.0 * math.pi)
    return wrapped + 2.0 * math.pi if wrapped == -math.pi else wrapped


def alpha2(S13: float, a: float, math=math) -> float:
    """``integral_0^1 cos(-a + eta S13) d eta`` of (15) = ``sinc(S13 / 2) cos(S13 / 2 - a)``, free of
    cancellation near S13 = 0 (docs/model.md §5.5); ``a = arctan(k1 S12 vr)`` of (12)."""
    half = 0.5 * S13
    sinc = 1.0 - half * half / 6.0 if abs(half) < 1e-4 else math.sin(half) / half
    return sinc * math.cos(half - a)


def initial_controller_state(p: dict) -> list:
    """``xc`` at the start with the estimates from the parameters ``p`` (``a1_hat0``, ``a2_hat0``,
    ``W1_hat0_i``, ``W2_hat0_i``; docs/model.md §5.1) and the filters zero (``start_filters`` sets them)."""
    return [
        p["a1_hat0"], p["a2_hat0"], 0.0, 0.0, *(p[f"W1_hat0_{i}"] for i in range(1, 9)),
        0.0, 0.0, *(p[f"W2_hat0_{i}"] for i in range(1, 7)),
    ]


def _surfaces(k1: float, m: list, math=math) -> tuple:
    """``(S11, S12, p, den, beta)`` of step 1 for measurements ``m``: (10), ``p = k1 S12 vr`` of (12),
    ``den = 1 + p^2`` and ``beta`` of (13)."""
    x, y, theta, xr, yr, vr = m[0], m[1], m[2], m[8], m[9], m[11]
    ex, ey = xr - x, yr - y
    cos_t, sin_t = math.cos(theta), math.sin(theta)
    S11 = cos_t * ex + sin_t * ey
    S12 = -sin_t * ex + cos_t * ey
    p = k1 * S12 * vr
    den = 1.0 + p * p
    return S11, S12, p, den, 1.0 + k1 * vr * S11 / den


def switches(g: Gains, xc: list, m: list) -> Switches:
    """The switches as the law chooses them at the state ``xc`` and measurements ``m``: the wrap of
    ``thetar - theta``, whether the beta guard acts and whether the projection acts on each estimate
    (docs/model.md §5.4, §5.6, §5.13)."""
    heading = m[10] - m[2]
    beta = _surfaces(g.k1, m)[4]
    turns = round((heading - wrap(heading)) / (2.0 * math.pi))
    if g.adaptation == PROJECTION:
        return Switches(turns, beta < g.beta_min, control_law(g, xc, m).projected)
    return Switches(turns, beta < g.beta_min)


def event_indicators(g: Gains, xc: list, m: list, held: Switches | None = None, math=math) -> list:
    """``[cos((thetar - theta) / 2), beta - beta_min, projection margin]`` at the state ``xc`` and measurements
    ``m`` with the switches ``held``: each changes sign exactly where a switch of ``switches`` is due
    (docs/model.md §5.13); the projection's is the least of its margins (``adaptation.project_rates``), 1 for
    the other laws; ``math`` as in ``control_law``."""
    margin = min(control_law(g, xc, m, held, math).margins) if g.adaptation == PROJECTION else 1.0
    return [math.cos(0.5 * (m[10] - m[2])), _surfaces(g.k1, m, math)[4] - g.beta_min, margin]


def control_law(g: Gains, xc: list, m: list, held: Switches | None = None, math=math) -> ControlLaw:
    """Evaluate the three DSC steps, equations (10)-(27).

    Parameters
    ----------
    g : Gains
        The design parameters.
    xc : list of float
        The controller state (20 entries, see the module).
    m : list of float
        The measurements (14 entries, see the module).
    held : Switches or None, optional
        The switches held since the last event (model exchange). Default None: chosen at ``m``.
    math : namespace, optional
        Where the functions of ``math`` come from: the module (default), or ``dual.DUAL_MATH`` for
        directional derivatives on duals.

    Returns
    -------
    ControlLaw
        The voltages (26), the derivative of ``xc`` and the law's intermediate values.
    """
    _, _, theta, theta_dot, v1, v2, i1, i2, _, _, thetar, vr, wr, vr_dot = m
    a1_hat, a2_hat, x2f1, x2f2 = xc[0], xc[1], xc[2], xc[3]
    W1_hat = xc[W1_SLICE]
    x3f1, x3f2 = xc[12], xc[13]
    W2_hat = xc[W2_SLICE]
    k1 = g.k1

    # Step 1, kinematics: (10), (12), (14)-(16).
    S11, S12, p, den, beta = _surfaces(k1, m, math)
    if held is None:
        S13bar = wrap(thetar - theta, math)
        guarded = beta < g.beta_min
    else:
        S13bar = (thetar - theta) - 2.0 * math.pi * held.turns
        guarded = held.guarded
    a = math.atan(p)
    S13 = S13bar + a
    sin_e, cos_e = math.sin(S13bar), math.cos(S13bar)
    alpha1 = (k1 * vr * vr * sin_e + k1 * S12 * vr_dot) / den
    al2 = alpha2(S13, a, math)
    kv = k1 * vr
    h1 = a1_hat * vr * cos_e + g.k2 * S11 + 0.5 * kv * kv * kv * kv * S11 * S11 * S11
    h2 = (a1_hat * al2 * vr * S12 + a2_hat * (wr + alpha1) + g.k3 * S13 + 0.5 * S13 * S13 * S13) / (
        g.beta_min if guarded else beta
    )
    x2bar1, x2bar2 = h1 + h2, h1 - h2

    # Step 2, robot dynamics: (17)-(22).
    x2f_dot1 = (x2bar1 - x2f1) / g.tau2
    x2f_dot2 = (x2bar2 - x2f2) / g.tau2
    # Phi1 = [[-theta_dot v2, 0, -v1, 0, -x2f_dot1, -x2f_dot2, 0, 0],
    #         [0, theta_dot v1, 0, -v2, 0, 0, -x2f_dot2, -x2f_dot1]], its products written out.
    S21, S22 = v1 - x2f1, v2 - x2f2
    w1, w2, w3, w4, w5, w6, w7, w8 = W1_hat
    x3bar1 = -g.k4 * S21 + theta_dot * v2 * w1 + v1 * w3 + x2f_dot1 * w5 + x2f_dot2 * w6
    x3bar2 = -g.k4 * S22 - theta_dot * v1 * w2 + v2 * w4 + x2f_dot2 * w7 + x2f_dot1 * w8

    # Step 3, actuators: (23)-(26).
    x3f_dot1 = (x3bar1 - x3f1) / g.tau3
    x3f_dot2 = (x3bar2 - x3f2) / g.tau3
    # Phi2 = [[-i1, 0, -v1, 0, -x3f_dot1, 0], [0, -i2, 0, -v2, 0, -x3f_dot2]], written out.
    S31, S32 = i1 - x3f1, i2 - x3f2
    r1, r2, e1, e2, l1, l2 = W2_hat
    u1 = -g.k5 * S31 + i1 * r1 + v1 * e1 + x3f_dot1 * l1
    u2 = -g.k5 * S32 + i2 * r2 + v2 * e2 + x3f_dot2 * l2

    # The adaptation laws (15), (16), (21), (27): the leakage of each (docs/model.md §3).
    law = g.adaptation
    if law == SIGMA:
        s1, s2, s3, s4 = g.sigma1, g.sigma2, g.sigma3, g.sigma4
    elif law == E_MODIFICATION:
        s1 = g.sigma1 * math.sqrt(S11 * S11 + S12 * S12 + S13 * S13)
        s2 = g.sigma2 * abs(S13)
        s3 = g.sigma3 * math.sqrt(S21 * S21 + S22 * S22)
        s4 = g.sigma4 * math.sqrt(S31 * S31 + S32 * S32)
    else:
        s1 = s2 = s3 = s4 = 0.0
    a1_hat_dot = g.gamma1 * (vr * (S11 * cos_e + al2 * S12 * S13) - s1 * a1_hat)
    a2_hat_dot = g.gamma2 * ((wr + alpha1) * S13 - s2 * a2_hat)
    G1 = g.Gamma1
    W1_hat_dot = [
        G1[0] * (-theta_dot * v2 * S21 - s3 * w1),
        G1[1] * (theta_dot * v1 * S22 - s3 * w2),
        G1[2] * (-v1 * S21 - s3 * w3),
        G1[3] * (-v2 * S22 - s3 * w4),
        G1[4] * (-x2f_dot1 * S21 - s3 * w5),
        G1[5] * (-x2f_dot2 * S21 - s3 * w6),
        G1[6] * (-x2f_dot2 * S22 - s3 * w7),
        G1[7] * (-x2f_dot1 * S22 - s3 * w8),
    ]
    G2 = g.Gamma2
    W2_hat_dot = [
        G2[0] * (-i1 * S31 - s4 * r1),
        G2[1] * (-i2 * S32 - s4 * r2),
        G2[2] * (-v1 * S31 - s4 * e1),
        G2[3] * (-v2 * S32 - s4 * e2),
        G2[4] * (-x3f_dot1 * S31 - s4 * l1),
        G2[5] * (-x3f_dot2 * S32 - s4 * l2),
    ]

    derivative = [a1_hat_dot, a2_hat_dot, x2f_dot1, x2f_dot2, *W1_hat_dot, x3f_dot1, x3f_dot2, *W2_hat_dot]
    projected, margins = _UNPROJECTED, ()
    if law == PROJECTION:
        derivative, projected, margins = project_rates(g, xc, derivative, held and held.projected, math)
    return ControlLaw(u1, u2, derivative, S11, S12, S13, beta, guarded, (x2bar1, x2bar2), (x3bar1, x3bar2),
                      projected, margins)


def start_filters(g: Gains, xc: list, m: list, math=math) -> list:
    """A new ``xc`` with its filters started from the measurements ``m``: ``x2f(0) = x2bar(0)`` of (17), then
    ``x3f(0) = x3bar(0)`` of (23) (docs/model.md §5.2); with ``x2f = x2bar``, ``x2f_dot`` is zero when
    ``x3bar`` is formed."""
    xc = list(xc)
    xc[2:4] = control_law(g, xc, m, math=math).x2bar
    xc[12:14] = control_law(g, xc, m, math=math).x3bar
    return xc
