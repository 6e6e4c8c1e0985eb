"""Overlapping Allan variance: the estimator itself, and recovery of simulated noise terms within 10 %."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.nav import allan as av
from ins_hil.sim.calibration import static_noise_record


def _naive_avar(rate: np.ndarray, dt: float, m: int) -> float:
    # textbook overlapping AVAR from cluster averages (IEEE 952 C.1), written as a plain loop
    n = len(rate)
    means = [rate[k : k + m].mean() for k in range(n - m + 1)]
    diffs = [(means[k + m] - means[k]) ** 2 for k in range(n - 2 * m + 1)]
    return 0.5 * sum(diffs) / len(diffs)


def test_estimator_matches_the_definition() -> None:
    rng = np.random.default_rng(0)
    dt = 0.1
    rate = rng.standard_normal(400) + np.cumsum(0.05 * rng.standard_normal(400))
    res = av.allan_deviation(rate * dt, dt, points_per_decade=20, max_fraction=0.25)
    for tau, ad in zip(res.tau, res.adev[:, 0]):
        m = round(tau / dt)
        assert ad**2 == pytest.approx(_naive_avar(rate, dt, m), rel=1e-10)


def test_constant_bias_does_not_change_the_curve() -> None:
    inc = static_noise_record(200.0, 0.01, 1e-3, seed=1)
    a = av.allan_deviation(inc, 0.01)
    b = av.allan_deviation(inc + 0.02 * 0.01, 0.01)  # + 0.02 rad/s bias
    np.testing.assert_allclose(a.adev, b.adev, rtol=1e-9)
    with pytest.raises(ValueError, match="long static record"):
        av.allan_deviation(inc[:10], 0.01)


def test_white_noise_gives_minus_half_slope() -> None:
    n_true = 2e-3
    inc = static_noise_record(2000.0, 0.01, n_true, seed=2)
    res = av.allan_deviation(inc, 0.01)
    # σ(τ) = N/√τ within the estimator's own confidence (3σ)
    expect = n_true / np.sqrt(res.tau)
    assert np.all(np.abs(res.adev / expect[:, None] - 1.0) < 3.0 * res.rel_error[:, None] + 0.01)
    for ax in range(3):
        p = av.noise_parameters(res, ax)
        assert p.random_walk == pytest.approx(n_true, rel=0.10)
        assert p.random_walk_readoff == pytest.approx(n_true, rel=0.10)


def test_all_three_terms_recovered_by_the_fit() -> None:
    # N-, B- and K-dominated regimes meet at τ ≈ 0.2 s and 15 s; 20000 s at 20 Hz
    n_true, b_true, k_true = 3e-5, 1e-4, 3e-5
    inc = static_noise_record(20000.0, 0.05, n_true, b_true, k_true, bias=np.array([1e-3, -2e-3, 5e-4]), seed=0)
    res = av.allan_deviation(inc, 0.05)
    for ax in range(3):
        p = av.noise_parameters(res, ax)
        assert p.random_walk == pytest.approx(n_true, rel=0.10)
        assert p.bias_instability == pytest.approx(b_true, rel=0.10)
        assert p.rate_random_walk == pytest.approx(k_true, rel=0.10)
        # the model curve follows the data within the estimator's confidence (plus 3 %)
        model = av.model_adev(res.tau, p)
        assert np.all(np.abs(res.adev[:, ax] / model - 1.0) < 3.0 * res.rel_error + 0.03)


def test_readoff_of_random_walk_and_rate_random_walk() -> None:
    # velocity random walk and rate random walk, well separated (crossover √3·N/K ≈ 6 s)
    n_true, k_true = 1e-3, 3e-4
    inc = static_noise_record(20000.0, 0.1, n_true, 0.0, k_true, seed=1)
    res = av.allan_deviation(inc, 0.1)
    for ax in range(3):
        p = av.noise_parameters(res, ax)
        assert p.random_walk_readoff == pytest.approx(n_true, rel=0.10)  # σ at τ = 1 s on the −½ line
        assert p.rate_random_walk_readoff == pytest.approx(k_true, rel=0.10)  # σ at τ = 3 s on the +½ line
        assert p.rate_random_walk == pytest.approx(k_true, rel=0.10)


def test_readoff_of_bias_instability() -> None:
    # flicker floor dominant from τ ≈ 0.05 s on: B = floor / 0.664
    b_true = 1e-4
    inc = static_noise_record(20000.0, 0.1, 1e-5, b_true, 0.0, seed=2)
    res = av.allan_deviation(inc, 0.1)
    for ax in range(3):
        p = av.noise_parameters(res, ax)
        assert p.bias_instability_readoff == pytest.approx(b_true, rel=0.10)
        assert p.bias_instability == pytest.approx(b_true, rel=0.10)
    assert av.B_FACTOR == pytest.approx(0.664, abs=5e-4)
    assert math.isfinite(p.tau_min) and p.tau_min > 0
