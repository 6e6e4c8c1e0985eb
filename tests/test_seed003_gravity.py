"""J2 gravity as a selectable gravity model of the navigation (seed 003 eq. 1.9; issue 43)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.core import NavConfig, NavCore
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownNED, StrapdownState
from ins_hil.reproduce import seed003


def _potential_gradient_ned(lat: float, h: float) -> np.ndarray:
    """Independent formulation: −∇ of the J2 potential U = GM/r (1 − J2 (a/r)² P₂(z/r)) + ½ω²(x² + y²) by central
    differences in ECEF (numpy only), as an acceleration in NED at longitude 0."""

    def U(p: np.ndarray) -> float:
        r = float(np.linalg.norm(p))
        p2 = 0.5 * (3.0 * (p[2] / r) ** 2 - 1.0)
        return earth.GM_WGS84 / r * (1.0 - earth.J2_WGS84 * (earth.A_WGS84 / r) ** 2 * p2) + 0.5 * earth.OMEGA_E**2 * (
            p[0] ** 2 + p[1] ** 2
        )

    p = earth.geodetic_to_ecef(lat, 0.0, h)
    step = 1.0
    grad = np.array([(U(p + step * e) - U(p - step * e)) / (2 * step) for e in np.eye(3)])
    return earth.dcm_ecef_to_ned(lat, 0.0) @ grad  # g = +∇U (U is the potential with GM/r > 0)


@pytest.mark.parametrize("lat_deg", [0.0, 20.0, 45.0, 70.0, 89.0])
@pytest.mark.parametrize("h", [0.0, 3000.0, 100_000.0])
def test_j2_gravity_is_the_gradient_of_the_j2_potential(lat_deg: float, h: float) -> None:
    lat = math.radians(lat_deg)
    np.testing.assert_allclose(earth.gravity_j2_ned(lat, h), _potential_gradient_ned(lat, h), atol=2e-8)


def test_j2_gravity_against_the_seeds_numbers() -> None:
    """Seed 003 eq. 1.9 with μ = J2: 9.78028 m/s² at the equator (after ω²a) and 9.83207 at the pole (digest);
    our vector model agrees with the seed's radial formula to the rounding of J2 (1.0826e-3 in the seed)."""
    eq, pole = earth.gravity_j2_ned(0.0, 0.0), earth.gravity_j2_ned(math.pi / 2, 0.0)
    assert eq[2] == pytest.approx(9.78028, abs=2e-5) and pole[2] == pytest.approx(9.83207, abs=2e-5)
    s_eq, s_pole = seed003.j2_gravity(seed003.J2)
    assert abs(eq[2] - s_eq) < 1e-6 and abs(pole[2] - s_pole) < 1e-6
    assert abs(eq[0]) < 1e-12 and abs(pole[0]) < 1e-12  # no north component on the equator or at the pole
    # against Somigliana normal gravity (the default model): within the truncated J4… terms at the surface
    for lat in np.radians(np.arange(0.0, 91.0, 5.0)):
        assert abs(earth.gravity_j2_ned(lat, 0.0)[2] - earth.normal_gravity(lat)) < 1.5e-4
        assert abs(earth.gravity_j2_ned(lat, 0.0)[0]) < 1e-4


def _rest_run(gravity: str | None, lat: float = math.radians(45.0), steps: int = 1000) -> np.ndarray:
    """A level IMU at rest (specific force −g of the normal model) for ``steps`` × 10 ms: the final velocity."""
    g = earth.normal_gravity(lat, 100.0)
    st = StrapdownState(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), lat, 0.0, 100.0)
    kw = {} if gravity is None else {"gravity": gravity}
    ins = StrapdownNED(st, earth_rate=False, **kw)
    for _ in range(steps):
        ins.step(np.zeros(3), np.array([0.0, 0.0, -g * 0.01]), 0.01)
    return ins.state.vel_ned.copy()


def test_strapdown_gravity_option() -> None:
    """Default unchanged bit for bit; 'j2' adds the model difference Δg·t (north and down)."""
    default = _rest_run(None)
    assert np.array_equal(default, _rest_run("normal"))
    assert np.max(np.abs(default)) < 1e-6  # at rest, the default model balances the specific force
    lat = math.radians(45.0)
    dg = earth.gravity_j2_ned(lat, 100.0) - earth.gravity_ned(lat, 100.0)
    np.testing.assert_allclose(_rest_run("j2") - default, dg * 10.0, atol=2e-6)
    assert abs(dg[0]) > 1e-5 and abs(dg[2]) > 1e-5  # the option changes the navigation
    with pytest.raises(ValueError, match=r"gravity='egm'"):
        StrapdownNED(StrapdownState(np.array([1.0, 0, 0, 0]), np.zeros(3), 0.0, 0.0, 0.0), gravity="egm")


def test_navconfig_gravity_selects_the_model() -> None:
    assert NavConfig().gravity == "normal"
    init = StrapdownState(np.array([1.0, 0, 0, 0]), np.zeros(3), 0.5, 0.1, 10.0)
    assert NavCore(init).ins.gravity == "normal"
    assert NavCore(init, NavConfig(gravity="j2")).ins.gravity == "j2"
    with pytest.raises(ValueError, match=r"NavConfig\.gravity='J2'"):
        NavConfig(gravity="J2")
