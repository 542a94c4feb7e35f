"""The models' own Python run on a symbolic number that records its arithmetic as a graph (docs/traced-c.md).

A ``Symbol`` stands for a run-time value (an entry of an argument array); arithmetic, ``abs``, comparisons and
the functions of ``TRACE_MATH`` on it add nodes to a ``Graph``, one node per distinct operation on distinct
operands (hash-consed: a subexpression computed twice is one node). Python's ``if`` on a traced comparison
asks for a bool (``Symbol.__bool__``): ``trace`` answers each such decision one way, runs the function again
for every other answer (depth first), and merges the results of the runs into selects on the decisions. The
graph holds exactly Python's operations in Python's order: nothing is folded or reassociated.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from types import SimpleNamespace

__all__ = ["Graph", "Symbol", "TRACE_MATH", "TooManyPaths", "Traced", "Untraceable", "trace"]

COMPARISONS = {"lt": "<", "le": "<=", "gt": ">", "ge": ">=", "eq": "==", "ne": "!="}
# Nodes of bool kind (C int): comparisons, selects between them, and whether Python raised (``fault``, ``any``).
BOOLEAN = {*COMPARISONS, "fault", "any"}
# Operations on which Python raises where C returns inf or nan (docs/traced-c.md, "When Python raises").
RAISING = {"div", "sin", "cos", "atan", "sqrt", "remainder", "fsum", "call"}
# More runs than this (combinations of decisions) and the function is not traced.
MAX_PATHS = 512


class Untraceable(Exception):
    """A function the tracer cannot follow: the message names it and says why (that FMU keeps its Python path)."""


class TooManyPaths(Untraceable):
    """A function whose decisions combine in more ways than allowed."""


class Graph:
    """The nodes of traced functions, each distinct operation on distinct operands stored once (hash-consing).

    A node is a tuple ``(op, *operands)``, its operands node indices (names and numbers for ``arg``, ``const`` and
    ``call``: the function's name, its arguments as ``substep`` passes them, its number of outputs), numbered in the
    order made, so operands come first.

    Attributes
    ----------
    nodes : list of tuple
        The nodes by index.
    """

    def __init__(self):
        self.nodes = []
        self._index = {}
        self._run = None

    def node(self, key: tuple) -> int:
        """The index of the node ``key``, added if new.

        Parameters
        ----------
        key : tuple
            ``(op, *operands)``.

        Returns
        -------
        int
            Its index in ``nodes``.
        """
        index = self._index.get(key)
        if index is None:
            index = self._index[key] = len(self.nodes)
            self.nodes.append(key)
        if self._run is not None and key[0] in RAISING:
            self._run.raising.add(index)
        return index

    def constant(self, value) -> int:
        """The node of a number.

        Parameters
        ----------
        value : float or int
            The number; an int (or bool) as Python converts it in float arithmetic, ``float(value)``.

        Returns
        -------
        int
            The index of its ``const`` node.
        """
        value = float(value)
        return self.node(("const", value.hex(), value))

    def operand(self, value) -> int | None:
        """The node of an operand.

        Parameters
        ----------
        value : Symbol, float or int
            The operand.

        Returns
        -------
        int or None
            Its node, None if it is neither a Symbol nor a number.
        """
        if type(value) is Symbol:
            return value.node
        if isinstance(value, (int, float)):
            return self.constant(value)
        return None

    def select(self, condition: int, if_true: int, if_false: int) -> int:
        """The node ``condition ? if_true : if_false``.

        Parameters
        ----------
        condition : int
            A node of bool kind.
        if_true, if_false : int
            The nodes selected.

        Returns
        -------
        int
            The select's node; ``if_true`` itself if both are the same node.
        """
        return if_true if if_true == if_false else self.node(("select", condition, if_true, if_false))

    def boolean(self, index: int) -> bool:
        """Whether a node is of bool kind (a C int: a comparison, a select of them, whether Python raises).

        Parameters
        ----------
        index : int
            The node.

        Returns
        -------
        bool
            True for bool kind, False for a number.
        """
        key = self.nodes[index]
        return key[0] in BOOLEAN or (key[0] == "select" and self.boolean(key[2]))

    def _decide(self, condition: int) -> bool:
        """The answer of the current run to the decision on ``condition`` (the same answer each time it is asked)."""
        return self._run.decide(condition)


class _Run:
    """One run of a traced function: the answers given (``decisions``: (condition, answer) in order), the raising
    nodes Python evaluated, ``flags``: bool nodes true where a function merged locally would have raised (``local``).
    A decision taken by an enclosing run (``parent``: the caller of a function merged locally) keeps its answer."""

    def __init__(self, prefix: tuple, parent: _Run | None = None):
        self.prefix, self.parent = prefix, parent
        self.decisions, self.answers, self.raising, self.flags = [], {}, set(), []

    def decide(self, condition: int) -> bool:
        run = self.parent
        while run is not None:
            if condition in run.answers:
                return run.answers[condition]
            run = run.parent
        if condition not in self.answers:
            position = len(self.decisions)
            answer = self.prefix[position] if position < len(self.prefix) else True
            self.decisions.append((condition, answer))
            self.answers[condition] = answer
        return self.answers[condition]


def _binary(op: str, reverse: bool = False):
    def method(self, other):
        graph = self.graph
        node = graph.operand(other)
        if node is None:
            return NotImplemented
        _numeric(graph, self.node, node)
        operands = (node, self.node) if reverse else (self.node, node)
        return Symbol(graph, graph.node((op, *operands)))

    return method


def _numeric(graph: Graph, *nodes: int) -> None:
    if any(graph.boolean(n) for n in nodes):
        raise Untraceable("arithmetic on a traced comparison (a bool used as a number)")


class Symbol:
    """A traced run-time value: operators and ``TRACE_MATH`` on it record nodes of its ``graph``.

    It has no conversion to float, int or an index: the ``math`` module, ``float()``, ``round()`` or ``range()``
    on it raise TypeError, which ``trace`` reports as ``Untraceable``.

    Parameters
    ----------
    graph : Graph
        Where its node is.
    node : int
        The index of its node.
    """

    __slots__ = ("graph", "node")

    def __init__(self, graph: Graph, node: int):
        self.graph = graph
        self.node = node

    def __repr__(self):
        return f"Symbol({self.graph.nodes[self.node]!r})"

    __add__, __radd__ = _binary("add"), _binary("add", reverse=True)
    __sub__, __rsub__ = _binary("sub"), _binary("sub", reverse=True)
    __mul__, __rmul__ = _binary("mul"), _binary("mul", reverse=True)
    __truediv__, __rtruediv__ = _binary("div"), _binary("div", reverse=True)
    __lt__, __le__, __gt__, __ge__ = _binary("lt"), _binary("le"), _binary("gt"), _binary("ge")
    __eq__, __ne__ = _binary("eq"), _binary("ne")
    __hash__ = None

    def __neg__(self):
        _numeric(self.graph, self.node)
        return Symbol(self.graph, self.graph.node(("neg", self.node)))

    def __pos__(self):
        return self

    def __abs__(self):
        _numeric(self.graph, self.node)
        return Symbol(self.graph, self.graph.node(("abs", self.node)))

    def __bool__(self):
        """The current run's answer for this comparison (a number: whether it is not zero, as for a float)."""
        graph = self.graph
        condition = self.node if graph.boolean(self.node) else graph.node(("ne", self.node, graph.constant(0.0)))
        return graph._decide(condition)


def _function(op: str, python):
    def function(*args):
        symbol = next((a for a in args if type(a) is Symbol), None)
        if symbol is None:
            return python(*args)
        graph = symbol.graph
        nodes = [graph.operand(a) for a in args]
        if None in nodes:
            raise Untraceable(f"{op}() of {args!r}")
        _numeric(graph, *nodes)
        return Symbol(graph, graph.node((op, *nodes)))

    function.__name__ = op
    return function


_hypot2 = _function("hypot", math.hypot)


def _hypot(*args):
    if len(args) != 2:
        raise Untraceable(f"hypot() of {len(args)} coordinates: only two are traced")
    return _hypot2(*args)


_fsum_of = _function("fsum", lambda *values: math.fsum(values))


def _fsum(values):
    return _fsum_of(*values)


TRACE_MATH = SimpleNamespace(
    pi=math.pi, sin=_function("sin", math.sin), cos=_function("cos", math.cos), atan=_function("atan", math.atan),
    sqrt=_function("sqrt", math.sqrt), remainder=_function("remainder", math.remainder), hypot=_hypot, fsum=_fsum,
)
"""The functions of the ``math`` module that the models use (as ``models.dual.DUAL_MATH``), on Symbols and floats."""


@dataclass
class Traced:
    """One traced function: its outputs as nodes of ``graph`` and whether Python would have raised.

    Parameters
    ----------
    name : str
        The name of the function (and of its C function).
    graph : Graph
        The nodes.
    arguments : dict
        The argument arrays in order, each name to its length (None: a scalar).
    outputs : list of int
        The node of each output (selects where the runs differed).
    fault : int
        The node that is true where Python would raise (a division by zero, a domain error).
    paths : int
        How many runs (combinations of decisions) the trace took.
    function : callable
        The traced Python function.
    public : bool, optional
        Whether its C functions are exported (default) or internal (``static``: one specialised on parameter
        choices, called by the exported one, ``specialise``).
    """

    name: str
    graph: Graph
    arguments: dict
    outputs: list
    fault: int
    paths: int
    function: Callable
    public: bool = True


def _arguments(graph: Graph, arguments: dict) -> dict:
    symbols = {}
    for name, size in arguments.items():
        if size is None:
            symbols[name] = Symbol(graph, graph.node(("arg", name, None)))
        else:
            symbols[name] = [Symbol(graph, graph.node(("arg", name, i))) for i in range(size)]
    return symbols


def trace(function, arguments: dict, name: str, graph: Graph | None = None, max_paths: int = MAX_PATHS) -> Traced:
    """Trace ``function(**symbols)``, which returns a flat list of numbers, over every combination of its decisions.

    Parameters
    ----------
    function : callable
        Called with one keyword per argument: a list of Symbols (an array) or a Symbol (a scalar).
    arguments : dict
        Each argument's name to its length, None for a scalar; the order is the C function's.
    name : str
        The function's name, in messages and in C.
    graph : Graph, optional
        The graph to add to (a new one by default).
    max_paths : int, optional
        The most runs (combinations of decisions) allowed.

    Returns
    -------
    Traced
        The outputs merged over the runs.

    Raises
    ------
    Untraceable
        If the function calls what the tracer cannot follow (a conversion to float, the ``math`` module on a
        traced value, ...) or takes more than ``max_paths`` runs (``TooManyPaths``); the message names the function
        and the reason.
    """
    graph = graph or Graph()
    symbols = _arguments(graph, arguments)
    try:
        leaves = _paths(graph, lambda: [_output(graph, value) for value in function(**symbols)], name, max_paths)
    except Untraceable as error:
        raise type(error)(f"{name}: {error}") from None
    except (TypeError, AttributeError, ValueError) as error:
        reason = f"calls what a traced value cannot enter ({type(error).__name__}: {error})"
        raise Untraceable(f"{name}: {reason}") from None
    merged = _merge(graph, [(decisions, [*outputs, fault]) for decisions, outputs, fault in leaves], 0)
    return Traced(name, graph, dict(arguments), merged[:-1], merged[-1], len(leaves), function)


def _paths(graph: Graph, call, name: str, max_paths: int, parent: _Run | None = None) -> list:
    """``(decisions, results, fault)`` of each run of ``call()`` (depth first, every combination of its decisions):
    what it returned and the node that is true where Python would have raised on that path."""
    leaves, pending = [], [()]
    while pending:
        prefix = pending.pop()
        graph._run = run = _Run(prefix, parent)
        try:
            results = call()
        finally:
            graph._run = parent
        answers = tuple(answer for _, answer in run.decisions)
        pending.extend(answers[:i] + (False,) for i in range(len(prefix), len(answers)))  # new decisions: True
        faults = [graph.node(("fault", n)) for n in sorted(run.raising)] + run.flags
        leaves.append((run.decisions, results, graph.node(("any", *faults))))
        if len(leaves) > max_paths:
            raise TooManyPaths(f"more than {max_paths} combinations of decisions" +
                               (f" in {name}()" if parent is not None else ""))
    return leaves


def _output(graph: Graph, value) -> int:
    node = graph.operand(value)
    if node is None:
        raise Untraceable(f"returns {value!r}, not a number")
    return node


def _merge(graph: Graph, leaves: list, depth: int) -> list:
    """The outputs of the runs ``leaves`` (which agree on their first ``depth`` decisions) merged into selects."""
    if len(leaves) == 1:
        return leaves[0][1]
    condition = leaves[0][0][depth][0]
    taken = [leaf for leaf in leaves if leaf[0][depth][1]]
    other = [leaf for leaf in leaves if not leaf[0][depth][1]]
    merged = zip(_merge(graph, taken, depth + 1), _merge(graph, other, depth + 1))
    return [graph.select(condition, a, b) for a, b in merged]
