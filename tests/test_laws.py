"""The adaptation laws compared (``dsc-fmu compare-laws``), their drift under a persistent error, and the laws and
the loads as axes of a step-size sweep."""

import csv
import json
import math

import numpy as np
import pytest
from fmpy import simulate_fmu

from dsc_fmu.cli import main
from dsc_fmu.cosim import signals
from dsc_fmu.models.parameters import ADAPTATIONS
from dsc_fmu.scenario import load_scenario
from dsc_fmu.study.cache import case_key
from dsc_fmu.study.cases import Grid, parse_set
from dsc_fmu.study.laws import LAW_KEYS, law_row

# Measurements held constant: the robot 0.5 m behind and 0.2 m beside the reference, heading 0.1 rad off.
HELD = {"x": 1.5, "y": 1.8, "theta": 0.1, "theta_dot": 0.0, "omega1": 0.0, "omega2": 0.0, "i1": 0.0, "i2": 0.0,
        "x_r": 2.0, "y_r": 2.0, "theta_r": 0.0, "v_r": 1.0, "omega_r": 0.2, "v_r_dot": 0.0}
K1, GAMMA1, SIGMA1 = 2.0, 2.0, 0.5


def a1_rate_and_surface_norm() -> tuple[float, float]:
    """``gamma1 vr (S11 cos(S13bar) + alpha2 S12 S13)`` of (15) and ``|S1| = |(S11, S12, S13)|`` at ``HELD``, from
    the paper's formulas (10), (12), (15)."""
    m = HELD
    ex, ey, vr = m["x_r"] - m["x"], m["y_r"] - m["y"], m["v_r"]
    S11 = math.cos(m["theta"]) * ex + math.sin(m["theta"]) * ey
    S12 = -math.sin(m["theta"]) * ex + math.cos(m["theta"]) * ey
    a = math.atan(K1 * S12 * vr)
    S13bar = m["theta_r"] - m["theta"]
    S13 = S13bar + a
    alpha2 = (math.sin(S13 - a) + math.sin(a)) / S13
    return GAMMA1 * vr * (S11 * math.cos(S13bar) + alpha2 * S12 * S13), math.sqrt(S11**2 + S12**2 + S13**2)


@pytest.mark.parametrize("law", ["none", "sigma", "e"])
def test_a_persistent_error_makes_the_unmodified_law_drift_and_the_leakage_keep_it_bounded(fmu_paths, law):
    """The controller alone under a tracking error that never goes away: without leakage a1_hat grows without
    bound at the rate of (15) (exactly linearly: its rate does not depend on a1_hat); sigma-modification holds
    it at ``rate / (gamma1 sigma1)``, e-modification at ``rate / (gamma1 sigma1 |S1|)``, each approached as
    ``1 - exp(-t / tc)``."""
    rate, norm = a1_rate_and_surface_norm()
    result = simulate_fmu(str(fmu_paths["DSCController"]), stop_time=20.0, step_size=1e-2, output_interval=1.0,
                          output=["a1_hat"], start_values={**HELD, "adaptation": ADAPTATIONS.index(law),
                                                           "sigma1": SIGMA1, "gamma1": GAMMA1, "k1": K1})
    t, a1_hat = result["time"], result["a1_hat"]
    sigma_bound = rate / (GAMMA1 * SIGMA1)
    if law == "none":
        assert a1_hat == pytest.approx(rate * t, rel=1e-12, abs=1e-12)
        assert abs(a1_hat[-1]) > 10.0 * abs(sigma_bound)  # past where sigma-modification holds it, still growing
        return
    leak = GAMMA1 * SIGMA1 * (norm if law == "e" else 1.0)
    assert a1_hat == pytest.approx(rate / leak * (1.0 - np.exp(-leak * t)), rel=1e-8, abs=1e-12)
    assert np.all(np.abs(a1_hat) < abs(rate / leak))  # bounded, at every output point


@pytest.mark.parametrize("version", [2, 3])
def test_projection_active_says_when_the_projection_holds_an_estimate(fmu_paths, fmu3_paths, version):
    """Under the persistent error of ``HELD`` a1_hat rises at the rate of (15) to ``a1_max`` and stays there:
    ``projection_active`` is false until it arrives and true from then on; under sigma-modification never."""
    rate, _ = a1_rate_and_surface_norm()
    a1_max = 5.0 * rate
    path = str((fmu_paths if version == 2 else fmu3_paths)["DSCController"])
    for law in ("projection", "sigma"):
        result = simulate_fmu(path, stop_time=10.0, step_size=0.01, output_interval=0.01,
                              output=["a1_hat", "projection_active"],
                              start_values={**HELD, "adaptation": ADAPTATIONS.index(law), "a1_max": a1_max})
        active = result["projection_active"].astype(bool)
        if law == "sigma":
            assert not active.any()
            continue
        held = result["a1_hat"] == a1_max
        assert not active[0] and active[-1] and held[-1]
        assert np.array_equal(active, held), result["time"][active != held]


def synthetic_result(rows: int = 301) -> np.ndarray:
    """A result of ``signals.DTYPE`` over 30 s with known estimates, errors and voltages."""
    result = np.zeros(rows, dtype=signals.DTYPE)
    result["time"] = np.linspace(0.0, 30.0, rows)
    result["a1_hat"], result["a2_hat"] = 3.0, 4.0
    result["W1_hat_norm"] = 0.1 * result["time"]
    result["W2_hat_norm"] = 12.0
    result["xe"], result["ye"] = 0.03, 0.04
    result["position_error"] = 0.05
    result["u1"], result["u2"] = np.sin(result["time"]) * 300.0, -420.0
    result["u1_applied"], result["u2_applied"] = np.clip(result["u1"], -150, 150), -150.0
    result["saturation_time"] = np.minimum(result["time"], 2.5)
    result["saturation_count"] = 2.0
    return result


def test_a_row_holds_the_last_third_and_the_whole_run_as_defined():
    scenario = load_scenario("paper")
    result = synthetic_result()
    row = law_row(scenario, "sigma", result)
    assert list(row) == list(LAW_KEYS)
    norm = np.sqrt(3.0**2 + 4.0**2 + (0.1 * result["time"]) ** 2 + 12.0**2)
    assert row["estimates_norm_end"] == pytest.approx(norm[-1]) and row["estimates_norm_max"] == pytest.approx(norm[-1])
    assert row["estimates_norm_growth_per_s"] == pytest.approx((norm[-1] - norm[200]) / 10.0)
    assert row["rms_position_error_m"] == pytest.approx(0.05) and row["final_position_error_m"] == pytest.approx(0.05)
    assert (row["max_abs_u_V"], row["max_abs_u_applied_V"]) == (420.0, 150.0)
    assert (row["limit_time_s"], row["limit_count"]) == (2.5, 2)
    assert row["diverged_reason"] == "" and math.isnan(row["diverged_time_s"])


@pytest.mark.slow
def test_compare_laws_writes_what_each_law_did_on_the_robust_scenario(fmu_paths, tmp_path, capsys):
    """The 150 V drivers wind up the paper's law: sigma-modification diverges (its leakage, with the paper's
    sigma1..4 and gains, acts over 500 s and more), the projection keeps the estimates in their sets and tracks."""
    fmu_dir = next(iter(fmu_paths.values())).parent
    status = main(["compare-laws", "robustness", "--laws", "sigma,projection", "--stop-time", "30", "--out",
                   str(tmp_path), "--fmu-dir", str(fmu_dir)])
    assert status == 0
    with open(tmp_path / "laws.csv") as file:
        rows = {row["adaptation"]: row for row in csv.DictReader(file)}
    assert json.loads((tmp_path / "laws.json").read_text())[1]["adaptation"] == "projection"
    assert rows["sigma"]["diverged_reason"] and float(rows["sigma"]["diverged_time_s"]) < 30.0
    assert not rows["projection"]["diverged_reason"]
    assert float(rows["projection"]["rms_position_error_m"]) < 0.05
    assert float(rows["projection"]["max_abs_u_applied_V"]) == 150.0 < float(rows["projection"]["max_abs_u_V"])
    assert float(rows["projection"]["limit_time_s"]) > 0.0
    scenario = load_scenario("robustness").controller
    W_max = math.hypot(scenario["W1_max"], scenario["W2_max"])
    a_max = math.hypot(scenario["a1_max"], scenario["a2_max"])
    assert float(rows["projection"]["estimates_norm_max"]) <= math.hypot(W_max, a_max) * (1.0 + 1e-9)
    table = (tmp_path / "laws.md").read_text()
    assert "| `robustness` | `sigma` | diverged at" in table and "| `robustness` | `projection` | 0.0" in table
    assert (tmp_path / "laws.png").read_bytes()[:4] == b"\x89PNG"
    assert "laws.csv" in capsys.readouterr().out


def test_compare_laws_refuses_an_unknown_law_in_one_line(capsys):
    assert main(["compare-laws", "--laws", "sigma,tanh"]) == 1
    error = capsys.readouterr().err
    assert error == "dsc-fmu: error: adaptation = 'tanh' is not allowed; allowed: sigma, e, projection, none\n"


def test_the_law_and_the_load_are_axes_of_a_sweep_with_cases_keyed_by_them():
    scenario = load_scenario("robustness")
    grid = Grid(step_sizes=[1e-3], orders=["gauss-seidel"], couplings=["hold"], tolerances=[],
                sets=[parse_set("controller.adaptation=sigma,projection"), parse_set("plant.tau_dc1=0,10")])
    cases = grid.cases(scenario)
    assert [dict(case.overrides) for case in cases] == [{"controller.adaptation": law, "plant.tau_dc1": load}
                                                        for law in ("sigma", "projection") for load in (0.0, 10.0)]
    identities = {"MobileRobot": "a", "DSCController": "b", "ReferenceRobot": "c"}
    assert len({case_key(scenario, case, identities) for case in cases}) == 4
