"""Fixed-step integration over one communication step: classical RK4 in equal sub-steps, explicit Euler."""

import math

__all__ = ["MAX_SUBSTEPS"]

# The most sub-steps one communication step may take: bounds the work of any single step.
MAX_SUBSTEPS = 1_000_000


def substeps(step_size: float, max_step: float) -> int:
    """The number (at least 1) of equal sub-steps no longer than ``max_step`` that make up ``step_size``; a step a
    rounding error longer than a multiple of ``max_step`` takes no extra one."""
    return max(1, math.ceil(step_size / max_step * (1.0 - 1e-12)))


def rk4_integrate(f, t0: float, x: list, step_size: float, max_step: float, project=None) -> list:
    """The state at ``t0 + step_size`` (s) of ``x_dot = f(t, x)`` from ``x`` at ``t0``, by RK4 in
    ``substeps(step_size, max_step)`` equal sub-steps (docs/model.md §5.11). Sub-step k starts at ``t0 + k h``:
    time is never accumulated. ``project``, if given, maps the state after each sub-step (onto a set).
    """
    n = substeps(step_size, max_step)
    h = step_size / n
    half = 0.5 * h
    sixth = h / 6.0
    for k in range(n):
        t = t0 + k * h
        k1 = f(t, x)
        k2 = f(t + half, [xi + half * di for xi, di in zip(x, k1)])
        k3 = f(t + half, [xi + half * di for xi, di in zip(x, k2)])
        k4 = f(t + h, [xi + h * di for xi, di in zip(x, k3)])
        x = [
            xi + sixth * (a + 2.0 * b + 2.0 * c + d)
            for xi, a, b, c, d in zip(x, k1, k2, k3, k4)
        ]
        if project is not None:
            x = project(x)
    return x


def euler_step(f, t0: float, x: list, step_size: float) -> list:
    """One explicit Euler step ``x + h f(t0, x)``: a controller sampled at the communication step ``h``."""
    return [xi + step_size * di for xi, di in zip(x, f(t0, x))]
