"""Which functions of the FMUs' models are traced to C, with which arguments, and the C file of them (docs/traced-c.md).

Each FMU's model (``fmu.robot_models``, ``fmu.controller_model``) is traced through its own hooks, ``rates`` and
``outputs``, with its parameters a run-time array in the order of its ``PARAMETERS`` table (``p``), so that what
it derives from them (``derive``: ``plant_coefficients``, ``gains``) is traced too and one C function serves every
parameter value, but for the Integer parameters with choices (``adaptation``, ``voltage_limit``, ``profile``):
one function per value a function uses (``specialise``), behind one that chooses by ``p``. The projection's helpers
are merged where they are called (``LOCAL``). Each RK4 loop repeats one traced sub-step of
``models.rk4.rk4_integrate`` over the rates the model's ``integrate`` evaluates, watching what it records.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

from ..fmu.controller_model import EULER, DSCControllerModel
from ..fmu.robot_models import MobileRobotModel, ReferenceRobotModel
from ..fmu.slave import ModelSlave
from ..models import adaptation, controller
from ..models.adaptation import PROJECTION
from ..models.controller import Switches, control_law
from ..models.plant import UNLIMITED, plant_derivatives, saturation
from ..registry import CONTROLLER, PLANT, REFERENCE
from . import binary, emit_c
from .local import merging_locally
from .specialise import dispatch_function, specialise
from .substep import trace_rk4_substep
from .trace import TRACE_MATH, Graph, Traced, Untraceable, trace

__all__ = ["TracedModels", "compile_library", "fmu_source", "trace_models"]

MODELS = {"plant": MobileRobotModel, "reference": ReferenceRobotModel, "controller": DSCControllerModel}
# The model of each FMU, and the functions its binary calls (``fmu_source``): the RK4 loops, the outputs, model
# exchange's evaluations with the switches held, and the rates the loops call; with the tangents of the outputs
# and the rates.
FMU_MODELS = {REFERENCE: "reference", PLANT: "plant", CONTROLLER: "controller"}
_ME = ("outputs_held", "rates_held", "indicators_held")
FMU_FUNCTIONS = {"reference": ("rates", "outputs", "rk4"), "plant": ("law", "rk4", "rk4_line", "outputs", *_ME),
                 "controller": ("law", "rk4", "rk4_line", "outputs", *_ME)}
# The switches a model holds between events in model exchange (``held``), from the run-time array ``s``: the plant's
# drivers (``FREE``, ``HIGH``, ``LOW``), the controller's ``Switches`` (turns, guarded, the four projections;
# nonzero for true).
HELD = {
    "plant": (2, tuple),
    "controller": (6, lambda s: Switches(s[0], s[1] != 0.0, tuple(switch != 0.0 for switch in s[2:6]))),
}
# The models' helpers whose decisions are merged where they are called (``local.merging_locally``): the
# projection's per-estimate choices, its margins' ``min`` and ``max``, the move onto the sets.
LOCAL = ((adaptation, ("_interval", "_ball", "project_estimates", "min", "max")), (controller, ("min",)))


def _model(kind: str, p: list, fixed: dict, s=None):
    """The FMU's model with the traced parameters ``p``, the choices ``fixed`` (``specialise.Choice``) in place, and
    the switches held from ``s`` (None: chosen at each evaluation)."""
    model = MODELS[kind]()
    model.p = {name: fixed.get(name, value) for name, value in zip(model.p, p)}
    if s is not None:
        model.held = HELD[kind][1](s)
    return model


def _arguments(kind: str, held: bool = False, time: bool = True) -> dict:
    model = MODELS[kind]
    arguments = {"p": len(model.PARAMETERS), **({"t": None} if time else {}), "x": len(model.STATES)}
    if model.INPUTS:
        arguments["u"] = len(model.INPUTS)
    if held:
        arguments["s"] = HELD[kind][0]
    return arguments


def _hook(kind: str, hook: str):
    def function(fixed, p, t, x, u=None, s=None):
        model = _model(kind, p, fixed, s)
        values = getattr(model, hook)(t, x, u, TRACE_MATH)
        if hook == "rates":
            return values
        return [value for value, v in zip(values, model.OUTPUTS) if v.name not in model.UNTRACED_OUTPUTS]

    return function


def _indicators(kind: str):
    def function(fixed, p, x, u, s=None):
        return _model(kind, p, fixed, s).indicators(x, u, TRACE_MATH)

    return function


def _start(fixed, p, u):
    """The controller's state before the first step, its filters started from the inputs (``initial_state``)."""
    return _model("controller", p, fixed).initial_state(u, TRACE_MATH)


def _law(fixed, p, t, x, u):
    """The controller's derivative, then whether the beta guard acts and beta: what ``DSCControllerModel.integrate``
    watches in co-simulation."""
    law = control_law(_model("controller", p, fixed).constants, x, u, None, TRACE_MATH)
    return [*law.derivative, law.guarded, law.beta]


def _drive(fixed, p, t, x, u):
    """The plant's derivative, then whether a driver limits its voltage: what ``MobileRobotModel.integrate`` counts
    in co-simulation."""
    k = _model("plant", p, fixed).constants
    switches = saturation(k, u[0], u[1])
    return [*plant_derivatives(k, t, x, u[0], u[1], TRACE_MATH, switches), switches != UNLIMITED]


def _projection(fixed):
    """What ``DSCControllerModel.integrate`` maps the state with after each sub-step, for the parameters ``p``."""
    def project(p):
        g = _model("controller", p, fixed).constants
        return (lambda x: adaptation.project_estimates(g, x, TRACE_MATH)) if g.adaptation == PROJECTION else None

    return project


def _inputs(t, p, u=None, slope=None, stamp=None):
    """The inputs at ``t`` within a step as the slave gives them (``fmu.slave.ModelSlave.inputs``): held, or on the
    line through ``u`` at ``stamp`` with slopes ``slope``."""
    if u is None:
        return {}
    return {"u": ModelSlave.inputs(SimpleNamespace(u=u, _slope=slope, _stamp=stamp), t)}


def _substep(rates: Traced, kind: str, line: bool, name: str, project) -> Traced:
    """The RK4 sub-step of ``kind`` (inputs held, or on a line), calling the traced rates."""
    arguments = {key: size for key, size in _arguments(kind).items() if key in ("p", "u")}
    if line:
        arguments.update(slope=arguments["u"], stamp=None)
    return trace_rk4_substep(rates, len(MODELS[kind].STATES), _inputs, arguments, name, project)


@dataclass
class TracedModels:
    """The traced functions, the C file and what could not be traced.

    Parameters
    ----------
    functions : dict
        Each traced function (``trace.Traced``) by its C name; one specialised on parameter choices
        (``specialise``) by its own name, ``<name>__<parameter>_<choice>...``, called by ``<name>``.
    untraceable : dict
        The reason, by the C name of each function (or specialisation) that could not be traced (its FMU keeps the
        Python path there: the C function returns 1).
    source : str
        The C file: ``emit_c.value_function`` of each, ``emit_c.tangent_function`` of the rates and outputs
        (differentiable in ``x`` and ``u``), ``emit_c.rk4_function`` of each model's RK4 loop with the inputs held
        (``dsc_<model>_rk4``) and on a line (``dsc_<model>_rk4_line``: ``slope`` and ``stamp`` after ``u``); the
        controller's ``initial_state`` (``dsc_controller_initial_state(p, u, out)``, differentiable in ``u``), the
        event indicators (``dsc_<model>_indicators(p, x, u, out)``, ``_held`` with ``s``); each specialised
        function behind an exported one that chooses by the parameters (``specialise.dispatch_function``).
    """

    functions: dict
    untraceable: dict
    source: str


class _Build:
    """The functions traced so far, their C and what failed."""

    def __init__(self):
        self.graph = Graph()
        self.functions, self.untraceable, self.definitions = {}, {}, []

    def add(self, name: str, kind: str, make, emit) -> list:
        """Trace ``make(fixed, name)`` once per combination of ``kind``'s parameter choices it uses; emit each with
        ``emit(traced)`` (a list of ``(suffix, definition)``) and, if specialised, the exported dispatcher per suffix.
        Returns ``(values, traced)`` of those traced."""
        parameters = MODELS[kind].PARAMETERS
        choices = {v.name: v.choices for v in parameters if v.integer and v.choices}
        index = {v.name: i for i, v in enumerate(parameters)}
        done, emitted = [], {}
        for values, full, traced in specialise(name, choices, make):
            try:
                if isinstance(traced, Untraceable):
                    raise traced
                traced.public = not values
                made = emit(traced)
            except Untraceable as error:
                reason = str(error)
                self.untraceable[full] = reason if reason.startswith(f"{full}: ") else f"{full}: {reason}"
                continue
            self.functions[full] = traced
            done.append((values, traced))
            for suffix, definition in made:
                self.definitions.append(definition)
                emitted.setdefault(suffix, []).append(({index[c]: v for c, v in values.items()}, definition))
        for suffix, cases in emitted.items():
            if cases[0][0]:
                self.definitions.append(dispatch_function(
                    name + suffix, cases[0][1], [(values, _name(definition)) for values, definition in cases]))
        return done


def _name(definition: str) -> str:
    head = definition.splitlines()[0]
    return head[:head.index("(")].split()[-1]


def trace_models(kinds=tuple(MODELS), functions: dict | None = None) -> TracedModels:
    """Trace the FMUs' models and write their C.

    Parameters
    ----------
    kinds : iterable of str, optional
        The models (keys of ``MODELS``): all three by default.
    functions : dict, optional
        By model, the functions to trace (``"rates"``, ``"outputs_held"``, ``"rk4"``, ...: the C names without
        ``dsc_<model>_``); None: every one.

    Returns
    -------
    TracedModels
        The functions, the C source and the untraceable ones with their reasons.
    """
    build = _Build()
    graph = build.graph

    def traced(function, arguments, differentiable=None):
        def make(fixed, name):
            return trace(lambda **symbols: function(fixed, **symbols), arguments, name, graph)

        def emit(traced):
            made = [("", emit_c.value_function(traced))]
            return made + ([("_tangent", emit_c.tangent_function(traced, differentiable))] if differentiable else [])

        return make, emit

    def wanted(kind, function):
        return functions is None or function in functions[kind]

    with merging_locally(LOCAL):
        rates = {}
        for kind in kinds:
            model = MODELS[kind]
            knowns = ("x", "u") if model.INPUTS else ("x",)
            for hook in ("rates", "outputs"):
                for held in (False, True) if kind in HELD else (False,):
                    function = f"{hook}{'_held' if held else ''}"
                    if wanted(kind, function):
                        done = build.add(f"dsc_{kind}_{function}", kind,
                                         *traced(_hook(kind, hook), _arguments(kind, held), knowns))
                        rates.setdefault(kind, done)
            for held in (False, True) if model.INDICATORS else ():
                function = f"indicators{'_held' if held else ''}"
                if wanted(kind, function):
                    build.add(f"dsc_{kind}_{function}", kind,
                              *traced(_indicators(kind), _arguments(kind, held, time=False)))
            if kind == "controller" and wanted(kind, "initial_state"):
                start = {"p": len(DSCControllerModel.PARAMETERS), "u": len(DSCControllerModel.INPUTS)}
                build.add("dsc_controller_initial_state", "controller", *traced(_start, start, ("u",)))
            law = {"plant": _drive, "controller": _law}.get(kind)
            if law is not None and wanted(kind, "law"):
                rates[kind] = build.add(f"dsc_{kind}_law", kind, *traced(law, _arguments(kind)))
            watch = {"plant": "count", "controller": "first"}.get(kind)
            for coupling in ("", "_line") if model.INPUTS else ("",):
                if wanted(kind, f"rk4{coupling}"):
                    _add_rk4(build, kind, coupling, watch, rates[kind])
    return TracedModels(build.functions, build.untraceable, emit_c.c_file(build.definitions))


def fmu_source(name: str, traced: bool = True) -> tuple:
    """The C of an FMU's model that its binary compiles, and what could not be traced.

    Parameters
    ----------
    name : str
        The FMU (a key of ``FMU_MODELS``).
    traced : bool, optional
        False: an empty table, the FMU runs its model in Python only (``binary.NO_TRACED_MODEL``).

    Returns
    -------
    tuple of (str, dict)
        The C: the functions of ``FMU_FUNCTIONS`` with their tangents (internal: the binary compiles the file with
        ``DSC_TRACED_API`` static) and ``TRACED_MODEL`` (``native/traced.h``), the table through which the binary
        calls them; and ``TracedModels.untraceable``.
    """
    if not traced:
        return binary.NO_TRACED_MODEL, {}
    kind = FMU_MODELS[name]
    models = trace_models((kind,), FMU_FUNCTIONS)
    return models.source + _table(kind), models.untraceable


def _watched(kind: str) -> int:
    """How many values ``kind``'s RK4 loop writes into its ``watch`` (``emit_c.rk4_function``): the plant's count
    (one); the controller's flag, time and the extras of its law after the first (``_law`` evaluated once)."""
    if kind == "plant":
        return 1
    if kind != "controller":
        return 0
    model = MODELS[kind]()
    u = [v.start for v in model.INPUTS]
    law = _law({}, list(model.p.values()), 0.0, model.initial_state(u), u)
    return 1 + len(law) - len(model.STATES)


def _table(kind: str) -> str:
    """``TRACED_MODEL`` of ``kind``'s functions, each behind the one signature of ``native/traced.h``."""
    model = MODELS[kind]
    f = f"dsc_{kind}"
    inputs = bool(model.INPUTS)
    u = "u, " if inputs else ""
    watch = {"plant": "TRACED_WATCH_COUNT", "controller": "TRACED_WATCH_FIRST"}.get(kind, "TRACED_WATCH_NONE")
    step_watch = ", watch" if kind in HELD else ""
    step = (f"if (slope) return {f}_rk4_line(p, u, slope, stamp, t0, step_size, count, x{step_watch});\n    "
            if inputs else "")
    held = kind in HELD
    lines = [
        "#include \"traced.h\"",
        "",
        "static int step(const double *p, const double *u, const double *slope, double stamp, double t0, "
        "double step_size, long count, double *x, double *watch) {",
        f"    {step}return {f}_rk4(p, {u}t0, step_size, count, x{step_watch});",
        "}",
        "",
        "static int outputs(const double *p, double t, const double *x, const double *u, const double *s, "
        "double *out) {",
        *([f"    if (s) return {f}_outputs_held(p, t, x, u, s, out);"] if held else []),
        f"    return {f}_outputs(p, t, x, {u}out);",
        "}",
        "",
        "static int rates(const double *p, double t, const double *x, const double *u, const double *s, double *out) {",
        f"    return {f}_rates{'_held' if held else ''}(p, t, x, {u}{'s, ' if held else ''}out);",
        "}",
        "",
    ]
    knowns = "dx, du" if inputs else "dx"
    for name, hook in (("outputs_tangent", "outputs"), ("rates_tangent", "rates")):
        signature = (f"static int {name}(const double *p, double t, const double *x, const double *u, const double *s, "
                     "const double *dx, const double *du, double *out, double *dout) {")
        held_call = f"return {f}_{hook}_held_tangent(p, t, x, u, s, {knowns}, out, dout);"
        free_call = f"return {f}_{hook}_tangent(p, t, x, {u}{knowns}, out, dout);"
        if not held:
            body = [f"    {free_call}"]
        elif hook == "outputs":
            body = [f"    if (s) {held_call}", f"    {free_call}"]
        else:
            body = [f"    {held_call}"]
        lines += [signature, *body, "}", ""]
    if model.INDICATORS:
        lines += ["static int indicators(const double *p, const double *x, const double *u, const double *s, "
                  "double *out) {", f"    return {f}_indicators_held(p, x, u, s, out);", "}", ""]
    traced_outputs = len([v for v in model.OUTPUTS if v.name not in model.UNTRACED_OUTPUTS])
    fields = {"parameters": len(model.PARAMETERS), "states": len(model.STATES), "inputs": len(model.INPUTS),
              "outputs": traced_outputs, "switches": HELD[kind][0] if held else 0, "indicators": len(model.INDICATORS),
              "watch": watch, "watched": _watched(kind), "step": "step", "outputs_of": "outputs", "rates": "rates",
              "indicators_of": "indicators" if model.INDICATORS else "0", "outputs_tangent": "outputs_tangent",
              "rates_tangent": "rates_tangent"}
    lines.append("const TracedModel TRACED_MODEL = {" + ", ".join(f".{k} = {v}" for k, v in fields.items()) + "};")
    return "\n" + "\n".join(lines) + "\n"


def _add_rk4(build: _Build, kind: str, coupling: str, watch: str | None, rates: list) -> None:
    """``dsc_<kind>_rk4<coupling>``: the sub-step over the traced ``rates`` (``(values, traced)`` per specialisation),
    specialised as they are and on the choices its ``project`` uses."""
    name, state = f"dsc_{kind}_rk4{coupling}", len(MODELS[kind].STATES)

    def make(fixed, full):
        matching = [(values, traced) for values, traced in rates
                    if all(fixed[choice].value == value for choice, value in values.items())]
        if not matching:
            raise Untraceable(f"{full}: its rates are not traced")
        values, traced = matching[0]
        for choice in values:  # the rates' choices: this sub-step is specialised on them too
            fixed[choice].used.append(choice)
        if kind == "controller" and fixed["discretization"] == EULER:
            raise Untraceable(f"{full}: discretization = euler takes one Euler step per communication step "
                              "(DSCControllerModel.integrate), not RK4 sub-steps")
        return _substep(traced, kind, bool(coupling), full, _projection(fixed) if kind == "controller" else None)

    build.add(name, kind, make, lambda traced: [("", emit_c.rk4_function(traced, state, watch))])


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
