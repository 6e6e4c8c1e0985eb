"""WGS84 model against the values derived in DIGEST_001_004 §1.2–1.3 (seed 001)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.nav import earth


def test_ellipsoid_constants() -> None:
    assert earth.B_WGS84 == pytest.approx(6_356_752.3142, abs=1e-4)
    assert earth.E2_WGS84 == pytest.approx(0.006694379990141, rel=1e-12)
    assert earth.K_SOMIGLIANA == pytest.approx(1.931852646e-3, rel=1e-8)


def test_radii_at_45() -> None:
    m, n = earth.radii(math.radians(45.0))
    assert n == pytest.approx(6_388_838.2901, abs=1e-3)
    assert m == pytest.approx(6_367_381.8156, abs=1e-3)


@pytest.mark.parametrize(
    "lat_deg, gamma",
    [
        (0, 9.7803253359),
        (15, 9.7837849623),
        (30, 9.7932472692),
        (45, 9.8061977693),
        (60, 9.8191769531),
        (75, 9.8286966274),
        (90, 9.8321849378),
    ],
)
def test_somigliana(lat_deg: float, gamma: float) -> None:
    assert earth.normal_gravity(math.radians(lat_deg)) == pytest.approx(gamma, abs=1e-9)


def test_gravity_with_height() -> None:
    assert earth.normal_gravity(math.radians(45), 1000.0) == pytest.approx(9.80311299, abs=1e-8)


def test_ecef_round_trip_and_ned() -> None:
    lat, lon, h = math.radians(40.0966), math.radians(-105.1474), 1601.0
    r = earth.geodetic_to_ecef(lat, lon, h)
    la, lo, hh = earth.ecef_to_geodetic(r)
    assert la == pytest.approx(lat, abs=1e-12) and lo == pytest.approx(lon, abs=1e-12)
    assert hh == pytest.approx(h, abs=1e-6)
    ned = np.array([120.0, -45.0, 10.0])
    p = earth.geodetic_from_ned(ned, lat, lon, h)
    np.testing.assert_allclose(earth.ned_from_geodetic(*p, lat, lon, h), ned, atol=1e-6)
    # small-difference linearisation agrees to the curvature term
    d = earth.ned_delta_small(p[0] - lat, p[1] - lon, p[2] - h, lat, h)
    np.testing.assert_allclose(d, ned, atol=0.01)


def test_earth_and_transport_rate() -> None:
    lat = math.radians(50)
    w = earth.earth_rate_ned(lat)
    assert np.linalg.norm(w) == pytest.approx(earth.OMEGA_E)
    assert w[2] < 0  # northern hemisphere: Earth rate points up
    m, _n = earth.radii(lat)
    t = earth.transport_rate_ned(lat, 0.0, np.array([10.0, 0.0, 0.0]))
    assert t[1] == pytest.approx(-10.0 / m)
