"""Sigma sets of Vargas et al. 2015 (Steps 1-2, 1a/eq. 1, 1b/2b): weights and moments."""

from __future__ import annotations

import numpy as np
import pytest

from vecu.estimators.common.covariance import cholesky_lower
from vecu.estimators.common.sigma_sets import (
    PAPER_SETS,
    agm,
    ahsm,
    arm,
    moment_errors,
    paper_set,
)


@pytest.mark.parametrize("name,points", [("ahsm", 7), ("arm", 4), ("agm", 4)])
def test_paper_sets_point_counts_and_moments(name: str, points: int) -> None:
    s = paper_set(name)
    assert s.name == name
    assert s.Z.shape == (3, points)
    assert s.w.shape == (points,)
    e0, e1, e2 = moment_errors(s)
    assert e0 < 1e-14  # sum w = 1
    assert e1 < 1e-14  # sum w Z = 0
    assert e2 < 1e-13  # sum w Z Z^T = I
    assert np.all(s.w > 0.0)


def test_ahsm_weights_lambda_12() -> None:
    s = ahsm(3, 12.0)
    assert s.w[0] == pytest.approx(0.8, abs=1e-15)  # lam / (n + lam)
    np.testing.assert_allclose(s.w[1:], 1.0 / 30.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(s.Z[:, 1:4], np.sqrt(15.0) * np.eye(3), atol=1e-15)
    np.testing.assert_allclose(s.Z[:, 4:], -np.sqrt(15.0) * np.eye(3), atol=1e-15)


def test_arm_step_1a_weights_equal_closed_form() -> None:
    # Step 1a computes w_i = (w0 rho^2 C^-1 11^T C^-T)_ii; it must equal (1 - w0)/n.
    for w0 in (0.8, 0.5, 0.1):
        s = arm(3, w0)
        assert s.w[0] == w0
        np.testing.assert_allclose(s.w[1:], (1.0 - w0) / 3.0, rtol=1e-13)
        assert max(moment_errors(s)) < 1e-13
    rho = np.sqrt(0.2 / 3.0)
    np.testing.assert_allclose(arm().Z[:, 0], -rho / np.sqrt(0.8), rtol=1e-14)  # eq. (1), chi_0


def test_agm_v_ones() -> None:
    s = agm((1.0, 1.0, 1.0))
    np.testing.assert_allclose(s.w, 0.25, rtol=0, atol=1e-15)  # w0 = 1/(1+3), w_i = w0 v_i^2
    np.testing.assert_allclose(s.Z[:, 0], -1.0, atol=1e-14)  # chi_0 carries e = -E w / w0


@pytest.mark.parametrize("s", [ahsm(2, 1.0), ahsm(5, 12.0), arm(2, 0.3), arm(6, 0.9),
                               agm((1.0, -2.0)), agm((0.5, 1.0, 2.0, 3.0))],
                         ids=lambda s: f"{s.name}-n{s.n}")
def test_other_dimensions_and_parameters(s) -> None:
    assert s.points == (2 * s.n + 1 if s.name == "ahsm" else s.n + 1)
    assert max(moment_errors(s)) < 1e-12


@pytest.mark.parametrize("name", PAPER_SETS)
def test_points_reproduce_mean_and_covariance(name: str) -> None:
    rng = np.random.default_rng(7)
    s = paper_set(name)
    A = rng.standard_normal((3, 3))
    P = A @ A.T + 0.1 * np.eye(3)
    x = rng.standard_normal(3) * 10
    chi = x[:, None] + cholesky_lower(P) @ s.Z
    m = chi @ s.w
    d = chi - m[:, None]
    np.testing.assert_allclose(m, x, atol=1e-12)
    np.testing.assert_allclose((d * s.w) @ d.T, P, atol=1e-12)


def test_invalid_parameters() -> None:
    with pytest.raises(ValueError):
        ahsm(3, -3.0)
    with pytest.raises(ValueError):
        arm(3, 1.0)
    with pytest.raises(ValueError):
        arm(3, 0.0)
    with pytest.raises(ValueError):
        agm((1.0, 0.0, 1.0))
    with pytest.raises(ValueError):
        paper_set("ukf")


def test_sets_are_immutable() -> None:
    s = paper_set("arm")
    with pytest.raises(ValueError):
        s.Z[0, 0] = 1.0
    with pytest.raises(ValueError):
        s.w[0] = 1.0
    with pytest.raises(AttributeError):
        s.name = "x"  # type: ignore[misc]  # the write the test expects to fail
