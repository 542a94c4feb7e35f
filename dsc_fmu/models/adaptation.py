"""The adaptation laws (15), (16), (21), (27) and Remark 4's alternatives: sigma-, e-modification, projection, none.

The estimates are ``a1_hat``, ``a2_hat``, ``W1_hat`` and ``W2_hat`` of the controller state ``xc``
(models/controller.py); docs/model.md §3 writes the four laws out and §5.13 the projection's switches.
"""

from __future__ import annotations

import math

from .parameters import ADAPTATIONS

__all__ = ["SIGMA", "E_MODIFICATION", "PROJECTION", "NONE", "project_rates", "project_estimates", "projection_conflict"]

SIGMA, E_MODIFICATION, PROJECTION, NONE = (ADAPTATIONS.index(name) for name in ("sigma", "e", "projection", "none"))
"""The values of the controller's parameter ``adaptation``."""

A1, A2, W1, W2 = 0, 1, slice(4, 12), slice(14, 20)  # the estimates' places in xc
# A weight vector is on its sphere from this fraction of the bound's square: a vector scaled onto the
# sphere (``project_estimates``) lands there to rounding, on either side.
ON_SPHERE = 1.0 - 1e-12


def _interval(value, rate, low: float, high: float, held: bool | None) -> tuple:
    """``(rate, active, margin)`` of an estimate kept in ``[low, high]``: the rate zero while the projection acts
    (on a bound with the rate pointing out, or ``held``); ``margin`` > 0 while the choice stands: while it acts the
    outward rate, else the larger of the distance to the nearer bound and the inward rate (an estimate that
    leaves a bound inward is not due)."""
    outward = rate if value > 0.5 * (low + high) else -rate
    active = ((value >= high or value <= low) and outward > 0.0) if held is None else held
    if active:
        return 0.0, True, outward
    return rate, False, max(min(high - value, value - low), -outward)


def _ball(W: list, rates: list, Gamma: tuple, bound: float, held: bool | None, math=math) -> tuple:
    """``(rates, active, margin)`` of a weight vector kept in the ball ``|W| <= bound``: Ioannou and Sun's
    projection (§4.4) in the metric of ``Gamma``, ``rates - Gamma W (W^T rates) / (W^T Gamma W)``, while ``W`` is
    on (``ON_SPHERE``) or outside the sphere with ``W^T rates`` > 0 (or ``held``); ``margin`` as in ``_interval``:
    ``W^T rates`` while it acts, else the larger of ``bound - |W|`` and ``-W^T rates``."""
    outward = math.fsum(w * r for w, r in zip(W, rates))
    squares = math.fsum(w * w for w in W)
    active = (squares >= ON_SPHERE * bound * bound and outward > 0.0) if held is None else held
    if not active:
        return rates, False, max(bound - math.sqrt(squares), -outward)
    weighted = math.fsum(G * w * w for G, w in zip(Gamma, W))
    if not weighted:  # W = 0, held by an importer's states: no normal to remove
        return rates, True, outward
    scale = outward / weighted
    return [r - G * w * scale for r, G, w in zip(rates, Gamma, W)], True, outward


def project_rates(g, xc: list, rates: list, held: tuple | None = None, math=math) -> tuple:
    """The gradient laws' rates under the projection of ``adaptation`` = projection (docs/model.md §3).

    The discontinuous operator of Ioannou and Sun (§4.4) on the rates ``rates`` of the gradient laws (the
    derivative of ``xc`` without leakage), keeping ``a1_hat`` in ``[a1_min, a1_max]``, ``a2_hat`` in
    ``[a2_min, a2_max]``, ``W1_hat`` in ``|W1_hat| <= W1_max`` and ``W2_hat`` in ``|W2_hat| <= W2_max``.

    Parameters
    ----------
    g : controller.Gains
        The design parameters with the bounds.
    xc, rates : list
        The controller state and its derivative without leakage (20 entries each).
    held : tuple of bool, optional
        Whether the projection acts on each of the four estimates, held since the last event (model exchange).
        Default None: chosen at ``xc`` (on or outside the set's boundary with the rate pointing out).
    math : namespace, optional
        Where the functions of ``math`` come from (``dual.DUAL_MATH`` for directional derivatives).

    Returns
    -------
    tuple
        ``(rates, active, margins)``: the projected derivative (a new list), whether the projection acts on each
        estimate, and each estimate's margin, positive while its choice stands (the event indicator's terms).
    """
    held = held or (None, None, None, None)
    a1_rate, a1_active, a1_margin = _interval(xc[A1], rates[A1], g.a1_min, g.a1_max, held[0])
    a2_rate, a2_active, a2_margin = _interval(xc[A2], rates[A2], g.a2_min, g.a2_max, held[1])
    W1_rates, W1_active, W1_margin = _ball(xc[W1], rates[W1], g.Gamma1, g.W1_max, held[2], math)
    W2_rates, W2_active, W2_margin = _ball(xc[W2], rates[W2], g.Gamma2, g.W2_max, held[3], math)
    projected = [a1_rate, a2_rate, *rates[2:4], *W1_rates, *rates[12:14], *W2_rates]
    return projected, (a1_active, a2_active, W1_active, W2_active), (a1_margin, a2_margin, W1_margin, W2_margin)


def project_estimates(g, xc: list, math=math) -> list:
    """The controller state with its estimates moved onto their sets (the discrete-time projection).

    docs/model.md §5.13.

    Parameters
    ----------
    g : controller.Gains
        The design parameters with the bounds.
    xc : list of float
        The controller state (20 entries).
    math : namespace, optional
        Where ``sqrt`` and ``fsum`` come from (the module, or a namespace that traces them).

    Returns
    -------
    list of float
        ``xc`` itself where every estimate is in its set; else a new list with ``a1_hat``, ``a2_hat`` clipped to
        their intervals and ``W1_hat``, ``W2_hat`` scaled onto their balls where outside (to rounding).
    """
    a1, a2 = min(max(xc[A1], g.a1_min), g.a1_max), min(max(xc[A2], g.a2_min), g.a2_max)
    W1_norm, W2_norm = math.sqrt(math.fsum(w * w for w in xc[W1])), math.sqrt(math.fsum(w * w for w in xc[W2]))
    if a1 == xc[A1] and a2 == xc[A2] and W1_norm <= g.W1_max and W2_norm <= g.W2_max:
        return xc
    W1_scale = g.W1_max / W1_norm if W1_norm > g.W1_max else 1.0
    W2_scale = g.W2_max / W2_norm if W2_norm > g.W2_max else 1.0
    return [a1, a2, *xc[2:4], *(w * W1_scale for w in xc[W1]), *xc[12:14], *(w * W2_scale for w in xc[W2])]


def projection_conflict(p: dict) -> str | None:
    """Why the controller's parameter values do not make a projection's sets.

    Parameters
    ----------
    p : dict
        The DSCController FMU's parameter values by name.

    Returns
    -------
    str or None
        The reason in one line, naming the values and what is allowed; None if each interval has ``min < max``
        and, with ``adaptation`` = projection, each initial estimate lies in its set.
    """
    for name in ("a1", "a2"):
        low, high = p[f"{name}_min"], p[f"{name}_max"]
        if not low < high:
            return f"{name}_min = {low:g} is not below {name}_max = {high:g}; allowed: {name}_min < {name}_max"
    if p["adaptation"] != PROJECTION:
        return None
    for name in ("a1", "a2"):
        value, low, high = p[f"{name}_hat0"], p[f"{name}_min"], p[f"{name}_max"]
        if not low <= value <= high:
            return (f"{name}_hat0 = {value:g} is outside [{name}_min, {name}_max] = [{low:g}, {high:g}]; allowed: an "
                    "initial estimate in its set (adaptation = projection)")
    for name, count in (("W1", 8), ("W2", 6)):
        norm, bound = math.sqrt(math.fsum(p[f"{name}_hat0_{i}"] ** 2 for i in range(1, count + 1))), p[f"{name}_max"]
        if norm > bound:
            return (f"|{name}_hat0| = {norm:g} is outside the ball {name}_max = {bound:g}; allowed: an initial "
                    "estimate in its set (adaptation = projection)")
    return None
