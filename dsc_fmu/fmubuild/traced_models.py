"""Which functions of the FMUs' models are traced to C, with which arguments, and the C file of them (docs/traced-c.md).

Each FMU's model (``fmu.robot_models``, ``fmu.controller_model``) is traced through its own hooks, ``rates`` and
``outputs``, with its parameters a run-time array in the order of its ``PARAMETERS`` table (``p``), so that what
it derives from them (``derive``: ``plant_coefficients``, ``gains``) is traced too and one C function serves every
parameter value. Each RK4 loop repeats one traced sub-step of ``models.rk4.rk4_integrate`` over those rates.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

from ..fmu.controller_model import DSCControllerModel
from ..fmu.robot_models import MobileRobotModel, ReferenceRobotModel
from ..fmu.slave import ModelSlave
from ..models.controller import Switches, control_law
from . import binary, emit_c
from .substep import trace_rk4_substep
from .trace import TRACE_MATH, Graph, TooManyPaths, Traced, Untraceable, trace

__all__ = ["TracedModels", "compile_library", "trace_models"]

MODELS = {"plant": MobileRobotModel, "reference": ReferenceRobotModel, "controller": DSCControllerModel}


def _model(kind: str, p: list, held=None):
    """The FMU's model with the traced parameters ``p`` (and the controller's switches ``held``: the number of turns,
    then each Boolean switch as a number, nonzero for true)."""
    model = MODELS[kind]()
    model.p = dict(zip(model.p, p))
    if held is not None:
        model.held = Switches(held[0], *(switch != 0.0 for switch in held[1:]))
    return model


def _arguments(kind: str, held: bool = False) -> dict:
    model = MODELS[kind]
    arguments = {"p": len(model.PARAMETERS), "t": None, "x": len(model.STATES)}
    if model.INPUTS:
        arguments["u"] = len(model.INPUTS)
    if held:
        arguments["s"] = len(Switches._fields)
    return arguments


def _hook(kind: str, hook: str):
    def function(p, t, x, u=None, s=None):
        return getattr(_model(kind, p, s), hook)(t, x, u, TRACE_MATH)

    return function


def _start(p, u):
    """The controller's state before the first step, its filters started from the inputs (``initial_state``)."""
    return _model("controller", p).initial_state(u, TRACE_MATH)


def _indicators(p, x, u, s):
    """The controller's event indicators at the held switches (``indicators``)."""
    return _model("controller", p, s).indicators(x, u)


def _law(p, t, x, u):
    """The controller's derivative, then whether the beta guard acts and beta: what its RK4 watches (co-simulation)."""
    law = control_law(_model("controller", p).constants, x, u, None, TRACE_MATH)
    return [*law.derivative, law.guarded, law.beta]


def _inputs(t, p, u=None, slope=None, stamp=None):
    """The inputs at ``t`` within a step as the slave gives them (``fmu.slave.ModelSlave.inputs``): held, or on the
    line through ``u`` at ``stamp`` with slopes ``slope``."""
    if u is None:
        return {}
    return {"u": ModelSlave.inputs(SimpleNamespace(u=u, _slope=slope, _stamp=stamp), t)}


def _substep(rates: Traced, kind: str, line: bool, name: str) -> Traced:
    """The RK4 sub-step of ``kind`` (inputs held, or on a line), its rates traced into it unless their decisions
    would then combine in more ways than the rates' own (then called)."""
    arguments = {key: size for key, size in _arguments(kind).items() if key in ("p", "u")}
    if line:
        arguments.update(slope=arguments["u"], stamp=None)
    state = len(MODELS[kind].STATES)
    try:
        return trace_rk4_substep(rates, state, _inputs, arguments, name, inline=True)
    except TooManyPaths:
        return trace_rk4_substep(rates, state, _inputs, arguments, name, inline=False)


@dataclass
class TracedModels:
    """The traced functions, the C file and what could not be traced.

    Parameters
    ----------
    functions : dict
        Each traced function (``trace.Traced``) by its C name.
    untraceable : dict
        The reason, by the C name of each function that could not be traced (its FMU keeps the Python path).
    source : str
        The C file: ``emit_c.value_function`` of each, ``emit_c.tangent_function`` of the rates and outputs
        (differentiable in ``x`` and ``u``), ``emit_c.rk4_function`` of each model's RK4 loop with the inputs held
        (``dsc_<model>_rk4``) and on a line (``dsc_<model>_rk4_line``: ``slope`` and ``stamp`` after ``u``); the
        controller's ``initial_state`` (``dsc_controller_initial_state(p, u, out)``, differentiable in ``u``) and
        ``indicators`` (``dsc_controller_indicators(p, x, u, s, out)``).
    """

    functions: dict
    untraceable: dict
    source: str


def trace_models() -> TracedModels:
    """Trace the three FMUs' models and write their C.

    Returns
    -------
    TracedModels
        The functions, the C source and the untraceable ones with their reasons.
    """
    graph = Graph()
    functions, untraceable, definitions = {}, {}, []

    def add(name, make, emit):
        try:
            traced = make()
            made = emit(traced)
        except Untraceable as error:
            untraceable[name] = str(error)
        else:
            functions[name] = traced
            definitions.extend(made)

    for kind, model in MODELS.items():
        knowns = ("x", "u") if model.INPUTS else ("x",)
        for hook in ("rates", "outputs"):
            for held in (False, True) if kind == "controller" else (False,):
                name = f"dsc_{kind}_{hook}{'_held' if held else ''}"
                add(name, lambda: trace(_hook(kind, hook), _arguments(kind, held), name, graph),
                    lambda traced: [emit_c.value_function(traced), emit_c.tangent_function(traced, knowns)])
    add("dsc_controller_law", lambda: trace(_law, _arguments("controller"), "dsc_controller_law", graph),
        lambda traced: [emit_c.value_function(traced)])
    start = {"p": len(DSCControllerModel.PARAMETERS), "u": len(DSCControllerModel.INPUTS)}
    add("dsc_controller_initial_state", lambda: trace(_start, start, "dsc_controller_initial_state", graph),
        lambda traced: [emit_c.value_function(traced), emit_c.tangent_function(traced, ("u",))])
    switched = {key: size for key, size in _arguments("controller", True).items() if key != "t"}
    add("dsc_controller_indicators", lambda: trace(_indicators, switched, "dsc_controller_indicators", graph),
        lambda traced: [emit_c.value_function(traced)])
    for kind, rates in (("plant", "dsc_plant_rates"), ("reference", "dsc_reference_rates"),
                        ("controller", "dsc_controller_law")):
        for coupling in ("", "_line") if MODELS[kind].INPUTS else ("",):
            name = f"dsc_{kind}_rk4{coupling}"
            if rates in untraceable:
                untraceable[name] = f"{name}: its rates are not traced ({untraceable[rates]})"
                continue
            watched = 2 if kind == "controller" else 0
            add(name, lambda: _substep(functions[rates], kind, bool(coupling), name),
                lambda traced: [emit_c.rk4_function(traced, len(MODELS[kind].STATES), watched)])
    return TracedModels(functions, untraceable, emit_c.c_file(definitions))


def compile_library(source: str, folder: Path, target: binary.Target | None = None,
                    flags: tuple = emit_c.C_FLAGS) -> Path:
    """Compile a traced C file into a shared library, its functions exported (tests, benchmarks).

    Parameters
    ----------
    source : str
        The C file's text (``TracedModels.source``).
    folder : Path
        Where the file and the library are written.
    target : binary.Target, optional
        The platform (default: this machine's).
    flags : tuple of str, optional
        The compiler's flags beyond the platform's: ``emit_c.C_FLAGS`` by default.

    Returns
    -------
    Path
        The library, to load with ``ctypes.CDLL``.

    Raises
    ------
    subprocess.CalledProcessError
        If Zig fails.
    """
    target = target or binary.host_target()
    path, library = folder / "traced.c", folder / f"traced{target.suffix}"
    path.write_text(source)
    subprocess.run([sys.executable, "-m", "ziglang", "cc", "-target", target.zig_target, "-shared", *target.flags,
                    "-fvisibility=default", "-O2", *flags, "-Wall", "-Wextra", "-Werror", "-Wno-unused-parameter",
                    f"-I{emit_c.TRACED_MATH_HEADER.parent}", str(path), "-o", str(library), *target.libraries],
                   check=True, capture_output=True)
    return library
