"""Every FMU (FMI 2.0 and 3.0) carries documentation/index.html made from its variables at build time, and
documentation/externalDependencies.txt."""

import re
import zipfile
from html import unescape
from html.parser import HTMLParser
from xml.etree import ElementTree as ET

import pytest
from fmpy import read_model_description

from dsc_fmu.fmubuild.fmus import DEPENDENCIES_FILE, DOCUMENTATION_FILE
from dsc_fmu.registry import FMUS
from dsc_fmu.fmubuild.documentation import EQUATIONS

VOID = {"meta", "br", "hr", "img", "link", "input"}
# Units the model description cannot carry (FMI Integer / Int32 and Boolean have none): from the tables.
TABLE_UNITS = {v.name: v.unit for spec in FMUS.values() for v in (*spec.parameters, *spec.inputs, *spec.outputs)}


@pytest.fixture(scope="module")
def fmus(fmu_paths, fmu3_paths):
    return {2: fmu_paths, 3: fmu3_paths}


class Page(HTMLParser):
    """Checks that every element is closed in order and collects the text of the table cells by row."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.open, self.problems, self.rows, self.pre, self._cell = [], [], [], [], None

    def handle_starttag(self, tag, attrs):
        if tag not in VOID:
            self.open.append(tag)
        if tag == "tr":
            self.rows.append([])
        elif tag in ("td", "th"):
            self._cell = ""

    def handle_startendtag(self, tag, attrs):
        pass

    def handle_endtag(self, tag):
        if not self.open or self.open.pop() != tag:
            self.problems.append(f"</{tag}> closes nothing open")
        if tag in ("td", "th"):
            self.rows[-1].append(self._cell)
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell += data
        if self.open and self.open[-1] == "pre":
            self.pre.append(data)


def _page(path):
    with zipfile.ZipFile(path) as archive:
        assert DOCUMENTATION_FILE in archive.namelist()
        return archive.read(DOCUMENTATION_FILE).decode("utf-8")


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", list(FMUS))
def test_documentation_lists_every_variable_with_its_unit(fmus, version, name):
    path = fmus[version][name]
    text = _page(path)
    ET.fromstring(text)  # well-formed: parses as XML too
    page = Page()
    page.feed(text)
    page.close()
    assert page.problems == [] and page.open == []

    md = read_model_description(str(path))
    header, *rows = page.rows
    assert header == ["name", "causality", "variability", "start", "unit", "description"]
    by_name = {row[0]: row for row in rows}
    assert [row[0] for row in rows] == [v.name for v in md.modelVariables]
    for v in md.modelVariables:
        row = by_name[v.name]
        unit = v.unit or TABLE_UNITS.get(v.name, "1" if v.type in ("Integer", "Int32") else "")
        assert row[1:3] == [v.causality, v.variability], v.name
        assert row[4] == unit, v.name
        assert row[5] == (v.description or ""), v.name
        if v.start is not None:
            assert float(row[3]) == float(v.start), v.name
    assert "".join(page.pre).strip() == EQUATIONS[name].strip()
    assert md.description in text and f"FMI {md.fmiVersion}" in text
    experiment = md.defaultExperiment
    assert f"startTime = {experiment.startTime}, stopTime = {experiment.stopTime}, stepSize = {experiment.stepSize}" in text


def test_equations_cite_the_paper_equations_of_each_fmu():
    assert "(1)" in EQUATIONS["MobileRobot"] and "(5)" in EQUATIONS["MobileRobot"]
    assert "(9)" in EQUATIONS["ReferenceRobot"]
    assert all(f"({n})" in EQUATIONS["DSCController"] for n in (10, 14, 15, 17, 23, 24))


@pytest.mark.parametrize("version", (2, 3))
@pytest.mark.parametrize("name", list(FMUS))
def test_documentation_states_what_the_importing_machine_needs(fmus, version, name):
    """The flag the model description declares, and the CPython the FMU loads instead of a tool."""
    path = fmus[version][name]
    with zipfile.ZipFile(path) as archive:
        root = ET.fromstring(archive.read("modelDescription.xml"))
        dependencies = " ".join(archive.read(DEPENDENCIES_FILE).decode("utf-8").split())
    flags = {root.find(tag).get("needsExecutionTool") for tag in ("CoSimulation", "ModelExchange")}
    section = _page(path).split("<h2>Requirements</h2>", 1)[1]
    paragraph = unescape(re.match(r"\s*<p>(.*?)</p>", section, re.S).group(1))
    assert dependencies == paragraph  # FMI 3.0's externalDependencies.txt, the same text
    (flag,) = flags  # both interfaces declare the same
    assert f"needsExecutionTool = {flag}" in paragraph
    for requirement in ("x86-64 or aarch64 Linux", "x86-64 Windows", "macOS (11.0 or newer on Apple Silicon",
                        "64-bit CPython 3.9 or newer", "DSC_FMU_PYTHON", "the Python that built the FMU", "PEP 514",
                        "Homebrew"):
        assert requirement in paragraph
