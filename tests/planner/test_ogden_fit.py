"""Ogden fitting (paper eqs 4-8): both methods recover the paper's curves from noisy test data."""
import numpy as np
import pytest

from planner.materials import ELASTOSIL_2030 as PAPER
from planner.ogden import biaxial_cauchy_stress, pure_shear_nominal_stress, uniaxial_nominal_stress
from planner.ogden_fit import OgdenTestData, fit_ogden, load_test_data, synthesize_test_data, write_test_data
from softblock_config import config_file

pytestmark = pytest.mark.fast


@pytest.fixture(scope="module")
def noisy_csv(tmp_path_factory):
    data = synthesize_test_data(PAPER.mu, PAPER.alpha, np.random.default_rng(7), relative_noise=0.01)
    return write_test_data(data, tmp_path_factory.mktemp("ogden") / "tests.csv")


def test_stress_functions_follow_eqs_5_and_7():
    lam = np.array([1.0, 1.5, 2.0])
    assert uniaxial_nominal_stress(PAPER.mu, PAPER.alpha, 1.0) == 0.0
    expected_shear = sum(2 * m / a * (lam ** (a - 1) - lam ** (-a - 1)) for m, a in zip(PAPER.mu, PAPER.alpha))
    np.testing.assert_allclose(pure_shear_nominal_stress(PAPER.mu, PAPER.alpha, lam), expected_shear)
    # Uniaxial is the biaxial state with l2 = l1**-0.5: nominal stress = Cauchy / stretch.
    np.testing.assert_allclose(
        uniaxial_nominal_stress(PAPER.mu, PAPER.alpha, lam),
        biaxial_cauchy_stress(PAPER.mu, PAPER.alpha, lam, lam**-0.5) / lam,
    )


@pytest.mark.parametrize("method", ["pso", "least_squares"])
def test_fit_recovers_the_paper_curves_within_2_percent(noisy_csv, method):
    data = load_test_data(noisy_csv)
    fit = fit_ogden(data, 3, method, rng=np.random.default_rng(3))
    assert fit.success and fit.method == method and fit.n_evaluations > 0
    for mode, stretch, truth in (
        ("uniaxial", data.uniaxial_stretch, uniaxial_nominal_stress),
        ("pure_shear", data.shear_stretch, pure_shear_nominal_stress),
    ):
        dense = np.linspace(stretch.min(), stretch.max(), 200)
        np.testing.assert_allclose(fit.stress(mode, dense), truth(PAPER.mu, PAPER.alpha, dense), rtol=0.02)


def test_least_squares_needs_far_fewer_evaluations(noisy_csv):
    data = load_test_data(noisy_csv)
    swarm = fit_ogden(data, 2, "pso", options={"particles": 30, "iterations": 200})
    lsq = fit_ogden(data, 2, "least_squares")
    assert lsq.n_evaluations * 10 < swarm.n_evaluations
    assert lsq.cost <= swarm.cost * 1.05


def test_shipped_example_csv_fits():
    data = load_test_data(config_file("ogden_test_data_example.csv"))
    assert len(data.uniaxial_stretch) == len(data.shear_stretch) == 25
    assert fit_ogden(data, 3).cost < 0.01


def test_bad_csvs_name_the_problem(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_test_data(tmp_path / "missing.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("mode,stretch\nuniaxial,1.1\n")
    with pytest.raises(ValueError, match="nominal_stress_Pa"):
        load_test_data(bad)
    bad.write_text("mode,stretch,nominal_stress_Pa\nbiaxial,1.1,5\n")
    with pytest.raises(ValueError, match="line 2: mode"):
        load_test_data(bad)
    bad.write_text("mode,stretch,nominal_stress_Pa\nuniaxial,1.1,abc\n")
    with pytest.raises(ValueError, match="line 2"):
        load_test_data(bad)
    bad.write_text("mode,stretch,nominal_stress_Pa\nuniaxial,1.1,5\nuniaxial,1.2,6\npure_shear,1.1,4\n")
    with pytest.raises(ValueError, match="pure_shear data need at least 2"):
        load_test_data(bad)


def test_bad_arguments_are_rejected():
    data = OgdenTestData(np.array([1.1, 1.2]), np.array([1e4, 2e4]), np.array([1.1, 1.2]), np.array([1e4, 2e4]))
    with pytest.raises(ValueError, match="n_terms"):
        fit_ogden(data, 0)
    with pytest.raises(ValueError, match="method"):
        fit_ogden(data, 1, "newton")
    with pytest.raises(ValueError, match="bounds"):
        fit_ogden(data, 1, options={"bounds": {"mu": (1.0, 0.1), "alpha": (1.0, 2.0)}})
    with pytest.raises(ValueError, match="stretch must be >= 1"):
        OgdenTestData(np.array([0.9, 1.2]), np.array([1.0, 2.0]), np.array([1.1, 1.2]), np.array([1.0, 2.0]))
