"""FilterConfig.omega_rv_terms: the ∂ω/∂r, ∂ω/∂v terms of build_F (digest 001-K) against finite differences of
the NED mechanization and against seed 001's corrected F31, F32; off (the default) leaves F unchanged."""

from __future__ import annotations

import math

import numpy as np

from ins_hil.fusion.ekf import ErrorStateEKF, FilterConfig
from ins_hil.nav import earth
from ins_hil.reproduce import seed001_jacobian as sj


def test_core_F_matches_finite_differences_with_the_terms() -> None:
    worst, att = sj.core_F_compare(True)
    assert worst < 1e-5
    assert att < 1e-6


def test_default_F_lacks_the_terms_and_is_unchanged() -> None:
    _, att = sj.core_F_compare(False)
    assert att > 0.5  # the default model leaves the attitude ← (δr, δv) blocks at zero
    lat, h, v = 0.9, 300.0, np.array([25.0, -12.0, 0.0])
    args = (np.eye(3), np.array([0.3, 0.1, -9.8]), earth.earth_rate_ned(lat), earth.transport_rate_ned(lat, h, v),
            np.array([0.1, 0.0, -9.8]), np.array([0.01, 0.0, 0.02]), lat, h)  # fmt: skip
    F0 = ErrorStateEKF(FilterConfig()).build_F(*args).copy()
    F1 = ErrorStateEKF(FilterConfig(omega_rv_terms=True)).build_F(*args).copy()
    diff = F1 != F0
    assert not diff[:3].any() and not diff[9:].any() and not diff[:, 6:].any()  # only rows δv, μ × cols δr, δv
    assert diff[6:9, 0:6].any() and diff[3:6, 0:6].any()
    # without earth_terms the option has nothing to add to
    F2 = ErrorStateEKF(FilterConfig(omega_rv_terms=True, earth_terms=False)).build_F(*args)
    np.testing.assert_array_equal(F2, ErrorStateEKF(FilterConfig(earth_terms=False)).build_F(*args))


def test_attitude_blocks_equal_seed001_F31_F32_in_ned() -> None:
    er, ev = sj.core_attitude_vs_seed001()
    assert er < 1e-9 and ev < 1e-9


def test_earth_rate_column_at_rest() -> None:
    # at rest only ∂ω_ie/∂δN survives: (−Ω sin φ, 0, −Ω cos φ)/(M + h)
    lat, h = math.radians(30.0), 0.0
    z = np.zeros(3)
    F = ErrorStateEKF(FilterConfig(omega_rv_terms=True)).build_F(
        np.eye(3), np.array([0.0, 0.0, -9.8]), earth.earth_rate_ned(lat), z, z, z, lat, h
    )
    M, _ = earth.radii(lat)
    exp = np.array([-math.sin(lat), 0.0, -math.cos(lat)]) * earth.OMEGA_E / (M + h)
    np.testing.assert_allclose(F[6:9, 0], exp, rtol=1e-12)
    np.testing.assert_array_equal(F[3:6, 0:2], 0.0)


def test_config_key_reaches_the_filter() -> None:
    from ins_hil.runtime.pipeline import nav_config

    cfg = nav_config({"filter": {"omega_rv_terms": True}})
    assert cfg.filter.omega_rv_terms is True
