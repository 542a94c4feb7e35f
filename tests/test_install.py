"""The main job from a non-editable install: FMU sources and scenarios travel inside the package."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "dsc_fmu", "fmu_sources", "scenarios")


@pytest.mark.slow
def test_run_from_a_non_editable_install(tmp_path):
    source = tmp_path / "source"
    source.mkdir()
    for name in SOURCES:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(REPO / name, source / name)
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--target", str(site), str(source)],
                   check=True)
    shutil.rmtree(source)
    env = {**os.environ, "PYTHONPATH": str(site)}

    work = tmp_path / "work"
    work.mkdir()
    located = subprocess.run([sys.executable, "-c", "import dsc_fmu; print(dsc_fmu.__file__)"], cwd=work, env=env,
                             capture_output=True, text=True, check=True)
    assert Path(located.stdout.strip()).is_relative_to(site)

    process = subprocess.run(
        [site / "bin" / "dsc-fmu", "run", "figure_eight", "--stop-time", "0.5", "--no-plots"],
        cwd=work, env=env, capture_output=True, text=True,
    )
    assert process.returncode == 0, process.stderr
    assert sorted(p.name for p in (work / "build" / "fmus").iterdir()) == [
        "DSCController.fmu", "MobileRobot.fmu", "ReferenceRobot.fmu",
    ]
    summary = json.loads((work / "results" / "figure_eight" / "summary.json").read_text())
    assert summary["settings"]["stop_time"] == 0.5 and summary["settings"]["steps"] == 500
