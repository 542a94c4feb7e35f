"""Forward-mode dual numbers and the ``math`` namespace the models evaluate on them (directional derivatives).

A ``Dual`` carries a value and one tangent, the derivative of the value along one direction of the
knowns. The model functions (``plant_derivatives``, ``reference_derivatives``, ``control_law``, ...)
take their math from a namespace argument, ``math`` by default; given ``DUAL_MATH`` instead and
duals for the knowns, the same code returns the values and their directional derivatives, exact to
rounding (docs/model.md §5.13). Comparisons look at the value, so a switch takes the branch the value
takes and the tangent is that branch's. Standard library only: bundled into every FMU.
"""

import math
from types import SimpleNamespace

__all__ = ["DUAL_MATH"]

_new = object.__new__


class Dual:
    """A value with one tangent, its derivative along the direction of the seed: ``value + tangent eps``, ``eps^2 = 0``.

    Arithmetic with floats and duals, unary minus, ``abs``, ``**`` with a float exponent; comparisons
    look at the values only. There is no conversion to float: a dual handed to the ``math`` module
    raises TypeError instead of losing its tangent.

    >>> y = 3.0 * DUAL_MATH.sin(Dual(0.0, 1.0)) + 1.0
    >>> y.value, y.tangent
    (1.0, 3.0)
    """

    __slots__ = ("value", "tangent")
    # The operators make their results with ``_new`` and set both slots: faster than calling the class.

    def __init__(self, value, tangent=0.0):
        self.value = value
        self.tangent = tangent

    def __repr__(self):
        return f"Dual({self.value!r}, {self.tangent!r})"

    def __add__(self, other):
        result = _new(Dual)
        if type(other) is Dual:
            result.value, result.tangent = self.value + other.value, self.tangent + other.tangent
        else:
            result.value, result.tangent = self.value + other, self.tangent
        return result

    __radd__ = __add__

    def __sub__(self, other):
        result = _new(Dual)
        if type(other) is Dual:
            result.value, result.tangent = self.value - other.value, self.tangent - other.tangent
        else:
            result.value, result.tangent = self.value - other, self.tangent
        return result

    def __rsub__(self, other):
        result = _new(Dual)
        result.value, result.tangent = other - self.value, -self.tangent
        return result

    def __mul__(self, other):
        result = _new(Dual)
        if type(other) is Dual:
            result.value = self.value * other.value
            result.tangent = self.value * other.tangent + self.tangent * other.value
        else:
            result.value, result.tangent = self.value * other, self.tangent * other
        return result

    __rmul__ = __mul__

    def __truediv__(self, other):
        result = _new(Dual)
        if type(other) is Dual:
            result.value = quotient = self.value / other.value
            result.tangent = (self.tangent - quotient * other.tangent) / other.value
        else:
            result.value, result.tangent = self.value / other, self.tangent / other
        return result

    def __rtruediv__(self, other):
        result = _new(Dual)
        result.value = quotient = other / self.value
        result.tangent = -quotient * self.tangent / self.value
        return result

    def __neg__(self):
        result = _new(Dual)
        result.value, result.tangent = -self.value, -self.tangent
        return result

    def __pos__(self):
        return self

    def __abs__(self):
        """``|x|``: the tangent of the branch the value is on (the + branch at 0, -0.0 included)."""
        return Dual(abs(self.value), self.tangent) if self.value >= 0.0 else Dual(-self.value, -self.tangent)

    def __pow__(self, exponent):
        """``x ** exponent`` for a float (or int) exponent (``x ** 0`` is 1 with tangent 0)."""
        if type(exponent) is Dual:
            return NotImplemented
        if exponent == 0:
            return Dual(1.0, 0.0)
        return Dual(self.value ** exponent, exponent * self.value ** (exponent - 1) * self.tangent)

    def __bool__(self):
        """Whether the value is not zero, as for a float (``if x:`` takes the value's branch)."""
        return self.value != 0.0

    def __lt__(self, other):
        return self.value < _value(other)

    def __le__(self, other):
        return self.value <= _value(other)

    def __gt__(self, other):
        return self.value > _value(other)

    def __ge__(self, other):
        return self.value >= _value(other)

    def __eq__(self, other):
        return self.value == _value(other)

    def __ne__(self, other):
        return self.value != _value(other)

    __hash__ = None


def _value(x):
    """The value of a dual, or ``x`` itself."""
    return x.value if type(x) is Dual else x


def tangent(x) -> float:
    """The tangent of a result ``x`` of a model function on duals: 0 for a float (a value that does not depend
    on the knowns)."""
    return x.tangent if type(x) is Dual else 0.0


def _sin(x):
    if type(x) is Dual:
        return Dual(math.sin(x.value), math.cos(x.value) * x.tangent)
    return math.sin(x)


def _cos(x):
    if type(x) is Dual:
        return Dual(math.cos(x.value), -math.sin(x.value) * x.tangent)
    return math.cos(x)


def _atan(x):
    if type(x) is Dual:
        return Dual(math.atan(x.value), x.tangent / (1.0 + x.value * x.value))
    return math.atan(x)


def _sqrt(x):
    """``sqrt(x)``; at ``x = 0`` the tangent is 0 (a norm at a zero estimate, docs/model.md §5.13)."""
    if type(x) is Dual:
        root = math.sqrt(x.value)
        return Dual(root, 0.5 * x.tangent / root if root else 0.0)
    return math.sqrt(x)


def _remainder(x, y):
    """``x`` less the nearest multiple of the float ``y``: tangent 1 on each branch (docs/model.md §5.4)."""
    if type(x) is Dual:
        return Dual(math.remainder(x.value, y), x.tangent)
    return math.remainder(x, y)


def _hypot(x, y):
    """``hypot(x, y)``: tangent ``(x x' + y y') / hypot`` (0 at the origin, as ``_sqrt``)."""
    if type(x) is not Dual and type(y) is not Dual:
        return math.hypot(x, y)
    x_value, y_value = _value(x), _value(y)
    length = math.hypot(x_value, y_value)
    return Dual(length, (x_value * tangent(x) + y_value * tangent(y)) / length if length else 0.0)


def _fsum(values):
    """``math.fsum`` of the values and, as exactly, of the tangents."""
    values = list(values)
    if not any(type(v) is Dual for v in values):
        return math.fsum(values)
    return Dual(math.fsum(_value(v) for v in values), math.fsum(tangent(v) for v in values))


DUAL_MATH = SimpleNamespace(
    pi=math.pi, sin=_sin, cos=_cos, atan=_atan, sqrt=_sqrt, remainder=_remainder, hypot=_hypot, fsum=_fsum,
)
"""The functions of the ``math`` module that the models use, on duals and floats alike."""
