"""Cross-check artefacts: each FMU replayed alone with its input file reproduces its reference."""

import numpy as np
import pytest
from fmpy import simulate_fmu
from fmpy.cross_check.validate_vendor_repo import validate_test_fmu
from fmpy.util import read_csv, read_ref_opt_file, validate_result

from dsc_fmu import signals
from dsc_fmu.crosscheck import write_crosscheck

H, T = 1e-3, 0.2


@pytest.fixture(scope="module")
def folders(fmu_paths, tmp_path_factory):
    return write_crosscheck(tmp_path_factory.mktemp("xc"), fmu_paths, step_size=H, stop_time=T)


@pytest.mark.parametrize("model", ["ReferenceRobot", "MobileRobot", "DSCController"])
def test_layout_and_replay(folders, model):
    folder = folders[model]
    assert folder.parts[-7:] == ("fmus", "2.0", "cs", "linux64", "dsc-fmu", folder.parts[-2], model)
    assert validate_test_fmu(str(folder)) == []
    assert (folder / "ReadMe.md").is_file()
    assert (folder / f"{model}_in.csv").is_file() == (model != "ReferenceRobot")
    options = read_ref_opt_file(folder / f"{model}_ref.opt")
    assert (options["StartTime"], options["StopTime"], options["StepSize"]) == (0.0, T, H)
    reference = read_csv(folder / f"{model}_ref.csv")
    inputs = folder / f"{model}_in.csv"
    result = simulate_fmu(str(folder / f"{model}.fmu"), stop_time=T, step_size=H, output_interval=H,
                          input=read_csv(inputs) if inputs.exists() else None, output=list(signals.RECORDED[model]))
    assert validate_result(result, reference) == 0
    for name in signals.RECORDED[model]:
        np.testing.assert_allclose(result[name], reference[name], rtol=1e-12, atol=1e-12)


def test_inputs_are_held_with_repeated_stamps(folders):
    inputs = read_csv(folders["MobileRobot"] / "MobileRobot_in.csv")
    assert np.all(np.diff(inputs["time"]) >= 0)
    assert np.array_equal(inputs["u1"][0::2], inputs["u1"][1::2])
    assert np.array_equal(inputs["time"][1:-1:2], inputs["time"][2::2])
