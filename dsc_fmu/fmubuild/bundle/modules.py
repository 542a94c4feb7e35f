"""Which standard-library modules an FMU's bundled code imports: found by importing it, as the binary
does, in a child of the building CPython that sees nothing but the standard library and the FMU's
resources, with the extension modules a bundle would rather not carry refused until an import needs one."""

from __future__ import annotations

import json
import subprocess
import sys
import sysconfig
from dataclasses import dataclass
from pathlib import Path

from ...errors import DscFmuError

__all__ = ["BundleError"]


class BundleError(DscFmuError, RuntimeError):
    """A CPython runtime cannot be bundled; the message says what is missing and what provides it."""


# Run by ``python -I -S RESOURCES ENTRY REFUSED ANSWER``: imports the bridge and slave modules, then every
# module a bundled module names in an import statement (in functions too); answers (JSON) each module's file
# and the files mapped, or the refused module an import needed.
_CHILD = r"""
import ast, importlib, json, sys
resources, entry, refused = sys.argv[1], sys.argv[2].split(), set(json.loads(sys.argv[3]))

def answer(**fields):
    with open(sys.argv[4], "w") as file:
        json.dump(fields, file)

class Refuse:
    def find_spec(self, name, path=None, target=None):
        if name in refused:
            raise ImportError(name, name=name)

def named_in(path):
    for node in ast.walk(ast.parse(open(path, "rb").read())):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level:
            yield node.module

sys.meta_path.insert(0, Refuse())
sys.path.insert(0, resources)
try:
    for name in entry[:2]:
        importlib.import_module(name)
    bundled = {m.__file__ for m in list(sys.modules.values())
               if (getattr(m, "__file__", None) or "").startswith(resources) and m.__file__.endswith(".py")}
    for name in sorted({n for path in bundled for n in named_in(path)}):
        try:
            importlib.import_module(name)
        except ImportError as error:
            if error.name in refused:
                raise
except ImportError as error:
    if error.name not in refused:
        raise
    answer(refused=error.name)
    sys.exit(0)
try:
    with open("/proc/self/maps") as maps:
        mapped = sorted({line.split(None, 5)[5].strip() for line in maps if len(line.split(None, 5)) == 6})
except OSError:
    mapped = []
answer(modules={name: getattr(module, "__file__", None) for name, module in sys.modules.items()}, mapped=mapped)
"""


@dataclass(frozen=True)
class Imports:
    """What the bundled code imports from the building CPython."""

    sources: dict[str, Path]  # the pure-Python modules' source files under the standard library, by name
    extensions: dict[str, Path]  # the extension modules' files (``lib-dynload``), by name
    names: frozenset  # every module imported, built-in and frozen ones included
    mapped: tuple  # the files the process had mapped: the libraries the extension modules loaded


def building_stdlib() -> tuple[Path, Path]:
    """The building CPython's ``stdlib`` and ``DESTSHARED`` (``lib-dynload``) folders."""
    return Path(sysconfig.get_paths()["stdlib"]), Path(sysconfig.get_config_var("DESTSHARED") or "")


def imported_modules(resources: Path, entry: str, refused: set[str]) -> Imports:
    """The standard-library modules the code in an FMU's unzipped ``resources`` imports when the binary
    loads it (``entry``: the entry file's line), doing without the ``refused`` extension modules where the
    code falls back; ``BundleError`` if it does not import."""
    stdlib, dynload = building_stdlib()
    refused = set(refused)
    answer_file = resources.parent / "imports.json"
    while True:
        run = subprocess.run([sys.executable, "-I", "-S", "-c", _CHILD, str(resources), entry, json.dumps(sorted(refused)),
                              str(answer_file)], capture_output=True, text=True, timeout=300)
        if run.returncode != 0:
            raise BundleError(f"the FMU's code does not import in a bare {sys.executable}: "
                              f"{(run.stderr.strip().splitlines() or ['no output'])[-1]}")
        answer = json.loads(answer_file.read_text())
        if "modules" in answer:
            break
        refused.discard(answer["refused"])
    files = {name: Path(file) for name, file in answer["modules"].items() if file}
    return Imports(
        sources={name: file for name, file in files.items() if file.suffix == ".py" and file.is_relative_to(stdlib)
                 and not file.is_relative_to(stdlib / "site-packages")},
        extensions={name: file for name, file in files.items() if file.parent == dynload},
        names=frozenset(answer["modules"]),
        mapped=tuple(Path(path) for path in answer["mapped"] if path.startswith("/")),
    )
