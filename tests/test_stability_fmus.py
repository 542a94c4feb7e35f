"""The step-size study's linearised loop from the FMUs' exact directional derivatives (``linearise(...,
source="fmus")``) against the model route's central differences and the paper's analytic entries."""

import math

import numpy as np
import pytest

from dsc_fmu.models.controller import gains
from dsc_fmu.models.plant import plant_coefficients
from dsc_fmu.study import stability as st
from dsc_fmu.study.fmu_loop import fmu_matrices
from dsc_fmu.study.tracking import MEASUREMENT_SELECTION
from dsc_fmu.scenario import load_scenario

NAMES = ("Ap", "Bp", "Cp", "Ac", "Bc", "Cc", "Dc")
# The model route differences at rel = 1e-6: its rounding error is about eps |f| / 1e-6 ~ 1e-10 of a row's
# values and its truncation h^2 |f'''|, so an entry near zero is off by up to ~1e-10 of the matrix's
# largest entry (measured: at most 5.4e-10, in Cc). Hence 1e-6 relative plus 1e-8 of the largest entry.
RTOL, ATOL = 1e-6, 1e-8


def assert_same(found, expected, name=""):
    np.testing.assert_allclose(found, expected, rtol=RTOL, atol=ATOL * max(np.abs(expected).max(), 1.0),
                               err_msg=name)


@pytest.fixture(scope="module")
def scenario():
    return load_scenario("on_reference")  # the scenario of tests/test_stability.py's operating point


@pytest.fixture(scope="module")
def loops(scenario, fmu_paths, tmp_path_factory):
    model = st.linearise(scenario)
    fmus = st.linearise(scenario, source="fmus", fmu_paths=fmu_paths,
                        workdir=tmp_path_factory.mktemp("stab"))
    return model, fmus


def test_the_selection_matrix_is_the_derivative_of_error_measurements():
    """m = E y + (vr, wr at inputs 11, 12): the controller's inputs of error_measurements, for random y."""
    rng = np.random.default_rng(28)
    vr, wr = 0.3, -0.2
    offset = np.zeros(14)
    offset[[11, 12]] = vr, wr
    for y in rng.normal(size=(5, 8)):
        np.testing.assert_array_equal(st.error_measurements(y, vr, wr), MEASUREMENT_SELECTION @ y + offset)


def test_the_fmu_route_gives_the_model_routes_matrices(loops):
    model, fmus = loops
    np.testing.assert_array_equal(fmus.operating_point, model.operating_point)
    assert (fmus.at_time, fmus.discretization, fmus.drift) == (model.at_time, model.discretization, model.drift)
    for name in NAMES:
        assert getattr(fmus, name).shape == getattr(model, name).shape
        assert_same(getattr(fmus, name), getattr(model, name), name)


def test_the_fmu_route_gives_the_same_predicted_boundaries(loops):
    """Every order, discretization and coupling: the same boundary to the bisection's relative width."""
    model, fmus = loops
    for order in ("gauss-seidel", "jacobi"):
        for discretization, coupling in (("rk4", "hold"), ("euler", "hold"), ("rk4", "linear"), ("euler", "linear")):
            args = (order, None if coupling == "hold" and discretization == "rk4" else discretization)
            found = st.predicted_boundary(fmus, *args, coupling=coupling)
            expected = st.predicted_boundary(model, *args, coupling=coupling)
            assert 0.0 < expected < 1.0
            assert found == pytest.approx(expected, rel=1e-3), (order, discretization, coupling)


def test_the_pose_rows_are_the_analytic_entries_of_eq_11(scenario, loops):
    """d S11'/d S12 = theta_dot, d S12'/d S11 = -theta_dot, d S11'/d S13bar = -vr sin S13bar,
    d S12'/d S13bar = vr cos S13bar, d S11'/d v1 = -r/2 + S12 r/(2R), d S13bar'/d v1 = -r/(2R) (eqs. (1), (11))."""
    _, fmus = loops
    k = plant_coefficients(scenario.plant)
    vr = scenario.reference["vr0"]
    S11, S12, S13bar, v1, v2 = fmus.operating_point[:5]
    w = 0.5 * k.r / k.R * (v1 - v2)
    A = fmus.Ap
    assert A[0, 1] == pytest.approx(w, rel=1e-14) and A[1, 0] == pytest.approx(-w, rel=1e-14)
    assert A[0, 2] == pytest.approx(-vr * math.sin(S13bar), rel=1e-13)
    assert A[1, 2] == pytest.approx(vr * math.cos(S13bar), rel=1e-14)
    assert A[0, 3] == pytest.approx(-0.5 * k.r + S12 * 0.5 * k.r / k.R, rel=1e-14)
    assert A[1, 4] == pytest.approx(-S11 * -0.5 * k.r / k.R, rel=1e-13)
    assert A[2, 3] == pytest.approx(-0.5 * k.r / k.R, rel=1e-14)
    assert np.all(A[3:, :3] == 0.0) and np.all(fmus.Bp[:3] == 0.0)


@pytest.mark.parametrize("pose", ((0.3, -0.2, 0.4), (-0.5, 0.7, -1.2), (0.4, 0.3, 3.5)),
                         ids=("near", "far", "wrapped"))
def test_the_fmu_route_away_from_steady_tracking(scenario, loops, fmu_paths, tmp_path, pose):
    """At poses far from tracking, the heading error beyond pi included (the controller's wrap, derivative 1):
    the loop's matrix from the FMUs is the central-difference Jacobian of the model's closed loop."""
    model, _ = loops
    z = model.operating_point.copy()
    z[:3] = pose
    loop = st.LinearLoop(*fmu_matrices(scenario, fmu_paths, z, model.at_time, tmp_path))
    k, g = plant_coefficients(scenario.plant), gains(scenario.controller)
    vr, wr = scenario.reference["vr0"], scenario.reference["wr0"]
    expected = st.jacobian(lambda v: st.closed_loop_derivative(k, g, vr, wr, v), z, 1e-6)
    assert_same(loop.closed_loop_matrix, expected)


def test_bad_sources_are_refused(scenario):
    with pytest.raises(ValueError, match="source = 'fmu' is not allowed; allowed: model, fmus"):
        st.linearise(scenario, source="fmu")
    with pytest.raises(ValueError, match="source 'fmus' needs fmu_paths"):
        st.linearise(scenario, source="fmus")


def test_fmi3_fmus_give_the_same_matrices(scenario, loops, fmu3_paths, tmp_path):
    model, fmus = loops
    found = fmu_matrices(scenario, fmu3_paths, model.operating_point, model.at_time, tmp_path)
    for name, matrix in zip(NAMES, found):
        np.testing.assert_array_equal(matrix, getattr(fmus, name), err_msg=name)
