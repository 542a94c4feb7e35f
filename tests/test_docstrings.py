"""Docstrings a user can scan: every public function, class and method in numpydoc, checked by numpydoc's
own validator.

Public means named in a module's ``__all__`` and defined there; a class's public methods and properties
are those it defines itself (not inherited, no leading underscore); an override without a docstring
shows its base's (``inspect.getdoc``), checked where the base defines it. The checks below are the ones that
make a docstring scannable: a one-line summary, every parameter listed with its type and meaning, a
Returns (or Yields) section for what comes back, known sections in numpydoc's order.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest
from numpydoc.validate import validate

import dsc_fmu

CHECKS = {
    "GL01", "GL02", "GL03", "GL06", "GL07", "GL08",
    "SS01", "SS02", "SS03", "SS04", "SS06",
    "PR01", "PR02", "PR03", "PR04", "PR06", "PR07", "PR10",
    "RT01", "RT03", "YD01",
}

MODULES = sorted(
    info.name for info in pkgutil.walk_packages(dsc_fmu.__path__, "dsc_fmu.")
    if not info.ispkg and info.name != "dsc_fmu.__main__"
)


def _inherits_doc(cls: type, member: str, value) -> bool:
    """Whether ``member`` overrides a base class's documented method without a docstring of its own
    (``inspect.getdoc`` then shows the base's, which is checked where it is defined)."""
    return getattr(value, "__doc__", None) is None and any(
        getattr(getattr(base, member, None), "__doc__", None) for base in cls.__mro__[1:])


def _public(module_name: str) -> list[str]:
    """The dotted names of the public functions, classes and class members that ``module_name`` defines."""
    module = importlib.import_module(module_name)
    names = []
    for name in getattr(module, "__all__", ()):
        obj = getattr(module, name)
        if getattr(obj, "__module__", None) != module_name:
            continue
        if inspect.isfunction(obj):
            names.append(f"{module_name}.{name}")
        elif inspect.isclass(obj):
            names.append(f"{module_name}.{name}")
            for member, value in vars(obj).items():
                if member.startswith("_") or _inherits_doc(obj, member, value):
                    continue
                if inspect.isfunction(value) or isinstance(value, (property, staticmethod, classmethod)):
                    names.append(f"{module_name}.{name}.{member}")
    return names


def _problems(dotted: str) -> list[str]:
    found = validate(dotted)
    # An enum's signature is enum's functional API (names, module, ...), not its own: its members document it.
    checks = {code for code in CHECKS if not code.startswith("PR")} if found["type"] == "EnumType" else CHECKS
    return [f"{code} {message}" for code, message in found["errors"] if code in checks]


@pytest.mark.parametrize("module_name", MODULES)
def test_public_docstrings_are_numpydoc(module_name):
    found = {dotted: _problems(dotted) for dotted in _public(module_name)}
    assert {dotted: problems for dotted, problems in found.items() if problems} == {}


def test_every_module_has_a_public_list():
    assert [name for name in MODULES if not hasattr(importlib.import_module(name), "__all__")] == []


def _prose(step_size, stop_time):
    """Co-simulate with step ``step_size`` until ``stop_time`` and give back the result."""
    return step_size * stop_time


def _scannable(step_size, stop_time):
    """Co-simulate with a fixed step.

    Parameters
    ----------
    step_size : float
        Communication step in s.
    stop_time : float
        Stop time in s.

    Returns
    -------
    float
        The product, in s².
    """
    return step_size * stop_time


def test_the_checks_reject_prose_and_pass_numpydoc():
    assert {"PR01", "RT01"} <= {code for code, _ in validate(f"{__name__}._prose")["errors"]}
    assert _problems(f"{__name__}._scannable") == []
