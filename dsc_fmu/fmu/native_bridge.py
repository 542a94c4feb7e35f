"""What the project's FMU binary (``dsc_fmu/fmubuild/native``) calls besides the slave's own FMI methods.

Bundled into every FMU beside the slave code; imports only the standard library. The binary
loads this module from its file in the FMU's resources (sys.path is never touched), counts the
users of the build's private package (``acquire`` imports it by its location; the last
``release`` forgets its every module), creates the slave through ``instantiate``, reads the variable
table and the model's sizes once (``variables``, ``dimensions``) to guard every get and set by value
reference, type, causality, variability and whether it is a continuous state, forwards the slave's
log queue (``drain_log``) and turns FMU states into bytes and back (``state_to_bytes``,
``state_from_bytes``) with a checksum and the identity of the build that made them.
"""

import hashlib
import importlib.util
import json
import os
import sys

# The binary calls the functions by name; the build imports the codes.
__all__ = ["TYPE_NAMES", "TYPES", "CAUSALITIES", "VARIABILITIES"]

# Codes and names the binary uses too: the build passes them to native/slave.h (binary._contract). The
# type names of each FMI version by code: Real, Integer, Boolean, then String.
TYPE_NAMES = {2: ("Real", "Integer", "Boolean", "String"), 3: ("Float64", "Int32", "Boolean", "String")}
TYPES = {name: code for names in TYPE_NAMES.values() for code, name in enumerate(names)}
CAUSALITIES = {"parameter": 0, "input": 1, "output": 2, "independent": 3, "local": 4}
VARIABILITIES = {"constant": 0, "fixed": 1, "tunable": 2, "discrete": 3, "continuous": 4}
OTHER = 9
MAGIC = b"dsc-fmu FMU state 1\n"
DIGEST = 32
PACKAGE = __name__.partition(".")[0]
_users = 0
_folders = set()


def _load(name: str, path: str):
    """The module ``name`` from the file ``path``, registered in ``sys.modules`` (and removed if it fails)."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def acquire(resources: str) -> None:
    """Count one more slave of this FMU build; import the build's package from ``resources`` if this process has
    not got it (the binary holds the import lock)."""
    global _users
    if PACKAGE not in sys.modules:
        _load(PACKAGE, os.path.join(resources, PACKAGE, "__init__.py"))
    _users += 1
    _folders.add(os.path.realpath(resources))


def _inside(path: str, folders) -> bool:
    path = os.path.realpath(path)
    return any(path == folder or path.startswith(folder + os.sep) for folder in folders)


def release() -> None:
    """Count one slave less; with the last, this build's modules leave ``sys.modules`` and the import caches
    of every folder it was loaded from: the process is as before the first."""
    global _users
    _users -= 1
    if _users > 0:
        return
    for name in [name for name in list(sys.modules) if name == PACKAGE or name.startswith(PACKAGE + ".")]:
        sys.modules.pop(name, None)
    for key in [key for key in list(sys.path_importer_cache) if isinstance(key, str) and _inside(key, _folders)]:
        sys.path_importer_cache.pop(key, None)
    _folders.clear()


def _slave_module(name: str, resources: str):
    """The slave script ``resources/<name>.py``, imported as ``<PACKAGE>.<name>``."""
    qualified = f"{PACKAGE}.{name}"
    return sys.modules.get(qualified) or _load(qualified, os.path.join(resources, f"{name}.py"))


def instantiate(slave_module: str, class_name: str, instance_name: str, resources: str, visible: bool):
    """A new slave: class ``class_name`` of the script ``slave_module`` in ``resources``."""
    cls = getattr(_slave_module(slave_module, resources), class_name)
    return cls(instance_name=instance_name, resources=resources, visible=visible)


def dimensions(slave) -> tuple:
    """``(continuous states, event indicators)`` of the slave's model, for model exchange."""
    return len(slave.model.STATES), len(slave.model.INDICATORS)


def _code(table: dict, value) -> int:
    name = getattr(value, "name", None)
    return table.get(name, OTHER)


def variables(slave) -> list:
    """``(value reference, type, causality, variability, state)`` of every variable as the codes of ``TYPES``,
    ``CAUSALITIES`` and ``VARIABILITIES`` (``OTHER`` for any other); state is 1 for a continuous state (the
    variable of an entry of ``slave.model.STATES``), else 0."""
    states = {s.variable.name for s in slave.model.STATES}
    return [
        (vr, TYPES.get(type(v).__name__, OTHER), _code(CAUSALITIES, v.causality), _code(VARIABILITIES, v.variability),
         int(v.name in states))
        for vr, v in slave.vars.items()
    ]


def drain_log(slave) -> list:
    """``(status, category, message)`` of every message the slave queued since the last call (its queue emptied):
    the FMI status as an int, two strings."""
    queue = slave.log_queue
    messages = [(int(getattr(m.status, "value", m.status)), str(m.category), str(m.msg)) for m in queue]
    del queue[:]
    return messages


def _identity(slave) -> str:
    return f"{type(slave).__module__}.{type(slave).__qualname__}"


def state_to_bytes(slave, state) -> bytes:
    """An FMU state of the slave (from its ``_get_fmu_state``, JSON-serializable) as bytes: a header, a SHA-256
    of the body, then the body: the slave's class and ``state`` in JSON."""
    body = json.dumps([_identity(slave), state], allow_nan=True).encode("utf-8")
    return MAGIC + hashlib.sha256(body).digest() + body


def state_from_bytes(slave, data: bytes):
    """The state that ``state_to_bytes`` wrote for this build of this model, for ``_set_fmu_state``.

    Raises
    ------
    ValueError
        If ``data`` has no header, its checksum does not match or it belongs to another slave class.
    """
    if not data.startswith(MAGIC) or len(data) < len(MAGIC) + DIGEST:
        raise ValueError(f"not a serialized FMU state of dsc-fmu ({len(data)} bytes without its header)")
    digest, body = data[len(MAGIC):len(MAGIC) + DIGEST], data[len(MAGIC) + DIGEST:]
    if hashlib.sha256(body).digest() != digest:
        raise ValueError("the serialized FMU state is damaged (its checksum does not match)")
    identity, state = json.loads(body.decode("utf-8"))
    if identity != _identity(slave):
        raise ValueError(f"the serialized FMU state belongs to {identity}, not to {_identity(slave)}")
    return state
