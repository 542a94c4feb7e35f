"""The electrically driven differential-drive robot: kinematics (1), dynamics (2), motors (5), drivers and loads."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

# The helpers (theta_dot, initial_plant_state, the drivers' switches FREE, HIGH, LOW, saturation, applied_voltages,
# saturation_indicators) serve the FMUs' models, the reference solution and the studies.
__all__ = ["PlantCoefficients", "LoadTorque", "plant_coefficients", "plant_derivatives"]

FREE, HIGH, LOW = 0, 1, -1
"""A motor driver's switch (docs/model.md §5.14): the voltage applied is u (free), +u_max (high) or -u_max (low)."""
UNLIMITED = (FREE, FREE)


class LoadTorque(NamedTuple):
    """One wheel's disturbance torque ``tau_d(t) = constant + amplitude sin(2 pi frequency t + phase)``, a load in (2).

    Parameters
    ----------
    constant, amplitude : float
        In N.m.
    frequency : float
        In Hz.
    phase : float
        In rad.
    """

    constant: float
    amplitude: float
    frequency: float
    phase: float

    def at(self, t: float, math=math) -> float:
        """The torque at a time.

        Parameters
        ----------
        t : float
            The time, in s.
        math : namespace, optional
            Where ``sin`` and ``pi`` come from (``math`` or ``dual.DUAL_MATH``).

        Returns
        -------
        float
            The torque, in N.m.
        """
        return self.constant + self.amplitude * math.sin(2.0 * math.pi * self.frequency * t + self.phase)


@dataclass(frozen=True)
class PlantCoefficients:
    """The constants of equations (1)-(8), computed once from the physical parameters.

    Parameters
    ----------
    r : float
        Wheel radius, in m.
    R : float
        Half the distance between the driving wheels, in m.
    m11, m12 : float
        The entries of the inertia matrix M of (2), in kg.m2.
    c : float
        The Coriolis coefficient, C = c [[0, theta_dot], [-theta_dot, 0]] in (2), in kg.m2.
    d11, d22 : float
        The viscous damping D of (2), right and left wheel, in N.m.s/rad.
    nkt1, nkt2 : float
        Gear ratio times torque constant, n kt of (5), in N.m/A.
    nke1, nke2 : float
        Gear ratio times back-EMF constant, n ke of (5), in V.s/rad.
    ra1, ra2 : float
        Armature resistances of (5), in Ohm.
    la1, la2 : float
        Armature inductances of (5), in H.
    u_max : tuple of float or None, optional
        ``(u_max1, u_max2)`` in V, the drivers' limits; None (default): no limit (docs/model.md §5.14).
    loads : tuple of LoadTorque or None, optional
        The disturbance torque of each wheel; None (default): none.
    """

    r: float
    R: float
    m11: float
    m12: float
    c: float
    d11: float
    d22: float
    nkt1: float
    nkt2: float
    nke1: float
    nke2: float
    ra1: float
    ra2: float
    la1: float
    la2: float
    u_max: tuple | None = None
    loads: tuple | None = None

    @property
    def det_M(self) -> float:
        """Determinant of M, m11^2 - m12^2 (> 0: M is positive definite)."""
        return self.m11 * self.m11 - self.m12 * self.m12


def plant_coefficients(p: dict) -> PlantCoefficients:
    """Coefficients of (2) and (5) from the parameters of docs/model.md §4.

    Parameters
    ----------
    p : dict
        The MobileRobot FMU's parameter values by name (SI units, as ``PLANT_PARAMETERS``).

    Returns
    -------
    PlantCoefficients
        The constants of (1)-(8).
    """
    r, R, d, mc, mw = p["r"], p["R"], p["d"], p["mc"], p["mw"]
    loads = tuple(LoadTorque(p[f"tau_dc{i}"], p[f"tau_da{i}"], p[f"f_d{i}"], p[f"phi_d{i}"]) for i in (1, 2))
    m = mc + 2.0 * mw
    inertia = mc * d * d + 2.0 * mw * R * R + p["Ic"] + 2.0 * p["Im"]
    k = 0.25 * r * r / (R * R)
    return PlantCoefficients(
        r=r,
        R=R,
        m11=k * (m * R * R + inertia) + p["Iw"],
        m12=k * (m * R * R - inertia),
        c=0.5 * r * r * mc * d / R,
        d11=p["d11"],
        d22=p["d22"],
        nkt1=p["N1"] * p["KT1"],
        nkt2=p["N2"] * p["KT2"],
        nke1=p["N1"] * p["KE1"],
        nke2=p["N2"] * p["KE2"],
        ra1=p["Ra1"],
        ra2=p["Ra2"],
        la1=p["La1"],
        la2=p["La2"],
        u_max=(p["u_max1"], p["u_max2"]) if p["voltage_limit"] else None,
        loads=loads if any(load.constant or load.amplitude for load in loads) else None,
    )


def theta_dot(k: PlantCoefficients, v1: float, v2: float) -> float:
    """Heading rate ``r / (2 R) (v1 - v2)`` in rad/s from the wheel speeds in rad/s: the third row of (1)."""
    return 0.5 * k.r / k.R * (v1 - v2)


def initial_plant_state(p: dict) -> list:
    """``[x, y, theta, v1, v2, i1, i2]`` at t = 0 from the parameters ``x0`` ... ``i2_0`` (docs/model.md §5.1:
    at rest by default)."""
    return [p["x0"], p["y0"], p["theta0"], p["omega1_0"], p["omega2_0"], p["i1_0"], p["i2_0"]]


def saturation(k: PlantCoefficients, u1: float, u2: float) -> tuple:
    """Each driver's switch (``HIGH``, ``LOW`` or ``FREE``) at the voltages ``u1``, ``u2`` in V: ``HIGH`` where
    ``u_j > u_max_j``, ``LOW`` where ``u_j < -u_max_j``; ``(FREE, FREE)`` without a limit (docs/model.md §5.14)."""
    if k.u_max is None:
        return UNLIMITED
    return tuple(HIGH if u > limit else LOW if u < -limit else FREE for u, limit in zip((u1, u2), k.u_max))


def applied_voltages(k: PlantCoefficients, u1: float, u2: float, held: tuple | None = None) -> tuple:
    """The voltages in V the drivers apply to the motors for the inputs ``u1``, ``u2``: ``clip(u_j, -u_max_j,
    u_max_j)`` with a limit, the switches ``held`` (model exchange) or chosen at ``u`` (None); ``u`` without one."""
    if k.u_max is None:
        return u1, u2
    switches = saturation(k, u1, u2) if held is None else held
    return tuple(u if switch == FREE else limit if switch == HIGH else -limit
                 for u, limit, switch in zip((u1, u2), k.u_max, switches))


def saturation_indicators(k: PlantCoefficients, u1: float, u2: float) -> list:
    """``[u_max1 - u1, u_max1 + u1, u_max2 - u2, u_max2 + u2]`` in V: each changes sign exactly where a driver's
    switch changes (docs/model.md §5.13); all 1 without a limit."""
    if k.u_max is None:
        return [1.0, 1.0, 1.0, 1.0]
    return [k.u_max[0] - u1, k.u_max[0] + u1, k.u_max[1] - u2, k.u_max[1] + u2]


def plant_derivatives(k: PlantCoefficients, t: float, x: list, u1: float, u2: float, math=math,
                      held: tuple | None = None) -> list:
    """Time derivative of the plant's state under the motor voltages, equations (6)-(8).

    Parameters
    ----------
    k : PlantCoefficients
        The plant's constants.
    t : float
        The time, in s (the disturbance torques depend on it).
    x : list of float
        The state ``[x, y, theta, v1, v2, i1, i2]`` in m, m, rad, rad/s, rad/s, A, A.
    u1, u2 : float
        Motor voltages of the right and left wheel, in V, before the drivers' limit (``applied_voltages``).
    math : namespace, optional
        Where ``sin`` and ``cos`` come from: the ``math`` module (default), or ``dual.DUAL_MATH`` for
        directional derivatives with ``x``, ``u1``, ``u2`` duals.
    held : tuple of int or None, optional
        The drivers' switches held since the last event (model exchange). Default None: chosen at ``u``.

    Returns
    -------
    list of float
        The derivative of each entry of ``x``, per s.
    """
    _, _, theta, v1, v2, i1, i2 = x
    if k.u_max is not None:
        u1, u2 = applied_voltages(k, u1, u2, held)
    speed = 0.5 * k.r * (v1 + v2)
    w = 0.5 * k.r / k.R * (v1 - v2)
    f1 = k.nkt1 * i1 - k.c * w * v2 - k.d11 * v1
    f2 = k.nkt2 * i2 + k.c * w * v1 - k.d22 * v2
    if k.loads is not None:
        f1 = f1 - k.loads[0].at(t, math)
        f2 = f2 - k.loads[1].at(t, math)
    det = k.m11 * k.m11 - k.m12 * k.m12
    return [
        speed * math.cos(theta),
        speed * math.sin(theta),
        w,
        (k.m11 * f1 - k.m12 * f2) / det,
        (k.m11 * f2 - k.m12 * f1) / det,
        (u1 - k.ra1 * i1 - k.nke1 * v1) / k.la1,
        (u2 - k.ra2 * i2 - k.nke2 * v2) / k.la2,
    ]
