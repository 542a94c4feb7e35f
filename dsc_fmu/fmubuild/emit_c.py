"""Straight-line C99 from traced functions: values, forward-mode tangents and the RK4 sub-step loop (docs/traced-c.md).

Every node becomes one ``const`` local in index order (operands first), so the C evaluates exactly the
operations Python evaluated, in Python's order; the file must be compiled with ``C_FLAGS`` (no contraction into
fused multiply-adds, no fused ``sincos``) and linked with the libm CPython uses.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

from .trace import COMPARISONS, Graph, Traced, Untraceable

__all__ = [
    "C_FLAGS", "TRACED_MATH_HEADER", "c_file", "rk4_function", "tangent_function", "value_function",
]

TRACED_MATH_HEADER = Path(__file__).parent / "native" / "traced_math.h"
C_FLAGS = ("-std=c99", "-ffp-contract=off", "-fno-builtin-sin", "-fno-builtin-cos")
"""What bit identity with CPython needs of the compiler (docs/traced-c.md, "Bit for bit")."""

_OPERATORS = {"add": "+", "sub": "-", "mul": "*", "div": "/", **COMPARISONS}
_LIBM = {"sin", "cos", "atan", "sqrt"}
_FSUM_MAX = 64  # the partials array of dsc_fsum
_LOOP_NAMES = {"count": "(double)count", "k": "(double)k"}  # the RK4 loop's count and index (C: long) as doubles
# The tangents of models.dual's one-argument rules: d the argument's tangent, v its value, result the node's value.
_UNARY_TANGENTS = {
    "neg": "-{d}",
    "abs": "{v} >= 0.0 ? {d} : -{d}",
    "sin": "cos({v}) * {d}",
    "cos": "-sin({v}) * {d}",
    "atan": "{d} / (1.0 + {v} * {v})",
    "sqrt": "{result} != 0.0 ? 0.5 * {d} / {result} : 0.0",
}


def _operands(key: tuple) -> list:
    """The node indices a node reads."""
    op = key[0]
    if op in ("arg", "const"):
        return []
    if op == "call":
        found = []
        for _, value in key[2]:
            found.extend(() if value is None else value if isinstance(value, tuple) else (value,))
        return found
    if op == "result":
        return [key[1]]
    return list(key[1:])


def _needed(graph: Graph, roots) -> list:
    """The nodes ``roots`` read, directly or not, themselves included, in index order."""
    seen, stack = set(), list(roots)
    while stack:
        index = stack.pop()
        if index not in seen:
            seen.add(index)
            stack.extend(_reads(graph, graph.nodes[index]))
    return sorted(seen)


def _reads(graph: Graph, key: tuple) -> list:
    """The nodes whose C values node ``key`` reads: its operands, except that whether a division raises reads only
    the divisor, and whether another operation raises reads that operation and its operands."""
    if key[0] != "fault":
        return _operands(key)
    raising = graph.nodes[key[1]]
    return [_operands(raising)[1]] if raising[0] == "div" else [key[1], *_operands(raising)]


def _constant(value: float) -> str:
    if value != value:
        return "NAN"
    if value in (float("inf"), float("-inf")):
        return "INFINITY" if value > 0 else "(-INFINITY)"
    return f"({value.hex()})"


def _value(graph: Graph, index: int) -> list:
    """The C lines that define node ``index`` (``n<index>``)."""
    key = graph.nodes[index]
    op, n = key[0], f"n{index}"
    a = [f"n{i}" for i in _operands(key)] if op not in ("call", "result") else []
    kind = "int" if graph.boolean(index) else "double"
    if op == "arg":
        source = _LOOP_NAMES.get(key[1], key[1])
        return [f"const double {n} = {source if key[2] is None else f'{source}[{key[2]}]'};"]
    if op == "const":
        return [f"const double {n} = {_constant(key[2])};"]
    if op in _OPERATORS:
        return [f"const {kind} {n} = {a[0]} {_OPERATORS[op]} {a[1]};"]
    if op == "neg":
        return [f"const double {n} = -{a[0]};"]
    if op == "abs":
        return [f"const double {n} = fabs({a[0]});"]
    if op in _LIBM:
        return [f"const double {n} = {op}({a[0]});"]
    if op in ("remainder", "hypot"):
        return [f"const double {n} = dsc_{op}({a[0]}, {a[1]});"]
    if op == "fsum":
        if len(a) > _FSUM_MAX:
            raise Untraceable(f"fsum of {len(a)} values: at most {_FSUM_MAX} are traced")
        values = f"(const double[]){{{', '.join(a)}}}"
        return [f"int f{index};", f"const double {n} = dsc_fsum({len(a)}, {values}, &f{index});"]
    if op == "select":
        return [f"const {kind} {n} = {a[0]} ? {a[1]} : {a[2]};"]
    if op == "any":
        return [f"const int {n} = {' | '.join(a) or '0'};"]
    if op == "fault":
        return [f"const int {n} = {_raises(graph, key[1])};"]
    if op == "call":
        arguments = ", ".join(_call_argument(name, value) for name, value in key[2])
        return [f"double c{index}[{key[3]}];", f"const int f{index} = {key[1]}({arguments}, c{index});"]
    return [f"const double {n} = c{key[1]}[{key[2]}];"]  # result


def _call_argument(name: str, value) -> str:
    if value is None:
        return name
    if isinstance(value, tuple):
        return f"(const double[]){{{', '.join(f'n{i}' for i in value)}}}"
    return f"n{value}"


def _raises(graph: Graph, index: int) -> str:
    """The C condition under which Python raises at node ``index`` (CPython's rules for float division and math)."""
    key = graph.nodes[index]
    op, n, a = key[0], f"n{index}", [f"n{i}" for i in _operands(key)]
    if op == "div":
        return f"({a[1]} == 0.0)"
    if op in _LIBM:
        return f"(isnan({n}) && !isnan({a[0]}))"
    if op == "remainder":
        return f"(isnan({n}) && !isnan({a[0]}) && !isnan({a[1]}))"
    return f"f{index}"  # fsum, call


def _linkage(traced: Traced) -> str:
    return "DSC_TRACED_API" if traced.public else "static"


def _signature(traced: Traced, extra: str) -> str:
    parts = [f"double {name}" if size is None else f"const double *{name}" for name, size in traced.arguments.items()]
    return f"{_linkage(traced)} int {traced.name}{extra}({', '.join(parts)}"


def _outputs(traced: Traced, target: str) -> list:
    return [f"{target}[{i}] = n{node};" for i, node in enumerate(traced.outputs)]


def value_function(traced: Traced) -> str:
    """The C function ``int <name>(<arguments>, double *out)``: the outputs into ``out``; returns 1 where Python raises.

    Parameters
    ----------
    traced : Traced
        The traced function.

    Returns
    -------
    str
        Its C definition.
    """
    nodes = _needed(traced.graph, [*traced.outputs, traced.fault])
    body = [line for i in nodes for line in _value(traced.graph, i)]
    return _function(_signature(traced, "") + ", double *out)", body + _outputs(traced, "out") +
                     [f"return n{traced.fault};"])


_SUM = re.compile(r"const double ([nd]\d+) = (dsc_fsum\(.*)")


def _function(signature: str, body: list) -> str:
    """The C function; a sum whose value nothing reads (it is there for whether Python raises) is not assigned."""
    uses = Counter(re.findall(r"\b[nd]\d+\b", "\n".join(body)))
    lines = []
    for line in body:
        found = _SUM.search(line)
        lines.append(line.replace(found.group(0), found.group(2)) if found and uses[found.group(1)] == 1 else line)
    return signature + "\n{\n" + "".join(f"    {line}\n" for line in lines) + "}\n"


def _active(graph: Graph, nodes: list, differentiable: set) -> dict:
    """For each node that depends on a differentiable argument: True (it has a tangent, active at run time or not)."""
    active = {}
    for i in nodes:
        key = graph.nodes[i]
        if key[0] == "arg":
            active[i] = key[1] in differentiable
        elif key[0] in ("call", "result"):
            raise Untraceable(f"no tangent through a call ({key[1]})")
        else:
            active[i] = not graph.boolean(i) and any(active[j] for j in _operands(key))
    return active


def _tangent(graph: Graph, index: int, active: dict) -> list:
    """The C lines of node ``index``'s activity ``a<index>`` and tangent ``d<index>`` (``models.dual``'s rules)."""
    key = graph.nodes[index]
    op, n = key[0], index
    ops = _operands(key)
    if op == "arg":
        seed = f"d{key[1]}" if key[2] is None else f"d{key[1]}[{key[2]}]"
        return [f"const int a{n} = {seed} != 0.0;", f"const double d{n} = {seed};"]
    act = [f"a{i}" if active[i] else None for i in ops]
    d = [f"d{i}" for i in ops]
    v = [f"n{i}" for i in ops]
    tangent0 = [f"({a} ? {t} : 0.0)" if a else "0.0" for a, t in zip(act, d)]
    activity = " | ".join(a for a in act if a)
    if op in ("add", "sub", "mul", "div"):
        rule = {
            "add": (f"{d[0]} + {d[1]}", d[0], d[1]),
            "sub": (f"{d[0]} - {d[1]}", d[0], f"-{d[1]}"),
            "mul": (f"{v[0]} * {d[1]} + {d[0]} * {v[1]}", f"{d[0]} * {v[1]}", f"{d[1]} * {v[0]}"),
            "div": (f"({d[0]} - n{n} * {d[1]}) / {v[1]}", f"{d[0]} / {v[1]}", f"-n{n} * {d[1]} / {v[1]}"),
        }[op]
        if act[0] and act[1]:
            tangent = f"({act[0]} && {act[1]}) ? {rule[0]} : {act[0]} ? {rule[1]} : {rule[2]}"
        else:
            tangent = rule[1] if act[0] else rule[2]
    elif op in _UNARY_TANGENTS:
        tangent = _UNARY_TANGENTS[op].format(d=d[0], v=v[0], result=f"n{n}")
    elif op == "remainder":
        if act[1]:
            raise Untraceable("remainder() by a differentiable divisor has no dual rule")
        tangent = d[0]
    elif op == "hypot":
        tangent = f"n{n} != 0.0 ? ({v[0]} * {tangent0[0]} + {v[1]} * {tangent0[1]}) / n{n} : 0.0"
    elif op == "fsum":
        return [f"const int a{n} = {activity};", f"int g{n};",
                f"const double d{n} = dsc_fsum({len(ops)}, (const double[]){{{', '.join(tangent0)}}}, &g{n});"]
    else:  # select
        tangent = f"{v[0]} ? {tangent0[1]} : {tangent0[2]}"
        activity = f"{v[0]} ? {act[1] or 0} : {act[2] or 0}"
    return [f"const int a{n} = {activity or 0};", f"const double d{n} = {tangent};"]


def _tangents_needed(graph: Graph, outputs: list, active: dict) -> set:
    """The nodes whose tangents the tangents of ``outputs`` need: the active ones they read, directly or not."""
    needed, stack = set(), [i for i in outputs if active[i]]
    while stack:
        index = stack.pop()
        if index not in needed:
            needed.add(index)
            stack.extend(j for j in _operands(graph.nodes[index]) if active[j])
    return needed


def tangent_function(traced: Traced, differentiable: tuple) -> str:
    """The C function ``int <name>_tangent(<arguments>, <seeds>, double *out, double *dout)``: values and tangents.

    ``out`` receives the values as ``value_function`` gives them, ``dout`` their tangents along the seeds, as
    ``models.dual`` computes them with a dual for each differentiable argument entry of nonzero seed
    (``fmu.directional.seeded``); it returns 1 where Python raises.

    Parameters
    ----------
    traced : Traced
        The traced function.
    differentiable : tuple of str
        The arguments with seeds, ``d<name>`` in C, after all the arguments.

    Returns
    -------
    str
        Its C definition.
    """
    graph = traced.graph
    nodes = _needed(graph, [*traced.outputs, traced.fault])
    active = _active(graph, nodes, set(differentiable))
    # Python sums the tangents of every fsum of duals it evaluates, and may raise there: those are needed too.
    sums = [i for i in nodes if active[i] and graph.nodes[i][0] == "fsum"]
    with_tangent = _tangents_needed(graph, [*traced.outputs, *sums], active)
    body, faults = [], [f"n{traced.fault}"]
    for i in nodes:
        body.extend(_value(graph, i))
        if i in with_tangent:
            body.extend(_tangent(graph, i, active))
            if graph.nodes[i][0] == "fsum":
                faults.append(f"(a{i} && g{i})")
    seeds = "".join(f", double d{name}" if traced.arguments[name] is None else f", const double *d{name}"
                    for name in differentiable)
    tangents = [f"dout[{k}] = {f'a{i} ? d{i} : 0.0' if active[i] else '0.0'};" for k, i in enumerate(traced.outputs)]
    return _function(_signature(traced, "_tangent") + seeds + ", double *out, double *dout)",
                     body + _outputs(traced, "out") + tangents + [f"return {' | '.join(faults)};"])


def rk4_function(substep: Traced, state: int, watch: str | None) -> str:
    """The C loop ``int <name>(<arguments>, long count, double *x, double *watch)``.

    It takes ``count`` sub-steps of ``substep`` (``trace.trace_rk4_substep``) from ``t0``: ``x`` becomes the state
    at ``t0 + step_size``, unchanged where Python raises (it returns 1; else 0). The rates' extra outputs per
    evaluation, the first a flag, are watched: ``"first"``: ``watch`` receives ``[1, t, extras[1:]...]`` of the
    first evaluation whose flag is true (left as given if none is); ``"count"``: ``watch[0]`` the number of
    evaluations whose flag is true.

    Parameters
    ----------
    substep : Traced
        The traced sub-step.
    state : int
        The length of the state.
    watch : str or None
        ``"first"``, ``"count"`` or None (no extras, no ``watch`` argument).

    Returns
    -------
    str
        Its C definition.
    """
    graph = substep.graph
    given = [name for name in substep.arguments if name not in ("count", "k", "x")]
    parts = [f"double {name}" if substep.arguments[name] is None else f"const double *{name}" for name in given]
    signature = f"{_linkage(substep)} int {substep.name}({', '.join(parts)}, long count, double *x_io"
    signature += ", double *watch)" if watch else ")"
    outputs = substep.outputs[state:]
    per_stage = len(outputs) // 4
    stages = [outputs[s * per_stage:(s + 1) * per_stage] for s in range(4)] if watch else []
    watched = [node for stage in stages for node in (stage if watch == "first" else stage[1:2])]
    roots = [*substep.outputs[:state], *watched, substep.fault]
    nodes = _needed(graph, roots)
    varying = set()
    for i in nodes:
        key = graph.nodes[i]
        if (key[0] == "arg" and key[1] in ("x", "k")) or any(j in varying for j in _reads(graph, key)):
            varying.add(i)
    tail = [f"if (n{substep.fault}) return 1;"]
    for stage in stages:
        if watch == "count":
            tail.append(f"if (n{stage[1]}) watched++;")
            continue
        values = [f"n{stage[0]}", *(f"n{i}" for i in stage[2:])]
        stores = " ".join(f"watch[{j + 1}] = {v};" for j, v in enumerate(values))
        tail.append(f"if (!watched && n{stage[1]}) {{ watched = 1; watch[0] = 1.0; {stores} }}")
    tail.extend(f"x[{i}] = n{node};" for i, node in enumerate(substep.outputs[:state]))
    before = [line for i in nodes if i not in varying for line in _value(graph, i)]
    body = [f"double x[{state}];", f"for (int i = 0; i < {state}; i++) x[i] = x_io[i];",
            *(["long watched = 0;"] if watch else []), *before,
            "for (long k = 0; k < count; k++) {",
            *_indented([*(line for i in nodes if i in varying for line in _value(graph, i)), *tail]), "}",
            f"for (int i = 0; i < {state}; i++) x_io[i] = x[i];",
            *(["watch[0] = (double)watched;"] if watch == "count" else []), "return 0;"]
    return _function(signature, body)


def _indented(lines: list) -> list:
    return [f"    {line}" for line in lines]


def c_file(functions: list) -> str:
    """A C file of the ``functions`` (C definitions), which includes ``traced_math.h``.

    Parameters
    ----------
    functions : list of str
        The definitions, callees before callers.

    Returns
    -------
    str
        The file's text.
    """
    head = ("/* Generated by dsc_fmu.fmubuild.emit_c from the Python models: do not edit (docs/traced-c.md). */\n"
            "#include <math.h>\n#include \"traced_math.h\"\n"
            "#ifndef DSC_TRACED_API\n#define DSC_TRACED_API\n#endif\n\n")
    return head + "\n".join(functions)
