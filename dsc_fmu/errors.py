"""The base of every error a user can cause: ``dsc-fmu`` catches it and prints its one-line message."""

__all__ = ["DscFmuError", "FmuNotFoundError", "FmiVersionError", "CosimulationError"]


class DscFmuError(Exception):
    """An error a user can cause and fix: its message is one line naming what is wrong and what is allowed."""


class FmuNotFoundError(DscFmuError, FileNotFoundError):
    """One of the three FMUs is not given or not a file."""


class FmiVersionError(DscFmuError, ValueError):
    """A folder holding FMUs of another FMI version than the one asked: building there would replace them."""


class CosimulationError(DscFmuError, RuntimeError):
    """A run that diverged or in which an FMU failed.

    Parameters
    ----------
    message : str
        One line: what failed, when, and what is allowed.
    time : float
        Simulated time of the failure in s.
    signal : str, optional
        The signal that diverged (``FMU.variable``), if one did.
    value : float, optional
        Its value there.

    Attributes
    ----------
    result : numpy.ndarray or None
        The rows recorded before the failure (dtype ``cosim.signals.DTYPE``), where the master knows them.
    steps : int or None
        The communication steps completed before the failure.
    fmu : str or None
        The FMU whose FMI call failed, if one did.
    """

    def __init__(self, message: str, time: float, signal: str | None = None, value: float | None = None):
        super().__init__(message)
        self.time, self.signal, self.value = time, signal, value
        self.result = None
        self.steps: int | None = None
        self.fmu: str | None = None

    def __reduce__(self):  # picklable with its attributes, to cross from a worker process
        return type(self), (str(self), self.time, self.signal, self.value), self.__dict__
