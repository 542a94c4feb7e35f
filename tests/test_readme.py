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


ROOT = README.parent
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation but hyphens and underscores dropped,
    spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    return {_slug(m.group(1)) for m in re.finditer(r"^#+ (.+)$", text, flags=re.M)}


@pytest.mark.parametrize("page", PAGES, ids=lambda page: str(page.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    """Every relative link and image of the README and the user guide names a file of the repository,
    and an anchor into a page names one of its headings."""
    broken = []
    for target in LINK.findall(page.read_text()):
        if re.match(r"^[a-z]+:", target):
            continue
        path, _, anchor = target.partition("#")
        file = (page.parent / path).resolve() if path else page
        if not file.exists() or (anchor and file.suffix == ".md" and anchor not in _anchors(file)):
            broken.append(target)
    assert broken == []


def test_the_readme_is_a_front_door_to_every_page_of_the_guide():
    """At most 350 lines, and every page under docs/ one link away."""
    text = README.read_text()
    assert len(text.splitlines()) <= 350
    linked = {(ROOT / target.partition("#")[0]).resolve() for target in LINK.findall(text)}
    assert [p.name for p in PAGES[1:] if p.resolve() not in linked] == []
