"""The base of every error a user can cause: ``dsc-fmu`` catches it and prints its one-line message."""

__all__ = ["DscFmuError", "FmuNotFoundError"]


class DscFmuError(Exception):
    """An error a user can cause and fix (a bad scenario or option, a missing or wrong FMU, a run that
    diverged, an archive a tool refuses); its message is one line naming what is wrong and what is allowed."""


class FmuNotFoundError(DscFmuError, FileNotFoundError):
    """One of the three FMUs is not given or not a file."""
