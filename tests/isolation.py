"""Run an FMU where dsc_fmu, numpy, fmpy and scipy cannot be imported, and judge what it loaded.

``run_isolated`` runs ``PRELUDE`` and a test's body in ``python -I -S`` (no site-packages, no
PYTHON* variables, no script or working folder on sys.path) from a temporary working folder. The
prelude installs a ``sys.meta_path`` finder that refuses and records every import of the blocked
packages, drops the repository from ``sys.path`` and loads the ctypes driver ``fmi_ctypes.py``
(standard library only) by path as ``driver``; the body ends with ``report(result)``.
``violations`` lists whatever in that report shows the FMU needed more than it carries.
"""

import json
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

TESTS = Path(__file__).resolve().parent
REPO = TESTS.parent
DRIVER = TESTS / "fmi_ctypes.py"
FLAGS = {"isolated": 1, "ignore_environment": 1, "no_site": 1, "safe_path": True}
PUBLIC_LIBRARIES = ("pythonfmu", "pythonfmu3")

PRELUDE = r'''
import sys

BLOCKED = ("numpy", "dsc_fmu", "fmpy", "scipy")
ATTEMPTS = []


class Blocker:
    """Refuse, and record, every import of a blocked top-level package."""

    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in BLOCKED:
            ATTEMPTS.append(name)
            raise ImportError(f"{name} is blocked: an FMU must not need it")
        return None


sys.meta_path.insert(0, Blocker())
PRELOADED = sorted(m for m in sys.modules if m.partition(".")[0] in BLOCKED)

import importlib.util
import json
import os

config = json.loads(sys.argv[1])
repo = os.path.realpath(config["repo"])


def inside(path, folder):
    path = os.path.realpath(path)
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


sys.path[:] = [p for p in sys.path if p and not inside(p, repo)]
PATH_AT_START = list(sys.path)

spec = importlib.util.spec_from_file_location("fmi_ctypes", config["driver"])
driver = importlib.util.module_from_spec(spec)
spec.loader.exec_module(driver)


def loaded_modules():
    """Every loaded module that has a file, with the file's real path."""
    modules = {}
    for name, module in list(sys.modules.items()):
        origin = getattr(module, "__file__", None)
        if origin:
            modules[name] = os.path.realpath(origin)
    return modules


def report(result):
    """Print ``result``, with the modules loaded (unless it has them) and what the blocker saw, as
    ``RESULT <json>``."""
    result.setdefault("modules", loaded_modules())
    result.update(
        attempts=ATTEMPTS,
        preloaded=PRELOADED,
        path_at_start=PATH_AT_START,
        flags={f: getattr(sys.flags, f) for f in ("isolated", "ignore_environment", "no_site", "safe_path")},
        blocked_loaded=sorted(m for m in sys.modules if m.partition(".")[0] in BLOCKED),
    )
    print("RESULT " + json.dumps(result))
'''


def run_isolated(body: str, config: dict, cwd: Path) -> dict:
    """Run ``PRELUDE + body`` with ``config`` (plus the repository and the driver) from ``cwd``;
    return what it reported."""
    script = Path(cwd) / "runner.py"
    script.write_text(PRELUDE + body)
    config = dict(config, repo=str(REPO), driver=str(DRIVER))
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON")}
    process = subprocess.run([sys.executable, "-I", "-S", str(script), json.dumps(config)],
                             cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
    lines = [line for line in process.stdout.splitlines() if line.startswith("RESULT ")]
    assert process.returncode == 0 and lines, (
        f"exit {process.returncode}\n{process.stdout[-2000:]}\n{process.stderr[-4000:]}")
    return json.loads(lines[-1][len("RESULT "):])


def _within(path, roots):
    return any(path == root or path.startswith(root.rstrip(os.sep) + os.sep) for root in roots)


def foreign_modules(result) -> dict:
    """Modules loaded from anywhere but the standard library (its site-packages excluded: they sit
    inside it), the extracted FMU and the driver."""
    paths = {key: os.path.realpath(path) for key, path in sysconfig.get_paths().items()}

    def allowed(path):
        return _within(path, [result["unzipped"], str(DRIVER)]) or (
            _within(path, [paths["stdlib"], paths["platstdlib"]])
            and not _within(path, [paths["purelib"], paths["platlib"]]))

    return {name: path for name, path in result["modules"].items() if name != "__main__" and not allowed(path)}


def violations(result, *bundled) -> dict:
    """What in a run's ``result`` breaks isolation, by check; empty if nothing does. ``bundled``:
    prefixes of module names that must have been loaded, all from the FMU's resources folder, with a
    pythonfmu of their own, and (where the result has ``modules_after_free`` and ``path_after_free``)
    gone, with ``sys.path`` as at the start, once the FMU was freed. No public pythonfmu may load."""
    found = {
        "flags": result["flags"] if result["flags"] != FLAGS else {},
        "preloaded": result["preloaded"],
        "repository on sys.path": [p for p in result["path_at_start"] if str(REPO) in p],
        "attempts": result["attempts"],
        "blocked_loaded": result["blocked_loaded"],
        "foreign modules": foreign_modules(result),
    }
    found["a public pythonfmu"] = sorted(m for m in result["modules"] if m.partition(".")[0] in PUBLIC_LIBRARIES)
    resources = os.path.join(result["unzipped"], "resources")
    for prefix in bundled:
        modules = {m: p for m, p in result["modules"].items() if m.startswith(prefix)}
        found[f"{prefix}* not from the FMU's resources"] = (
            {m: p for m, p in modules.items() if not _within(p, [resources])} if modules else "none loaded")
        found[f"{prefix}* without its own pythonfmu"] = not any(m.rpartition(".")[2] in PUBLIC_LIBRARIES
                                                               for m in modules)
        found[f"{prefix}* left after the instance was freed"] = [
            m for m in result.get("modules_after_free", ()) if m.startswith(prefix)]
    if "path_after_free" in result:
        found["sys.path changed by the FMU"] = result["path_after_free"] != result["path_at_start"]
    return {check: what for check, what in found.items() if what}


def bits(rows) -> list:
    """``rows`` with every float as its hexadecimal form, so that equal means equal to the last bit."""
    return [{name: v.hex() if isinstance(v, float) else v for name, v in row.items()} for row in rows]
