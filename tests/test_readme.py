"""The README's Python API example runs as written."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.mark.slow
def test_python_api_example_runs(tmp_path):
    section = README.read_text().split("## Python API", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    process = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert process.returncode == 0, process.stderr
    steps, wall_time, error = process.stdout.split()
    assert int(steps) == 5000 and float(wall_time) > 0 and 0 <= float(error) < 1
    assert sorted(p.name for p in (tmp_path / "build" / "fmus").iterdir()) == [
        "DSCController.fmu", "MobileRobot.fmu", "ReferenceRobot.fmu"]
