"""The controller does not depend on the order in which an importer initialises, sets and reads the three
FMUs: every order, stepped sequentially and Jacobi-style, with reads of u between the sets the way
container FMUs and generic masters make them, runs the paper's start like our master."""

import itertools

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi2 import FMU2Slave

from dsc_fmu.cosim.master import cosimulate
from dsc_fmu.models import parameters as P
from dsc_fmu.scenario import load_scenario

NAMES = ("ReferenceRobot", "MobileRobot", "DSCController")
H, STEPS = 1e-3, 300


class Loop:
    """The three FMUs wired as the paper's loop, each input set from the outputs present when it is set."""

    def __init__(self, unzipped):
        self.fmus, self.vr = {}, {}
        for name in NAMES:
            md = read_model_description(str(unzipped[name]))
            self.vr[name] = {v.name: v.valueReference for v in md.modelVariables}
            fmu = FMU2Slave(guid=md.guid, unzipDirectory=str(unzipped[name]), modelIdentifier=name,
                            instanceName=f"{name}_order")
            fmu.instantiate()
            self.fmus[name] = fmu

    def refs(self, name, names):
        return [self.vr[name][n] for n in names]

    def set_inputs(self, name):
        if name == "DSCController":
            measured = (self.fmus["MobileRobot"].getReal(self.refs("MobileRobot", [v.name for v in P.PLANT_OUTPUTS]))
                        + self.fmus["ReferenceRobot"].getReal(
                            self.refs("ReferenceRobot", [v.name for v in P.REFERENCE_OUTPUTS])))
            self.fmus[name].setReal(self.refs(name, [v.name for v in P.CONTROLLER_INPUTS]), measured)
        elif name == "MobileRobot":
            u = self.fmus["DSCController"].getReal(self.refs("DSCController", ["u1", "u2"]))
            self.fmus[name].setReal(self.refs(name, ["u1", "u2"]), u)
            return u
        return None

    def run(self, order, jacobi):
        for name in order:
            fmu = self.fmus[name]
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            fmu.exitInitializationMode()
        voltages, path = [], []
        for k in range(STEPS):
            t = k * H
            for name in order:
                u = self.set_inputs(name)
                voltages += u or []
                if not jacobi:
                    self.fmus[name].doStep(t, H)
            if jacobi:
                for name in order:
                    self.fmus[name].doStep(t, H)
            path.append(self.fmus["MobileRobot"].getReal(self.refs("MobileRobot", ["x", "y"])))
        for fmu in self.fmus.values():
            fmu.terminate()
            fmu.freeInstance()
        return max(abs(v) for v in voltages), np.array(path)


@pytest.fixture(scope="module")
def ours(fmu_paths):
    scenario = load_scenario("paper").with_simulation(stop_time=STEPS * H, output_interval=H)
    result = cosimulate(scenario, fmu_paths, step_size=H, order="jacobi").result
    return np.column_stack([result["x"][1:], result["y"][1:]])


@pytest.mark.parametrize("jacobi", (False, True), ids=("sequential", "jacobi"))
@pytest.mark.parametrize("order", list(itertools.permutations(NAMES)), ids=lambda o: "-".join(n[:3] for n in o))
def test_every_order_runs_the_paper_start_like_our_master(fmu_unzipped, ours, order, jacobi):
    max_u, path = Loop(fmu_unzipped).run(order, jacobi)
    assert max_u < 50.0, f"max |u| = {max_u:.4g} V"  # 10.5 V over these 0.3 s
    deviation = np.max(np.hypot(*(path - ours).T))
    # Orders that hand u or the measurements over one step later differ from our Jacobi master as
    # libcosim does (12 to 18 um over these 0.3 s, measured); a controller started from stale inputs
    # (zeros at its first step) deviates by 2.3 mm.
    assert deviation < 1e-3, f"position deviation from our master {deviation:.4g} m"
