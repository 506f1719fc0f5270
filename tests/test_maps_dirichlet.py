"""Dirichlet moments, entropy and the Eq. 3 update against scipy and hand-computed values."""

import numpy as np
import pytest
import torch
from scipy import stats

from helios.maps import dirichlet


def test_entropy_matches_scipy_to_1e9_over_many_vectors():
    rng = np.random.default_rng(0)
    for _ in range(300):
        C = int(rng.integers(2, 12))
        gamma = np.exp(rng.uniform(np.log(1e-3), np.log(5e4), size=C))
        assert abs(float(dirichlet.entropy(gamma)) - stats.dirichlet.entropy(gamma)) < 1e-9 * max(1.0, abs(stats.dirichlet.entropy(gamma)))


def test_entropy_is_batched_and_float64_for_tensors():
    gamma = torch.tensor([[1.0, 1.0, 1.0], [3.0, 1.0, 2.0], [1e4, 1.0, 1.0]], dtype=torch.float32)
    h = dirichlet.entropy(gamma)
    assert h.dtype == torch.float64 and h.shape == (3,)
    for row, value in zip(gamma.double().numpy(), h.numpy()):
        assert value == pytest.approx(stats.dirichlet.entropy(row), abs=1e-9)
    # the flat Dirichlet is the maximum-entropy one: log of the simplex volume, -log((C-1)!)
    assert float(h[0]) == pytest.approx(-np.log(2.0), abs=1e-12)


def test_entropy_rejects_non_positive_concentrations():
    with pytest.raises(ValueError, match="> 0"):
        dirichlet.entropy(np.array([1.0, 0.0, 2.0]))


def test_moments_match_scipy_and_expectations_sum_to_one():
    gamma = np.array([[2.0, 5.0, 1.0, 0.5], [30.0, 1.0, 1.0, 1.0]])
    e, var = dirichlet.expectation(gamma), dirichlet.variance(gamma)
    np.testing.assert_allclose(e.sum(axis=1), 1.0, atol=1e-15)
    for row, e_row, v_row in zip(gamma, e, var):
        np.testing.assert_allclose(e_row, stats.dirichlet.mean(row), rtol=1e-14)
        np.testing.assert_allclose(v_row, stats.dirichlet.var(row), rtol=1e-12)


def test_pixel_evidence_adds_alpha_times_kappa_to_the_labelled_class():
    gamma = torch.ones(3, 4, dtype=torch.float64)
    g = torch.tensor([0, 0, 2, 1])
    labels = torch.tensor([1, 1, 3, 0])
    kappa = torch.tensor([0.5, 0.25, 0.1, 0.7])
    dirichlet.add_pixel_evidence(gamma, g, labels, kappa, scale=3.0)
    expected = np.ones((3, 4))
    expected[0, 1] += 3 * 0.75
    expected[2, 3] += 3 * 0.1
    expected[1, 0] += 3 * 0.7
    np.testing.assert_allclose(gamma.numpy(), expected, rtol=1e-7)


def test_most_likely_class_sends_flat_ties_to_background():
    gamma = np.array([[1.0, 1.0, 1.0], [2.0, 1.0, 1.0], [1.0, 3.0, 3.0], [1.0, 4.0, 3.0]])
    assert dirichlet.most_likely_class(gamma, background_index=2).tolist() == [2, 0, 2, 1]
