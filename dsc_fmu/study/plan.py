"""The plan of a sweep's case: the scenario it runs and the cache keys of its row and reference solution."""

from __future__ import annotations

from dataclasses import dataclass

from ..scenario import Scenario
from .cache import case_key, reference_key
from .cases import Case, apply

__all__ = ["Plan"]


@dataclass(frozen=True)
class Plan:
    """A case of a sweep ready to run: the scenario it runs and its cache keys.

    Parameters
    ----------
    case : Case
        The case.
    applied : Scenario
        The case applied to the sweep's scenario (``cases.apply``).
    key : str
        The cache key of its row (``cache.case_key``).
    reference_key : str
        The cache key of its reference solution (``cache.reference_key``).
    """

    case: Case
    applied: Scenario
    key: str
    reference_key: str

    @classmethod
    def of(cls, scenario: Scenario, case: Case, identities: dict) -> Plan:
        """The plan of a case on a sweep's scenario.

        Parameters
        ----------
        scenario : Scenario
            The sweep's scenario.
        case : Case
            The case.
        identities : dict
            The FMUs' identities by name (``cache.fmu_identities``).

        Returns
        -------
        Plan
            The case, applied, with its keys.
        """
        return cls(case, apply(scenario, case), case_key(scenario, case, identities),
                   reference_key(scenario, case, identities))
