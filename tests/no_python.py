"""A Linux machine without Python, for the tests: a command run in a mount namespace (``unshare -m``, root)
in which every CPython of this machine is hidden, with exactly the environment given (``env -i``).

What is hidden (``hidden()``, found once per session; ``mount_script()`` mounts it):

- folders, each covered by an empty read-only tmpfs: pyenv's ``versions`` (``$PYENV_ROOT``, ``~/.pyenv``,
  and the one the running interpreter comes from), each CPython's own prefix (``sys.base_prefix``, the
  prefix of every ``python*`` on the bin folders, of every ``libpython3*`` found), and where a prefix is
  shared with the system (``/``, ``/usr``, ``/usr/local``) its standard library and site folders
  (``lib/python3*``, ``lib64/python3*``: ``/usr/lib/python3.11``, ``/usr/lib/python3/dist-packages``, ...);
- files, each covered by ``/dev/null``: every ``libpython3*`` under the dynamic loader's folders
  (``/etc/ld.so.conf``, the default and multiarch ``lib`` folders, ``$LD_LIBRARY_PATH``, ``ldconfig -p``'s
  entries) and every ``python*`` in the bin folders (``$PATH``'s and ``/usr/local/bin``, ``/usr/bin``,
  ``/bin``, ``sbin``...), unless it lies in a hidden folder already.

Nothing else is touched, so the test's own files (its temporary folders, the compiled C hosts, the
unzipped FMUs) stay visible; ``run_without_python`` refuses a working folder or a program that would
be hidden (its arguments may name hidden files on purpose).

    run = run_without_python([host, "2", folder, ...], cwd=tmp_path)   # like c_hosts.run_c

Without ``unshare`` or the privilege to use it, ``required`` skips (fails under ``DSC_FMU_CI``)."""

import functools
import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from c_hosts import EMPTY_ENVIRONMENT
from wine import required

__all__ = ["Hidden", "hidden", "mount_script", "run_without_python"]

SHARED_PREFIXES = (Path("/"), Path("/usr"), Path("/usr/local"))
BIN_FOLDERS = ("/usr/local/sbin", "/usr/local/bin", "/usr/sbin", "/usr/bin", "/sbin", "/bin")
LOADER_FOLDERS = ("/lib", "/lib64", "/usr/lib", "/usr/lib64", "/usr/local/lib", "/usr/local/lib64", "/lib/{arch}",
                  "/usr/lib/{arch}", "/usr/local/lib/{arch}")
ARCH = "x86_64-linux-gnu"
OUTER_ENVIRONMENT = {"PATH": "/usr/sbin:/usr/bin:/sbin:/bin"}


@dataclass(frozen=True)
class Hidden:
    """What the namespace hides: ``folders`` under an empty tmpfs, ``files`` under ``/dev/null`` (real
    paths, sorted)."""

    folders: tuple[Path, ...]
    files: tuple[Path, ...]

    def covers(self, path: Path) -> bool:
        """Whether ``path`` (resolved) is hidden: one of ``files``, or in one of ``folders``."""
        path = Path(os.path.realpath(path))
        return path in self.files or any(path.is_relative_to(folder) for folder in self.folders)


def _existing_folders(paths) -> set[Path]:
    return {Path(os.path.realpath(p)) for p in paths if p and os.path.isdir(p)}


def _pyenv_versions() -> set[Path]:
    """pyenv's versions folders: ``$PYENV_ROOT``'s, ``~/.pyenv``'s, and any ancestor of the running
    interpreter named ``versions`` inside a folder named like pyenv."""
    roots = [os.environ.get("PYENV_ROOT"), Path.home() / ".pyenv"]
    running = [Path(sys.base_prefix), Path(os.path.realpath(sys.executable))]
    ancestors = [a for p in running for a in p.parents if a.name == "versions" and "pyenv" in a.parent.name]
    return _existing_folders([*(Path(r) / "versions" for r in roots if r), *ancestors])


def _bin_folders() -> set[Path]:
    return _existing_folders([*os.environ.get("PATH", "").split(os.pathsep), *BIN_FOLDERS])


def _python_executables() -> set[Path]:
    """Every file named ``python*`` in the bin folders (as found there, links not followed)."""
    return {entry for folder in _bin_folders() for entry in folder.glob("python*") if entry.is_file()}


def _ld_so_conf(path: Path) -> list[str]:
    """The folders ``path`` (an ld.so.conf) names, its ``include`` lines followed."""
    folders = []
    for line in path.read_text(errors="replace").splitlines() if path.is_file() else []:
        line = line.split("#", 1)[0].strip()
        if line.startswith("include "):
            for pattern in line.split()[1:]:
                for included in sorted(Path("/").glob(pattern.lstrip("/"))):
                    folders += _ld_so_conf(included)
        elif line:
            folders.append(line)
    return folders


def _ldconfig_libraries() -> list[str]:
    """The ``libpython3*`` files the loader's cache names (``ldconfig -p``)."""
    ldconfig = shutil.which("ldconfig", path=OUTER_ENVIRONMENT["PATH"])
    if not ldconfig:
        return []
    listing = subprocess.run([ldconfig, "-p"], capture_output=True, text=True, timeout=60).stdout
    return re.findall(r"^\s*libpython3\S*\s.*=>\s*(\S+)$", listing, re.MULTILINE)


def _loader_folders() -> set[Path]:
    named = [f.format(arch=ARCH) for f in LOADER_FOLDERS]
    named += _ld_so_conf(Path("/etc/ld.so.conf")) + os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep)
    return _existing_folders(named)


def _libpythons() -> set[Path]:
    """Every ``libpython3*`` file under the loader's folders (their whole trees) and in its cache."""
    found = {Path(p) for p in _ldconfig_libraries() if os.path.exists(p)}
    for folder in _loader_folders():
        for parent, _, names in os.walk(folder):
            found |= {Path(parent) / n for n in names if n.startswith("libpython3")}
    return found


def _prefix_of(path: Path) -> Path | None:
    """The CPython installation ``path`` (an executable in ``bin/`` or a library in ``lib/``,
    ``lib/<arch>/``) belongs to, if that folder holds a ``lib/python3*``."""
    folder = Path(os.path.realpath(path)).parent
    if folder.name == ARCH:
        folder = folder.parent
    if folder.name not in ("bin", "lib", "lib64"):
        return None
    prefix = folder.parent
    return prefix if any((prefix / "lib").glob("python3*")) else None


def _standard_libraries(prefix: Path) -> set[Path]:
    return _existing_folders([*prefix.glob("lib/python3*"), *prefix.glob("lib64/python3*")])


def _outermost(folders: set[Path]) -> tuple[Path, ...]:
    """``folders`` without those inside another of them."""
    return tuple(sorted(f for f in folders if not any(f != o and f.is_relative_to(o) for o in folders)))


@functools.cache
def hidden() -> Hidden:
    """Every CPython of this machine, as the folders and files the namespace covers (module docstring)."""
    executables, libraries = _python_executables(), _libpythons()
    prefixes = {Path(os.path.realpath(sys.base_prefix))}
    prefixes |= {p for p in map(_prefix_of, executables | libraries) if p}
    folders = _pyenv_versions() | {p for p in prefixes if p not in SHARED_PREFIXES}
    for shared in SHARED_PREFIXES:
        folders |= _standard_libraries(shared)
    folders = _outermost(folders)
    covered = Hidden(folders, ())
    files = {Path(os.path.realpath(f)) for f in executables | libraries}
    return Hidden(folders, tuple(sorted(f for f in files if not covered.covers(f))))


@functools.cache
def mount_script() -> str:
    """The shell script that hides ``hidden()`` in the current mount namespace, then runs ``env -i "$@"``
    (the environment's ``NAME=value`` words, then the command)."""
    what = hidden()
    lines = ["set -e"]
    lines += [f"mount -t tmpfs -o ro,size=4k,mode=755 no-python {shlex.quote(str(f))}" for f in what.folders]
    lines += [f"mount --bind /dev/null {shlex.quote(str(f))}" for f in what.files]
    lines.append('exec env -i "$@"')
    return "\n".join(lines)


@functools.cache
def _unavailable() -> str | None:
    """Why the namespace cannot be made here (``unshare`` missing, not permitted, or the mounts fail), or None."""
    unshare = shutil.which("unshare", path=OUTER_ENVIRONMENT["PATH"])
    if not unshare:
        return "util-linux's unshare is not installed (Debian: apt-get install util-linux)"
    if os.geteuid() != 0:
        return "a mount namespace (unshare -m) needs root"
    probe = _namespace(["true"], Path("/"), EMPTY_ENVIRONMENT, 120)
    return None if probe.returncode == 0 else f"unshare -m with the mounts failed: {probe.stderr.strip()[-500:]}"


def _namespace(command: list, cwd: Path, env: dict, timeout: float) -> subprocess.CompletedProcess:
    words = [f"{name}={value}" for name, value in env.items()]
    return subprocess.run(["unshare", "--mount", "--propagation", "private", "--", "sh", "-c", mount_script(),
                           "no-python", *words, *(str(c) for c in command)], cwd=cwd, env=OUTER_ENVIRONMENT,
                          capture_output=True, text=True, timeout=timeout)


def _check_visible(program: str, cwd: Path) -> None:
    """Raise ValueError if ``cwd`` or ``program`` (when a path) would be hidden; the command's arguments
    may name hidden files on purpose."""
    for path in [Path(cwd), *([Path(program)] if "/" in program else [])]:
        if hidden().covers(path):
            raise ValueError(f"{path} would be hidden in the namespace without Python (it lies in a CPython's files)")


def run_without_python(command: list, cwd: Path, env: dict | None = None,
                       timeout: float = 600) -> subprocess.CompletedProcess:
    """Run ``command`` (its words made strings) in ``cwd`` in a mount namespace where ``hidden()`` is
    hidden, with exactly ``env`` as its environment (default: ``c_hosts.EMPTY_ENVIRONMENT``; a command
    by name is looked up on ``env``'s PATH), like ``c_hosts.run_c``: the finished process, its output as
    text. Skips (fails under ``DSC_FMU_CI``) where the namespace cannot be made."""
    reason = _unavailable()
    if reason:
        required(reason)
    _check_visible(str(command[0]), cwd)
    return _namespace(command, cwd, env or EMPTY_ENVIRONMENT, timeout)
