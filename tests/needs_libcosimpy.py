"""The one rule for tests that need libcosimpy (the extra ``libcosim``): they skip only where it cannot be
installed (no wheel for this platform or Python), with that reason; anywhere else a missing libcosimpy
fails them, and under ``DSC_FMU_CI`` (``.ci/run``) they never skip.

A test module imports the fixture and marks the tests that need it::

    from needs_libcosimpy import libcosimpy  # noqa: F401 (the fixture)

    @pytest.mark.usefixtures("libcosimpy")
    def test_...
"""

import pytest

from dsc_fmu.interop.libcosim_install import Interpreter, LibcosimUnavailableError, require_libcosimpy
from wine import required


def check_libcosimpy(interpreter: Interpreter | None = None) -> None:
    """Return where libcosimpy imports; else fail, or skip where ``interpreter`` (default: this one) has no
    libcosimpy wheel and ``DSC_FMU_CI`` is not set. The reason is ``require_libcosimpy``'s message."""
    try:
        require_libcosimpy("this test", interpreter)
    except LibcosimUnavailableError as error:
        if (interpreter or Interpreter.current()).has_libcosimpy_wheel:
            pytest.fail(str(error))
        required(str(error))


@pytest.fixture()
def libcosimpy():
    """libcosimpy importable, or the test skipped or failed by ``check_libcosimpy``'s rule."""
    check_libcosimpy()
