"""Where libcosimpy, the optional extra ``libcosim``, can be installed, and the one-line error where it is missing.

libcosimpy 0.0.6 ships wheels only (``WHEELS``), no sdist; everything of dsc-fmu but ``interop.libcosim`` works
without it, so it is an extra, imported only inside the functions that use it."""

from __future__ import annotations

import platform
import sys
from dataclasses import dataclass

from ..errors import DscFmuError

__all__ = ["INSTALL", "WHEELS", "LibcosimUnavailableError", "require_libcosimpy"]

INSTALL = "python3 -m pip install 'dsc-fmu[libcosim]'"
WHEELS = "CPython 3.11-3.14 on x86-64 Linux with glibc 2.28 or newer and on 64-bit Windows"
_PYTHONS = ((3, 11), (3, 14))
_PLATFORMS = {("Linux", "x86_64"), ("Windows", "AMD64")}
_GLIBC = (2, 28)
_SYSTEMS = {"Darwin": "macOS"}  # platform.system()'s names where users know another


class LibcosimUnavailableError(DscFmuError, ImportError):
    """The optional libcosimpy cannot be imported: not installed, or without a wheel for this platform or Python."""


@dataclass(frozen=True)
class Interpreter:
    """A Python interpreter and its machine, as far as choosing a wheel goes: ``platform``'s names
    (``python_implementation``, ``system``, ``machine``), glibc's version on Linux (None: another C library or
    system), pointer width in bits."""

    implementation: str
    version: tuple[int, int]
    system: str
    machine: str
    glibc: tuple[int, int] | None = None
    bits: int = 64

    @classmethod
    def current(cls) -> Interpreter:
        """The interpreter running this code."""
        library, version = platform.libc_ver()
        glibc = tuple(int(part) for part in version.split(".")[:2]) if library == "glibc" else None
        return cls(platform.python_implementation(), sys.version_info[:2], platform.system(), platform.machine(),
                   glibc, 64 if sys.maxsize > 2**32 else 32)

    @property
    def has_libcosimpy_wheel(self) -> bool:
        """Whether libcosimpy ships a wheel for this interpreter (``WHEELS``)."""
        return (self.implementation == "CPython" and _PYTHONS[0] <= self.version <= _PYTHONS[1]
                and (self.system, self.machine) in _PLATFORMS and self.bits == 64
                and (self.system != "Linux" or (self.glibc is not None and self.glibc >= _GLIBC)))

    def __str__(self) -> str:
        bits = "" if self.bits == 64 else f" ({self.bits}-bit)"
        libc = ""
        if self.system == "Linux":
            libc = " without glibc" if self.glibc is None else " with glibc {}.{}".format(*self.glibc)
        system = _SYSTEMS.get(self.system, self.system)
        return f"{self.implementation} {self.version[0]}.{self.version[1]}{bits} on {system} {self.machine}{libc}"


def require_libcosimpy(needed_by: str, interpreter: Interpreter | None = None) -> None:
    """Check that libcosimpy imports, before anything that needs it starts.

    Parameters
    ----------
    needed_by : str
        What needs it, for the message: a function or command.
    interpreter : Interpreter or None, optional
        Where it should import, for the message. Default None: ``Interpreter.current()``.

    Raises
    ------
    LibcosimUnavailableError
        If ``import libcosimpy`` fails: where a wheel exists, naming the command that installs it; elsewhere,
        saying that there is none for this platform or Python and that the rest of dsc-fmu works without it.
    """
    try:
        import libcosimpy  # noqa: F401
    except ImportError:
        here = interpreter or Interpreter.current()
        if here.has_libcosimpy_wheel:
            raise LibcosimUnavailableError(f"{needed_by} needs libcosimpy, which is not installed; install it "
                                           f"with: {INSTALL}") from None
        raise LibcosimUnavailableError(f"{needed_by} needs libcosimpy, which has no wheel for {here} (only for "
                                       f"{WHEELS}), so it cannot be installed here; the rest of dsc-fmu works "
                                       "without it") from None
