"""One sub-step of ``models.rk4.rk4_integrate`` traced from its own source, calling the traced rates."""

from __future__ import annotations

import math
from contextlib import contextmanager

from ..models import rk4
from .trace import Graph, Symbol, Traced, trace

__all__ = ["trace_rk4_substep"]


@contextmanager
def _symbolic_substep(count: Symbol, index: Symbol):
    """``models.rk4.rk4_integrate`` taking ``count`` sub-steps (a run-time number), tracing sub-step ``index``."""
    rk4.substeps, saved = (lambda step_size, max_step: count), rk4.substeps
    rk4.range = lambda n: (index,)
    try:
        yield
    finally:
        rk4.substeps = saved
        del rk4.range


def trace_rk4_substep(rates: Traced, state: int, inputs, arguments: dict, name: str, project=None) -> Traced:
    """One sub-step of ``models.rk4.rk4_integrate`` traced from its own source.

    Parameters
    ----------
    rates : Traced
        ``rates(p, t, x, ...)``: a traced function whose first ``state`` outputs are the state's derivative and
        whose other outputs are watched (the C loop keeps those of the first evaluation whose first extra is true).
    state : int
        The length of the state.
    inputs : callable
        ``inputs(t, p, ...)`` (the sub-step's own arguments as keywords): the keyword arguments of ``rates`` other
        than ``p``, ``t`` and ``x`` at time ``t``.
    arguments : dict
        The sub-step's own arguments, ``p`` first, as in ``trace``; after them come ``t0``, ``step_size``,
        ``count``, ``k`` and ``x``.
    name : str
        The name of the sub-step.
    project : callable, optional
        ``project(p)``: None, or what ``rk4_integrate`` maps the state with after each sub-step (its ``project``).

    Returns
    -------
    Traced
        Outputs: the state after sub-step ``k`` of ``count`` from ``t0``, then for each of the four evaluations its
        time and the extra outputs of ``rates``.

    Raises
    ------
    Untraceable
        As ``trace``.
    """
    graph = rates.graph
    arguments = {**arguments, "t0": None, "step_size": None, "count": None, "k": None, "x": state}

    def substep(t0, step_size, count, k, x, **symbols):
        watched = []

        def derivative(t, x):
            arguments = _call_arguments(graph, rates, t, x, inputs(t, **symbols))
            call = graph.node(("call", rates.name, arguments, len(rates.outputs)))
            results = [Symbol(graph, graph.node(("result", call, i))) for i in range(len(rates.outputs))]
            watched.extend([t, *results[state:]])
            return results[:state]

        with _symbolic_substep(count, k):
            x = rk4.rk4_integrate(derivative, t0, x, step_size, math.inf, project and project(symbols["p"]))
        return [*x, *watched]

    return trace(substep, arguments, name, graph, 1)


def _call_arguments(graph: Graph, rates: Traced, t, x, others: dict) -> tuple:
    """The arguments of a call of ``rates``: per argument, its name and a node (scalar), a tuple of nodes, or None
    (the caller's array of that name)."""
    given = {"t": t, "x": x, **others}
    passed = []
    for name, size in rates.arguments.items():
        value = given.get(name)
        if value is None:
            passed.append((name, None))
        elif size is None:
            passed.append((name, graph.operand(value)))
        else:
            passed.append((name, tuple(graph.operand(v) for v in value)))
    return tuple(passed)
