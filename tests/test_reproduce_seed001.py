"""Seed 001 cases 001-C (series gravity), 001-H (ENU / y-x-z converters), 001-J (coarse alignment eqs. 64–69)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.nav import enu
from ins_hil.nav.alignment import coarse_alignment_enu
from ins_hil.nav.rotation import euler_from_dcm
from ins_hil.reproduce import seed001_frames as s1
from ins_hil.reproduce import seed001_jacobian as s1k


def test_somigliana_table_1() -> None:
    for deg, val in ((0, 9.7803253359), (45, 9.8061977693), (90, 9.8321849378)):
        assert s1.somigliana(math.radians(deg)) == pytest.approx(val, abs=1e-9)


def test_series_meets_0_1_ugal_only_with_f2_over_8() -> None:
    assert s1.max_series_deviation() < 1e-7
    assert s1.max_series_deviation(printed=True) == pytest.approx(1.38e-5, rel=0.02)
    assert s1.series_coefficients()[1] == pytest.approx(-5.8615e-6, rel=1e-4)


def test_euler_yxz_matrix_and_round_trip() -> None:
    e = s1.euler_checks(n=50)
    assert max(e.values()) < 1e-12


def test_heading_sign_and_ned_conversion() -> None:
    """ψ = +90° turns the nose West (counter-clockwise); in NED/FRD that is yaw −90°."""
    R = enu.dcm_enu_from_euler_yxz(0.0, 0.0, math.radians(90.0))
    np.testing.assert_allclose(R[:, 1], (-1.0, 0.0, 0.0), atol=1e-15)
    C = enu.dcm_ned_frd_from_enu_rfu(R)
    assert math.degrees(euler_from_dcm(C)[2]) == pytest.approx(-90.0)
    np.testing.assert_allclose(enu.dcm_enu_rfu_from_ned_frd(C), R, atol=1e-15)
    v = np.array([1.0, 2.0, 3.0])
    np.testing.assert_array_equal(enu.enu_from_ned(v), (2.0, 1.0, -3.0))
    np.testing.assert_array_equal(enu.ned_from_enu(enu.enu_from_ned(v)), v)


def test_coarse_alignment_recovers_the_attitude_with_the_specific_force_sign() -> None:
    err, orth = s1.alignment_case()
    assert err < 1e-12 and orth < 1e-12
    err_p, orth_p = s1.alignment_case(printed_sign=True)
    assert orth_p > 0.1 and err_p > 0.1


def test_coarse_alignment_refuses_at_the_pole() -> None:
    with pytest.raises(ValueError, match="latitude"):
        coarse_alignment_enu(np.array([0, 0, 9.8]), np.array([0, 0, 7e-5]), math.radians(90.0), 9.83)


def test_rows_pass() -> None:
    assert all(r.status == "pass" for r in s1.rows())


def test_error_model_F_matches_finite_differences() -> None:
    """001-K: the corrected F blocks agree with the numerical Jacobian of eq. (59); the printed F31/F32 signs do not."""
    c = s1k.compare()
    assert c["worst"] < 1e-5
    assert c["printed_att"] > 0.5
    assert c["f21_33"] == pytest.approx(c["f21_33_ref"], rel=0.01)


def test_F_detects_a_wrong_entry() -> None:
    Fa, Fn = s1k.analytic_F(), s1k.numerical_F()
    Fa[1, 0] *= -1.0  # F11(2,1) = λ̇ tan φ with the wrong sign
    assert abs(Fa[1, 0] - Fn[1, 0]) > 0.5 * abs(Fn[1, 0])


def test_earth_rows_check_the_core_earth_model() -> None:
    rows = [r for r in s1.rows() if r.group.startswith("001-A/B/D/E ")]
    assert len(rows) == 11  # 001-A (2), 001-B (7), 001-D, 001-E
    assert all(r.status == "pass" for r in rows)


def test_attitude_update_and_kalman_forms() -> None:
    """001-I and 001-L."""
    assert s1.attitude_update_error() < 1e-12
    assert s1.kalman_forms_error() < 1e-10


def test_a_broken_schuler_loop_is_a_reported_failure_not_a_crash(monkeypatch) -> None:
    """No zero crossings (e.g. the transport-rate sign flipped): the period rows fail with NaN instead of raising."""
    import ins_hil.reproduce.seed001 as s1m

    orig = s1m.schuler_run

    def flat():
        r = orig()
        return s1m.SchulerRun(r.t, np.abs(r.dv_north) + 1.0, r.dr_north, r.period_theory)

    s1m.rows.cache_clear()
    monkeypatch.setattr(s1m, "schuler_run", flat)
    try:
        rows = s1m.rows()
        assert [r.status for r in rows[:2]] == ["fail", "fail"]
    finally:
        s1m.rows.cache_clear()
