"""The traced C against CPython on random points, free of pytest so that the same checks run on this host
(``test_trace.py``) and in the arm64 root under qemu (``test_trace_aarch64.py``, task ``traced_points``).

Each check takes the compiled library (``ctypes.CDLL``) and returns what a test asserts: the first case whose
C results differ from CPython's in any bit (None if none does) and the cases counted per branch.
"""

from __future__ import annotations

import ctypes
import math
import random
import struct
from types import SimpleNamespace

from dsc_fmu.fmu.controller_model import DSCControllerModel
from dsc_fmu.fmu.directional import seeded
from dsc_fmu.fmu.robot_models import MobileRobotModel, ReferenceRobotModel
from dsc_fmu.fmu.slave import ModelSlave
from dsc_fmu.models.adaptation import PROJECTION
from dsc_fmu.models.controller import Switches, control_law, switches
from dsc_fmu.models.dual import DUAL_MATH, tangent
from dsc_fmu.models.plant import FREE, HIGH, LOW, saturation

MODELS = {"plant": MobileRobotModel, "reference": ReferenceRobotModel, "controller": DSCControllerModel}
STATES = {kind: len(model.STATES) for kind, model in MODELS.items()}
P = ctypes.POINTER(ctypes.c_double)
RK4 = (("plant", False), ("plant", True), ("controller", False), ("controller", True), ("reference", False))
# The parameter choices of case ``i``: every value in turn.
CHOICES = {"plant": lambda i: {"voltage_limit": i % 2}, "controller": lambda i: {"adaptation": i % 4},
           "reference": lambda i: {"profile": i % 2}}


def array(values):
    """A C array of doubles (one element at least)."""
    return (ctypes.c_double * max(1, len(values)))(*values)


def call(library, name, arguments, outputs):
    """``name(*arguments, out)``: arrays for lists, doubles for floats; the outputs and the returned fault flag."""
    out = array([0.0] * outputs)
    fault = getattr(library, name)(*(array(a) if isinstance(a, list) else ctypes.c_double(a) for a in arguments), out)
    return list(out), fault


def _bits(value) -> bytes:
    value = float(value)
    return b"nan" if value != value else struct.pack("<d", value)


def same(c_values, python_values) -> bool:
    """Whether two lists of numbers are equal bit for bit (any NaN equal to any NaN)."""
    return [_bits(v) for v in c_values] == [_bits(v) for v in python_values]


def parameters(kind, rng, spread=0.2, **fixed):
    """The model's parameters by name, the Real ones each scaled by a random factor in [1 - spread, 1 + spread], then
    ``fixed``; the plant's limit between 1 and 12 V and its loads on or off at random, the controller's projection's
    sets about as large as the random estimates."""
    p = {v.name: v.start if v.integer else v.start * rng.uniform(1 - spread, 1 + spread) + (0.0 if v.start else
         rng.uniform(-0.1, 0.1)) for v in MODELS[kind].PARAMETERS}
    if kind == "plant":
        p.update(u_max1=rng.uniform(1, 12), u_max2=rng.uniform(1, 12))
        for i in (1, 2):
            loaded = rng.random() < 0.5
            p.update({f"tau_dc{i}": rng.uniform(-5, 5) * loaded, f"tau_da{i}": rng.uniform(0, 5) * loaded,
                      f"f_d{i}": rng.uniform(0, 2), f"phi_d{i}": rng.uniform(-3, 3)})
    if kind == "controller":
        p.update(a1_min=-1.0, a1_max=1.0, a2_min=-0.5, a2_max=1.5, W1_max=rng.uniform(2, 5), W2_max=rng.uniform(2, 4))
    return {**p, **fixed}


def model(kind, p, held=None):
    """The FMU's model with the parameters ``p`` (and the switches ``held``: model exchange)."""
    m = MODELS[kind]()
    m.p = dict(p)
    m.held = held
    return m


def controller_state(rng, p):
    """A random controller state, its weight estimates now and then exactly on their spheres."""
    xc = [rng.uniform(-2, 2) for _ in range(20)]
    for part, bound in ((slice(4, 12), p["W1_max"]), (slice(14, 20), p["W2_max"])):
        if rng.random() < 0.25:
            norm = math.sqrt(math.fsum(w * w for w in xc[part]))
            xc[part] = [w * bound / norm for w in xc[part]]
    return xc


def measurements(rng, case):
    """Controller inputs: ``case`` 0 anywhere (wraps), 1 on the reference (alpha2's series), 2 behind it (beta guard),
    3 the heading error exactly -pi."""
    theta, thetar = rng.uniform(-8, 8), rng.uniform(-8, 8)
    x, y = rng.uniform(-5, 5), rng.uniform(-5, 5)
    xr, yr = x + rng.uniform(-2, 2), y + rng.uniform(-2, 2)
    if case == 1:
        xr, yr, thetar = x, y, theta + rng.uniform(-1.5e-4, 1.5e-4)
    elif case == 2:
        d = rng.uniform(0.5, 3.0)
        xr, yr = x - d * math.cos(theta), y - d * math.sin(theta)
    elif case == 3:
        theta, thetar = math.pi, 0.0
    return [x, y, theta, rng.uniform(-2, 2), rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(-3, 3),
            rng.uniform(-3, 3), xr, yr, thetar, rng.uniform(0.1, 2.0), rng.uniform(-1, 1), rng.uniform(-1, 1)]


def plant(library, held, count=2000):
    """``dsc_plant_rates``, ``_outputs`` and ``_indicators`` (``_held``: the drivers' switches held) at random states,
    inputs and parameters, the limit on in every other case; counts the cases with a driver limiting and with
    loads."""
    rng = random.Random(1 + 10 * held)
    counts = {"cases": 0, "limited": 0, "loaded": 0}
    for i in range(count):
        p = parameters("plant", rng, voltage_limit=i % 2)
        x, u, t = [rng.uniform(-10, 10) for _ in range(7)], [rng.uniform(-12, 12) for _ in range(2)], rng.uniform(0, 30)
        s, switched = _held("plant", rng) if held else (None, None)
        m = model("plant", p, s)
        suffix = "_held" if held else ""
        arguments = [list(p.values()), t, x, u, *([switched] if held else [])]
        for hook, python in (("rates", m.rates(t, x, u)), ("outputs", m.outputs(t, x, u)[:-1]),
                             ("indicators", m.indicators(x, u))):
            given = [a for a in arguments if a is not t] if hook == "indicators" else arguments
            values, fault = call(library, f"dsc_plant_{hook}{suffix}", given, len(python))
            if fault or not same(values, python):
                return (hook, p, x, u, s), counts
        counts["cases"] += 1
        counts["limited"] += any(switch != FREE for switch in (s or saturation(m.constants, *u)))
        counts["loaded"] += m.constants.loads is not None
    return None, counts


def reference(library, profile, count=1000):
    """``dsc_reference_rates`` and ``_outputs`` with ``profile`` at random times, states and parameters."""
    rng = random.Random(2 + profile)
    for _ in range(count):
        p = {**parameters("reference", rng), "profile": profile}
        x, t = [rng.uniform(-10, 10) for _ in range(3)], rng.uniform(0, 100)
        for hook, outputs in (("rates", 3), ("outputs", 6)):
            values, fault = call(library, f"dsc_reference_{hook}", [list(p.values()), t, x], outputs)
            if fault or not same(values, getattr(model("reference", p), hook)(t, x, None)):
                return (hook, p, x, t), {}
    return None, {"cases": count}


def controller(library, held, adaptation, count=3000):
    """The controller's rates, outputs and event indicators under the law ``adaptation``, switches chosen
    (co-simulation) or ``held`` (model exchange), with the cases counted per branch: wrapped, wrapped to exactly
    pi, on alpha2's series, guarded or not, and (projection) each estimate projected or free."""
    rng = random.Random(4 + held + 10 * adaptation)
    branches = {"wrap": 0, "wrap to pi": 0, "series": 0, "guarded": 0, "unguarded": 0}
    for i in range(count):
        case = i % 4 if i % 4 != 3 or i % 40 == 3 else 0
        p = parameters("controller", rng, spread=0.1, adaptation=adaptation)
        xc, m = controller_state(rng, p), measurements(rng, case)
        chosen = switches(model("controller", p).constants, xc, m)
        turns = chosen.turns + (0 if case == 1 else rng.choice((-1, 0, 1)))
        s, switched = _held("controller", rng) if held else (None, None)
        s = s and s._replace(turns=turns)
        law_model = model("controller", p, s)
        law = control_law(law_model.constants, xc, m, s)
        branches["wrap"] += abs(m[10] - m[2]) > math.pi
        branches["wrap to pi"] += m[10] - m[2] == -math.pi
        branches["series"] += abs(0.5 * law.S13) < 1e-4
        branches["guarded" if law.guarded else "unguarded"] += 1
        if adaptation == PROJECTION:
            for estimate, active in zip(("a1", "a2", "W1", "W2"), law.projected):
                key = f"{estimate} {'projected' if active else 'free'}"
                branches[key] = branches.get(key, 0) + 1
        arguments = [list(p.values()), 0.0, xc, m, *([[float(turns), *switched[1:]]] if held else [])]
        suffix = "_held" if held else ""
        for hook, outputs in (("rates", 20), ("outputs", 24), ("indicators", 3)):
            given = [a for i, a in enumerate(arguments) if i != 1] if hook == "indicators" else arguments
            python = law_model.indicators(xc, m) if hook == "indicators" else getattr(law_model, hook)(0.0, xc, m)
            values, fault = call(library, f"dsc_controller_{hook}{suffix}", given, outputs)
            if fault or not same(values, python):
                return (hook, p, xc, m, s), branches
    return None, branches


def _held(kind, rng):
    """Random switches to hold: the plant's drivers, the controller's ``Switches`` (as a tuple and as ``s``)."""
    if kind == "plant":
        s = tuple(rng.choice((FREE, HIGH, LOW)) for _ in range(2))
        return s, [float(v) for v in s]
    s = Switches(rng.choice((-1, 0, 1)), rng.random() < 0.5, tuple(rng.random() < 0.5 for _ in range(4)))
    return s, [float(s.turns), float(s.guarded), *map(float, s.projected)]


def tangents(library, count=1500):
    """The ``_tangent`` functions against the dual numbers, 30 % of the seeds zero (those knowns stay floats); every
    other plant and controller case with its switches held (``_held_tangent``)."""
    rng = random.Random(6)
    for i in range(count):
        kind = ("plant", "reference", "controller")[i % 3]
        held, s = _held(kind, rng) if kind != "reference" and i // 3 % 2 else (None, None)
        m = model(kind, parameters(kind, rng, spread=0.1, **CHOICES[kind](i)), held)
        x = [rng.uniform(-3, 3) for _ in range(STATES[kind])]
        u = {"plant": [rng.uniform(-3, 3) for _ in range(2)], "controller": measurements(rng, i % 3),
             "reference": None}[kind]
        dx = [0.0 if rng.random() < 0.3 else rng.uniform(-1, 1) for _ in x]
        du = None if u is None else [0.0 if rng.random() < 0.3 else rng.uniform(-1, 1) for _ in u]
        xs, us = seeded(x, dict(enumerate(dx))), None if u is None else seeded(u, dict(enumerate(du)))
        for hook in ("rates", "outputs") if kind != "reference" else ("rates",):
            python = getattr(m, hook)(0.5, xs, us, DUAL_MATH)
            python = python[:-1] if (kind, hook) == ("plant", "outputs") else python  # saturation_time: bookkeeping
            out, dout = array([0.0] * len(python)), array([0.0] * len(python))
            arguments = [array(list(m.p.values())), ctypes.c_double(0.5), array(x), *([] if u is None else [array(u)])]
            arguments += ([] if s is None else [array(s)]) + [array(dx)] + ([] if u is None else [array(du)])
            name = f"dsc_{kind}_{hook}{'' if s is None else '_held'}_tangent"
            fault = getattr(library, name)(*arguments, out, dout)
            values = [v.value if hasattr(v, "value") else v for v in python]
            if fault or not same(list(out), values) or not same(list(dout), [tangent(v) for v in python]):
                return (name, x, u, s, dx, du), {}
    return None, {"cases": count}


def start(library, count=1000):
    """``dsc_controller_initial_state`` (the filters started from the inputs) and its tangents in the inputs, 30 % of
    the seeds zero, against ``initial_state`` on floats and on dual numbers."""
    rng = random.Random(9)
    for i in range(count):
        m = model("controller", parameters("controller", rng, spread=0.1, adaptation=i % 4))
        u = measurements(rng, i % 4)
        du = [0.0 if rng.random() < 0.3 else rng.uniform(-1, 1) for _ in u]
        python = m.initial_state(seeded(u, dict(enumerate(du))), DUAL_MATH)
        out, dout = array([0.0] * 20), array([0.0] * 20)
        fault = library.dsc_controller_initial_state_tangent(array(list(m.p.values())), array(u), array(du), out, dout)
        values, fault_of_values = call(library, "dsc_controller_initial_state", [list(m.p.values()), u], 20)
        if (fault or fault_of_values or not same(values, m.initial_state(u)) or not same(list(out), values)
                or not same(list(dout), [tangent(v) for v in python])):
            return (m.p, u, du), {}
    return None, {"cases": count}


def rk4(library, kind, line, runs=600):
    """``dsc_<kind>_rk4`` (inputs held) or ``_rk4_line`` (inputs on a line) over ten sub-steps against the FMU model's
    own ``integrate``, the choices of the model varied; the watch too: the controller's first guarded evaluation
    ``[1, t, beta]``, the plant's count of evaluations with a driver limiting (from its ``saturation_time``). Counts
    the runs in which the guard acted, the limit acted, the projection moved an estimate."""
    rng = random.Random(7)
    counts = {"runs": runs, "guarded": 0, "limited": 0, "projected": 0}
    for i in range(runs):
        p = parameters(kind, rng, spread=0.1, **CHOICES[kind](i))
        x = controller_state(rng, p) if kind == "controller" else [rng.uniform(-2, 2) for _ in range(STATES[kind])]
        u = {"plant": [rng.uniform(-12, 12) for _ in range(2)], "controller": measurements(rng, i % 3),
             "reference": None}[kind]
        t0, step_size = rng.uniform(0, 30), rng.choice((1e-3, 0.01, 0.05))
        slope = [rng.uniform(-0.5, 0.5) * (20 if kind == "plant" else 1) for _ in u] if line else None
        stamp = t0 + rng.choice((0.0, step_size))
        slave = SimpleNamespace(u=u, _slope=slope, _stamp=stamp)
        m = model(kind, {**p, "max_step": step_size / 10})
        m._guard_seen = None
        expected = m.integrate(t0, x, step_size, lambda t: ModelSlave.inputs(slave, t))
        state, watch = array(x), array([0.0, 0.0, 0.0])
        arguments = [array(list(p.values()))] + ([] if u is None else [array(u)])
        arguments += [array(slope), ctypes.c_double(stamp)] if line else []
        arguments += [ctypes.c_double(t0), ctypes.c_double(step_size), ctypes.c_long(10), state]
        function = getattr(library, f"dsc_{kind}_rk4{'_line' if line else ''}")
        function.argtypes = [P] * (1 + (u is not None)) + ([P, ctypes.c_double] if line else [])
        function.argtypes += [ctypes.c_double, ctypes.c_double, ctypes.c_long, P]
        function.argtypes += [P] if kind != "reference" else []
        fault = function(*arguments, *([watch] if kind != "reference" else []))
        watched = [0.0, 0.0, 0.0]
        if kind == "controller" and m._guard_seen:
            watched = [1.0, *m._guard_seen]
        elif kind == "plant":
            watched[0] = float(round(m.saturation_time * 40 / step_size))
        if fault or not same(list(state), expected) or (kind != "reference" and not same(list(watch), watched)):
            return (kind, line, p, x, u, t0, step_size), counts
        counts["guarded"] += kind == "controller" and m._guard_seen is not None
        counts["limited"] += kind == "plant" and m.saturation_count > 0
        counts["projected"] += kind == "controller" and p["adaptation"] == PROJECTION and (
            expected[0] in (p["a1_min"], p["a1_max"]) or expected[1] in (p["a2_min"], p["a2_max"]))
    return None, counts


def traced_points(fmus: dict) -> dict:
    """Task (``debian_root``): every check above on the library ``fmus["traced"]``; the first differing case of
    each that has one (as text) and the counts."""
    library = ctypes.CDLL(fmus["traced"])
    checks = {**{f"plant held={h}": lambda h=h: plant(library, h) for h in (False, True)},
              **{f"reference {p}": lambda p=p: reference(library, p) for p in (0, 1)},
              **{f"controller held={h} adaptation={a}": lambda h=h, a=a: controller(library, h, a)
                 for h in (False, True) for a in range(4)},
              "tangents": lambda: tangents(library), "initial state": lambda: start(library),
              **{f"rk4 {k} line={ln}": lambda k=k, ln=ln: rk4(library, k, ln) for k, ln in RK4}}
    found = {name: check() for name, check in checks.items()}
    return {"differing": {name: repr(case) for name, (case, _) in found.items() if case is not None},
            "counts": {name: counts for name, (_, counts) in found.items()}}
