"""The reference robot (9) and its velocity profiles vr(t), wr(t), vr_dot(t)."""

import math

__all__ = ["reference_derivatives"]

CONSTANT = 0
FIGURE_EIGHT = 1


def _figure_eight(t: float, A: float, B: float, T: float, math=math) -> tuple:
    """Speed, turn rate and acceleration along x = A sin(W t), y = B sin(2 W t), W = 2 pi / T (``math``: as in
    ``velocity``)."""
    W = 2.0 * math.pi / T
    s1, c1 = math.sin(W * t), math.cos(W * t)
    s2, c2 = math.sin(2.0 * W * t), math.cos(2.0 * W * t)
    xd, yd = A * W * c1, 2.0 * B * W * c2
    xdd, ydd = -A * W * W * s1, -4.0 * B * W * W * s2
    v = math.hypot(xd, yd)
    return v, (xd * ydd - yd * xdd) / (v * v), (xd * xdd + yd * ydd) / v


def velocity(p: dict, t: float, math=math) -> tuple:
    """``(vr, wr, vr_dot)`` of (9) at time ``t`` (s), in m/s, rad/s, m/s2, for the ReferenceRobot FMU's parameters
    ``p``, whose ``profile`` selects the profile (docs/model.md §5.8); ``math``: where ``sin``, ``cos`` and ``hypot``
    come from (the module, or a namespace such as ``dual.DUAL_MATH``).
    """
    if p["profile"] == FIGURE_EIGHT:
        return _figure_eight(t, p["eight_A"], p["eight_B"], p["eight_T"], math)
    return p["vr0"], p["wr0"], 0.0


def min_speed(p: dict, t_end: float) -> float:
    """Smallest vr (m/s) over ``[0, t_end]`` for the ReferenceRobot FMU's parameters ``p`` (docs/model.md §5.7: vr > 0
    is required). Exact: for the figure eight, vr^2 = W^2 (A^2 s + 4 B^2 (2 s - 1)^2) with s = cos^2(W t) in
    [0, 1], minimised in closed form (over a whole period, so a lower bound for any shorter run).
    """
    if p["profile"] != FIGURE_EIGHT:
        return p["vr0"]
    A, B = p["eight_A"], p["eight_B"]
    W = 2.0 * math.pi / p["eight_T"]
    s = min(1.0, max(0.0, 0.5 * (1.0 - A * A / (16.0 * B * B))))
    return W * math.sqrt(A * A * s + 4.0 * B * B * (2.0 * s - 1.0) ** 2)


def initial_reference_state(p: dict) -> list:
    """``[xr, yr, thetar]`` at t = 0 from the parameters ``x0``, ``y0``, ``theta0``."""
    return [p["x0"], p["y0"], p["theta0"]]


def reference_derivatives(p: dict, t: float, x: list, math=math) -> list:
    """Time derivative of the reference's state, equation (9).

    Parameters
    ----------
    p : dict
        The ReferenceRobot FMU's parameter values by name.
    t : float
        Time, in s.
    x : list of float
        The state ``[xr, yr, thetar]`` in m, m, rad.
    math : namespace, optional
        Where ``sin``, ``cos`` and ``hypot`` come from: the ``math`` module (default), or ``dual.DUAL_MATH`` for
        directional derivatives with ``x`` duals (the profile depends on ``t`` alone).

    Returns
    -------
    list of float
        ``[vr cos(thetar), vr sin(thetar), wr]`` in m/s, m/s, rad/s.
    """
    vr, wr, _ = velocity(p, t, math)
    return [vr * math.cos(x[2]), vr * math.sin(x[2]), wr]
