"""Integer parameters with choices fixed at build time: one traced function per combination of the values a function
uses (docs/traced-c.md, "Parameter choices").

A parameter such as the controller's ``adaptation`` chooses between laws for a whole run. Traced as a run-time value
its comparisons would be decisions, every law's arithmetic would be evaluated in C at every call and merged by
selects. Instead each such parameter enters the trace as a ``Choice``: a fixed value that notes every use. A
function is traced with each choice at its first value; for the first choice it used, again once per value; and so
on, until each trace has all the choices it used fixed. The C calls the specialised function of the values in ``p``.
"""

from __future__ import annotations

import operator
import re

from .trace import Untraceable

__all__ = ["Choice", "dispatch_function", "specialise"]


class Choice:
    """An Integer parameter fixed at ``value`` while a function is traced: any use appends ``name`` to ``used``.

    Parameters
    ----------
    name : str
        The parameter's name.
    value : int
        Its value for this trace.
    used : list of str
        Where its uses are noted.
    """

    __slots__ = ("name", "value", "used")

    def __init__(self, name: str, value: int, used: list):
        self.name, self.value, self.used = name, value, used

    def __repr__(self):
        return f"Choice({self.name}={self.value})"


def _noting(operation):
    def method(self, *others):
        self.used.append(self.name)
        return operation(self.value, *(other.value if type(other) is Choice else other for other in others))

    return method


for _name in ("eq", "ne", "lt", "le", "gt", "ge", "add", "sub", "mul", "truediv", "floordiv", "mod", "neg", "pos",
              "abs", "index"):
    setattr(Choice, f"__{_name}__", _noting(getattr(operator, _name)))
for _name in ("add", "sub", "mul", "truediv", "floordiv", "mod"):
    setattr(Choice, f"__r{_name}__", _noting(lambda a, b, op=getattr(operator, _name): op(b, a)))
for _name, _operation in (("bool", bool), ("int", int), ("float", float), ("hash", hash)):
    setattr(Choice, f"__{_name}__", _noting(_operation))


def _identifier(text: str) -> str:
    return re.sub(r"\W", "_", text)


def specialise(name: str, choices: dict, make) -> list:
    """Trace ``make`` once per combination of the values of the choices it uses.

    Parameters
    ----------
    name : str
        The function's name; a specialised one adds ``__<parameter>_<choice>`` per choice fixed.
    choices : dict
        Each Integer parameter's name to the names of its values 0, 1, ...
    make : callable
        ``make(fixed, name)``: the ``trace.Traced`` of the function named ``name`` with the parameters ``fixed``
        (name to ``Choice``) in place of the run-time values.

    Returns
    -------
    list of tuple
        ``(values, name, traced)`` per combination: the choices used and their values (a dict, empty if none was
        used), the specialised function's name, and its ``Traced`` or, where that combination could not be traced,
        the ``Untraceable`` raised.
    """
    found, pending = [], [{}]
    while pending:
        values = pending.pop()
        used = []
        fixed = {choice: Choice(choice, values.get(choice, 0), used) for choice in choices}
        full = name + "".join(f"__{choice}_{_identifier(choices[choice][v])}" for choice, v in values.items())
        try:
            traced = make(fixed, full)
        except Untraceable as error:
            traced = error
        new = next((choice for choice in used if choice not in values), None)
        if new is None:
            found.append((values, full, traced))
        else:
            pending.extend({**values, new: v} for v in reversed(range(len(choices[new]))))
    return found


def dispatch_function(name: str, definition: str, cases: list) -> str:
    """The exported C function ``name`` that calls the function specialised on the parameter values in ``p``.

    Parameters
    ----------
    name : str
        Its name.
    definition : str
        The definition of one specialised function (its first line gives the signature).
    cases : list of tuple
        ``(values, callee)``: the values of the choices (index in ``p`` to value) and the function to call there.

    Returns
    -------
    str
        Its C definition; it returns 1 (run in Python) for values no case has.
    """
    head = definition.splitlines()[0]
    parameters = head[head.index("(") + 1:head.rindex(")")]
    arguments = ", ".join(re.findall(r"\w+", part)[-1] for part in parameters.split(","))
    body = [f"if ({' && '.join(f'p[{i}] == {float(v)!r}' for i, v in values.items())}) "
            f"return {callee}({arguments});" for values, callee in cases]
    lines = "".join(f"    {line}\n" for line in [*body, "return 1;"])
    return f"DSC_TRACED_API int {name}({parameters})\n{{\n{lines}}}\n"
