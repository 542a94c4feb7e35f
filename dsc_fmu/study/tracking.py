"""The plant in error coordinates (eqs. (10)-(12)) and the controller's inputs that measure it there."""

from __future__ import annotations

import math

import numpy as np

from ..models.plant import PlantCoefficients, plant_derivatives, theta_dot

__all__ = ["error_coordinates", "error_plant_derivatives", "error_outputs", "error_measurements",
           "MEASUREMENT_SELECTION"]


# E = d m / d y of ``error_measurements`` (constant): theta_dot, v1, v2, i1, i2 to the controller's inputs
# 3..7, S11, S12, S13bar to x_r, y_r, theta_r (inputs 8..10); the robot's pose, vr, wr, vr_dot held.
MEASUREMENT_SELECTION = np.zeros((14, 8))
MEASUREMENT_SELECTION[[3, 4, 5, 6, 7, 8, 9, 10], [3, 4, 5, 6, 7, 0, 1, 2]] = 1.0
MEASUREMENT_SELECTION.setflags(write=False)


def error_coordinates(plant: list, reference: list) -> list:
    """The plant state in error coordinates, eqs. (10), (12) (S13bar not wrapped).

    Parameters
    ----------
    plant : list of float
        ``[x, y, theta, v1, v2, i1, i2]`` in m, m, rad, rad/s, rad/s, A, A.
    reference : list of float
        ``[xr, yr, thetar]`` in m, m, rad.

    Returns
    -------
    list of float
        ``xp = [S11, S12, S13bar, v1, v2, i1, i2]`` in m, m, rad, rad/s, rad/s, A, A.
    """
    x, y, theta = plant[:3]
    ex, ey = reference[0] - x, reference[1] - y
    c, s = math.cos(theta), math.sin(theta)
    return [c * ex + s * ey, -s * ex + c * ey, reference[2] - theta, *plant[3:]]


def error_plant_derivatives(k: PlantCoefficients, vr: float, wr: float, xp, u) -> list:
    """The derivative of the plant state in error coordinates, eqs. (11), (7), (8).

    Eq. (11) gives S11, S12, S13bar; the wheel and motor rows (7), (8) come from
    ``models.plant.plant_derivatives`` (they do not depend on the pose), with the drivers' limit and the
    disturbance torques at t = 0 (``study.stability`` takes only a constant one).

    Parameters
    ----------
    k : models.plant.PlantCoefficients
        The plant's coefficients (``plant_coefficients``).
    vr : float
        The reference's speed, in m/s.
    wr : float
        The reference's turn rate, in rad/s.
    xp : sequence of float
        ``[S11, S12, S13bar, v1, v2, i1, i2]`` (``error_coordinates``).
    u : sequence of float
        The voltages ``[u1, u2]``, in V.

    Returns
    -------
    list of float
        The 7 derivatives of ``xp``, per s.
    """
    S11, S12, S13bar, v1, v2, i1, i2 = xp
    w = theta_dot(k, v1, v2)
    rows = plant_derivatives(k, 0.0, [0.0, 0.0, 0.0, v1, v2, i1, i2], u[0], u[1])
    return [w * S12 - 0.5 * k.r * (v1 + v2) + vr * math.cos(S13bar), -w * S11 + vr * math.sin(S13bar),
            wr - w, *rows[3:]]


def error_outputs(k: PlantCoefficients, xp) -> list:
    """The measurement of the plant state in error coordinates.

    Parameters
    ----------
    k : models.plant.PlantCoefficients
        The plant's coefficients (``plant_coefficients``).
    xp : sequence of float
        ``[S11, S12, S13bar, v1, v2, i1, i2]`` (``error_coordinates``).

    Returns
    -------
    list of float
        ``y = [S11, S12, S13bar, theta_dot, v1, v2, i1, i2]``, theta_dot in rad/s from eq. (1).
    """
    S11, S12, S13bar, v1, v2, i1, i2 = xp
    return [S11, S12, S13bar, theta_dot(k, v1, v2), v1, v2, i1, i2]


def error_measurements(y, vr: float, wr: float) -> list:
    """The controller's inputs equivalent to a measurement in error coordinates.

    The robot is put at the origin heading 0, so xr = S11, yr = S12, thetar = S13bar (eq. (10) with
    theta = 0), and vr_dot = 0.

    Parameters
    ----------
    y : sequence of float
        ``[S11, S12, S13bar, theta_dot, v1, v2, i1, i2]`` (``error_outputs``).
    vr : float
        The reference's speed, in m/s.
    wr : float
        The reference's turn rate, in rad/s.

    Returns
    -------
    list of float
        The controller's 14 inputs ``m`` in its input order (docs/model.md §3).
    """
    S11, S12, S13bar, td, v1, v2, i1, i2 = y
    return [0.0, 0.0, 0.0, td, v1, v2, i1, i2, S11, S12, S13bar, vr, wr, 0.0]
