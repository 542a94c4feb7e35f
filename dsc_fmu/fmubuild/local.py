"""Functions whose decisions are merged where they are called, not multiplied into their callers' paths (traced-c.md).

``trace`` runs a function once per combination of its decisions, so independent decisions multiply: four estimates
each projected or not, each with its margin's ``min`` and ``max``, make thousands of paths. A function merged locally
is run, where it is called with a traced argument, once per combination of its own decisions only (its caller's
answers kept), and what it returns is merged into selects there: its caller sees one result and takes no decision.
"""

from __future__ import annotations

import builtins
from contextlib import contextmanager

from .trace import MAX_PATHS, Graph, Symbol, Untraceable, _merge, _paths

__all__ = ["merged_locally", "merging_locally"]


def _symbol(value) -> Symbol | None:
    """The first Symbol in ``value`` (lists, tuples and dicts searched), or None."""
    if type(value) is Symbol:
        return value
    items = value.values() if isinstance(value, dict) else value if isinstance(value, (list, tuple)) else ()
    return next((found for found in map(_symbol, items) if found is not None), None)


def _flatten(value) -> tuple:
    """``(shape, leaves)`` of a result made of lists and tuples (exactly those types) of anything else."""
    if type(value) in (list, tuple):
        shapes, leaves = [], []
        for item in value:
            shape, found = _flatten(item)
            shapes.append(shape)
            leaves.extend(found)
        return (type(value), tuple(shapes)), leaves
    return None, [value]


def _unflatten(shape, leaves):
    if shape is None:
        return next(leaves)
    kind, shapes = shape
    return kind(_unflatten(item, leaves) for item in shapes)


def _same(a, b) -> bool:
    if type(a) is Symbol or type(b) is Symbol:
        return type(a) is type(b) and a.node == b.node
    return type(a) is type(b) and a == b


def _node(graph: Graph, value, name: str) -> int:
    node = graph.operand(value)
    if node is None:
        raise Untraceable(f"{name}() returns {value!r} on one path and something else on another")
    return node


def merged_locally(function):
    """``function``, its decisions merged where it is called with a traced argument.

    Parameters
    ----------
    function : callable
        Returns numbers, bools or anything else in lists and tuples of the same shape on every path.

    Returns
    -------
    callable
        Calls ``function`` as it is where no argument is traced; else runs it once per combination of its own
        decisions and returns its result with each leaf that differs between the runs a select (a bool as 1.0 or
        0.0), adding to its caller's fault where it would raise.

    Raises
    ------
    Untraceable
        (from the call) If the shapes differ between runs, a leaf that is not a number differs, or the function has
        more than ``trace.MAX_PATHS`` combinations of decisions.
    """
    name = getattr(function, "__name__", repr(function))

    def merged(*args, **kwargs):
        symbol = _symbol((args, kwargs))
        if symbol is None or symbol.graph._run is None:
            return function(*args, **kwargs)
        graph, outer, shapes = symbol.graph, symbol.graph._run, []

        def call():
            shape, leaves = _flatten(function(*args, **kwargs))
            shapes.append(shape)
            return leaves

        runs = _paths(graph, call, name, MAX_PATHS, outer)
        if any(shape != shapes[0] for shape in shapes):
            raise Untraceable(f"{name}() returns results of different shapes on different paths")
        first = runs[0][1]
        varying = [i for i in range(len(first)) if any(not _same(leaves[i], first[i]) for _, leaves, _ in runs)]
        merged_nodes = _merge(graph, [(decisions, [*(_node(graph, leaves[i], name) for i in varying), fault])
                                      for decisions, leaves, fault in runs], 0)
        outer.flags.append(merged_nodes[-1])
        values = list(first)
        for i, node in zip(varying, merged_nodes):
            values[i] = Symbol(graph, node)
        return _unflatten(shapes[0], iter(values))

    merged.__name__ = name
    return merged


@contextmanager
def merging_locally(places):
    """Within the block, the named functions of each module merged locally (``merged_locally``).

    Parameters
    ----------
    places : iterable of (module, tuple of str)
        Each module and the names of its functions to merge; a name the module does not define is a builtin
        (``min``, ``max``), shadowed in that module only.

    Yields
    ------
    None
        The modules are restored after the block.
    """
    saved = []
    try:
        for module, names in places:
            for name in names:
                merged = merged_locally(getattr(module, name, None) or getattr(builtins, name))
                saved.append((module, name, module.__dict__.get(name)))
                setattr(module, name, merged)
        yield
    finally:
        for module, name, value in reversed(saved):
            if value is None:
                delattr(module, name)
            else:
                setattr(module, name, value)
