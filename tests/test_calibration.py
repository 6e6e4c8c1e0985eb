"""Book §4.2 calibration: Table 4.1, the Table 4.2 decomposition, LS-by-QR, and recovery of simulated errors.

Tolerances (issue 9): scale factors to 1e-4, misalignment to 0.01°, biases to 1 % of their size
at the simulated noise level (mems_accel / mems_gyro white noise and bias instability).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.nav import calibration as cal
from ins_hil.sim import calibration as simcal
from ins_hil.sim.sensors import mems_accel, mems_gyro
from ins_hil.types import ImuFlags

R2 = math.sqrt(2.0) / 2.0
MIS_TOL = math.radians(0.01)


# --- book reference cases (DIGEST_000 §8 cases 18, 19) ---------------------------------------


def test_table_4_1_reference_rates() -> None:
    # case 18: C_x(φ1) C_y(φ2) [0 0 1]^T reproduces every row of Table 4.1 exactly
    printed = np.array(
        [[0, 0, 1], [R2, 0, R2], [-R2, 0, R2], [-1, 0, 0], [0, -R2, R2], [0, R2, R2], [0, 1, 0]], dtype=float
    )
    np.testing.assert_allclose(cal.table_4_1(1.0), printed, atol=1e-15)
    # ±ω_ref: gyro_references lists +ω then −ω at each position (N = 14 experiments per rate)
    refs = cal.gyro_references(cal.TABLE_4_1_TILTS, [2.0])
    assert refs.shape == (14, 3)
    np.testing.assert_allclose(refs[0::2], 2.0 * printed, atol=1e-15)
    np.testing.assert_allclose(refs[1::2], -2.0 * printed, atol=1e-15)


def test_table_4_2_decomposition() -> None:
    # case 19: A = diag(S) A_α from Table 4.2, split by eqs. 4.18–4.21, tolerance 1.5e-4
    a_alpha = np.array([[1.0, -0.0062, 0.0160], [0.0063, 1.0, 0.0118], [-0.0171, -0.0071, 1.0]])
    s = np.array([1.0015, 1.0007, 1.0003])
    d = cal.decompose(np.diag(s) @ a_alpha)
    # book prints 0.0010 at (2,1) of I + εB_sym: a typo (the matrix must be symmetric); tested corrected
    sym_expected = np.array([[1.0015, 0.0001, -0.0005], [0.0001, 1.0007, 0.0023], [-0.0005, 0.0023, 1.0003]])
    skew_expected = np.array([[1.0, -0.0063, 0.0165], [0.0063, 1.0, 0.0095], [-0.0165, -0.0095, 1.0]])
    np.testing.assert_allclose(d.sym, sym_expected, atol=1.5e-4)
    np.testing.assert_allclose(d.skew, skew_expected, atol=1.5e-4)
    assert abs(d.sym[1, 0] - 0.0010) > 5e-4  # the printed value is not reproducible
    np.testing.assert_allclose(d.scale, s, atol=1e-12)
    np.testing.assert_allclose(d.misalignment, a_alpha, atol=1e-12)  # A_ε = S⁻¹A (eq. 4.13 split)
    # eq. 4.21: μ1 = K[1,2], μ2 = K[2,0], μ3 = K[0,1]
    np.testing.assert_allclose(d.mu, [0.0095, -0.0165, -0.0063], atol=1.5e-4)
    # eq. 4.20: I + εB ≈ (I + εB_sym)(I + εB_skew) ≈ (I + εB_skew)(I + εB_sym) to O(ε²)
    a = np.diag(s) @ a_alpha
    np.testing.assert_allclose(d.sym @ d.skew, a, atol=5e-4)
    np.testing.assert_allclose(d.skew @ d.sym, a, atol=5e-4)


def test_book_accel_positions_match_book_a_ix() -> None:
    # §4.2.1: a_ix = C_ix g_ref = [0, 9.81 sinφ, 9.81 cosφ], a_iy = [−9.81 sinφ, 0, 9.81 cosφ];
    # body FRD specific force is the negative (g_ref points along the sensor's up axis in the book)
    refs = cal.accel_references(cal.BOOK_ACCEL_POSITIONS, 9.81)
    phi = np.arange(1, 9) * math.pi / 4
    ax = np.column_stack([np.zeros(8), 9.81 * np.sin(phi), 9.81 * np.cos(phi)])
    ay = np.column_stack([-9.81 * np.sin(phi), np.zeros(8), 9.81 * np.cos(phi)])
    np.testing.assert_allclose(refs, -np.vstack([ax, ay]), atol=1e-12)
    assert cal.design_matrix(refs).shape == (48, 12)  # 16 positions, 48 equations (eq. 4.12)


def test_qr_solution_matches_normal_equations_and_cond() -> None:
    rng = np.random.default_rng(4)
    refs = cal.accel_references(cal.BOOK_ACCEL_POSITIONS)
    a_sig = cal.design_matrix(refs)
    x_true = np.concatenate([(np.eye(3) + 0.01 * rng.standard_normal((3, 3))).ravel(), [0.1, -0.2, 0.3]])
    b_exact = a_sig @ x_true
    exact = cal.solve_qr(a_sig, b_exact)
    np.testing.assert_allclose(exact.x, x_true, atol=1e-12)
    assert exact.dev_percent < 1e-10  # eq. 4.17: consistent data → 0 %
    b = b_exact + 0.01 * rng.standard_normal(len(b_exact))
    res = cal.solve_qr(a_sig, b)
    x_ne = np.linalg.solve(a_sig.T @ a_sig, a_sig.T @ b)  # eq. 4.13
    np.testing.assert_allclose(res.x, x_ne, atol=1e-10)
    assert res.cond == pytest.approx(math.sqrt(np.linalg.cond(a_sig.T @ a_sig)), rel=1e-8)  # eq. 4.16
    # dev = ‖z2‖/‖z1‖: z2 is the LS residual, z1 the projected data
    r = b - a_sig @ res.x
    assert res.dev_percent == pytest.approx(100 * np.linalg.norm(r) / np.linalg.norm(a_sig @ res.x), rel=1e-9)


# --- simulated runs ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def accel_run() -> simcal.CalibrationRun:
    rng = np.random.default_rng(11)
    acc = mems_accel(rng)
    acc.bias = np.array([0.20, -0.15, 0.25])  # 15–25 mg, the size of mems_accel's 20 mg turn-on bias
    return simcal.accel_static_run(mems_gyro(rng), acc, dt=0.02, step_time=20.0, seed=3)


@pytest.fixture(scope="module")
def gyro_run() -> simcal.CalibrationRun:
    rng = np.random.default_rng(12)
    gy = mems_gyro(rng)
    gy.bias = np.radians([0.2, -0.25, 0.3])  # the size of mems_gyro's 0.2 °/s turn-on bias
    # 30 and 90 °/s with 12 s steps: whole revolutions, so the horizontal Earth rate averages out
    rates = (math.radians(30.0), math.radians(90.0))
    return simcal.rate_table_run(gy, mems_accel(rng), rates=rates, step_time=12.0, dt=0.02, seed=4)


def _check_recovery(fit: cal.TriadFit, true_m: np.ndarray, true_bias: np.ndarray) -> None:
    s_true = np.diag(true_m)
    np.testing.assert_allclose(np.diag(fit.matrix), s_true, atol=1e-4)  # scale factors to 1e-4
    mis_fit = fit.decomposition.misalignment - np.eye(3)
    mis_true = true_m / s_true[:, None] - np.eye(3)
    assert np.abs(mis_fit - mis_true).max() < MIS_TOL  # misalignment to 0.01°
    assert np.all(np.abs(fit.bias - true_bias) < 0.01 * np.abs(true_bias))  # biases to 1 %


def _mean_true_bias(run: simcal.CalibrationRun, which: str) -> np.ndarray:
    # the bias the sensor had during the steps: turn-on bias + mean Gauss–Markov drift (bias instability)
    b = run.imu.accel_bias if which == "accel" else run.imu.gyro_bias
    return b[run.labels >= 0].mean(axis=0)


def test_accel_multi_position_recovers_errors(accel_run: simcal.CalibrationRun) -> None:
    m = accel_run.accel_model
    fit = cal.calibrate_accel(accel_run.accel, accel_run.labels, accel_run.references)
    assert fit.n_equations == 48
    _check_recovery(fit, m.matrix(), _mean_true_bias(accel_run, "accel"))
    assert fit.dev_percent < 0.1


def test_gyro_rate_table_recovers_errors(gyro_run: simcal.CalibrationRun) -> None:
    m = gyro_run.gyro_model
    fit = cal.calibrate_gyro(gyro_run.gyro, gyro_run.labels, gyro_run.references)
    assert fit.n_equations == 84  # 2 rates × 7 positions × ±ω × 3 axes, as the book's 84
    _check_recovery(fit, m.matrix(), _mean_true_bias(gyro_run, "gyro"))
    assert fit.dev_percent < 0.1
    # without the vertical Earth rate in the references the bias estimate is visibly worse
    refs_no_earth = cal.gyro_references(cal.TABLE_4_1_TILTS, (math.radians(30.0), math.radians(90.0)))
    fit2 = cal.calibrate_gyro(gyro_run.gyro, gyro_run.labels, refs_no_earth)
    tb = _mean_true_bias(gyro_run, "gyro")
    assert np.abs(fit2.bias - tb).max() > 3 * np.abs(fit.bias - tb).max()


def test_detected_steps_give_the_same_calibration(accel_run: simcal.CalibrationRun) -> None:
    labels = cal.detect_steps(accel_run.accel, accel_run.imu.dt, window=1.0, max_std=0.05, min_duration=5.0)
    assert labels.max() + 1 == 16
    # every detected sample lies inside the true step of the same index
    sel = labels >= 0
    assert np.all(accel_run.labels[sel] == labels[sel])
    fit = cal.calibrate_accel(accel_run.accel, labels, accel_run.references)
    _check_recovery(fit, accel_run.accel_model.matrix(), _mean_true_bias(accel_run, "accel"))


# --- bad or insufficient data --------------------------------------------------------------------


def test_too_few_positions(accel_run: simcal.CalibrationRun) -> None:
    labels = np.where(accel_run.labels < 3, accel_run.labels, -1)
    with pytest.raises(cal.CalibrationError, match="at least 4 positions"):
        cal.calibrate_accel(accel_run.accel, labels, accel_run.references[:3])


def test_positions_in_one_plane(accel_run: simcal.CalibrationRun) -> None:
    labels = np.where(accel_run.labels < 8, accel_run.labels, -1)  # rotations about X only
    with pytest.raises(cal.CalibrationError, match="both X and Y"):
        cal.calibrate_accel(accel_run.accel, labels, accel_run.references[:8])


def test_missing_step(accel_run: simcal.CalibrationRun) -> None:
    labels = np.where(accel_run.labels == 15, -1, accel_run.labels)
    with pytest.raises(cal.CalibrationError, match="15 steps but the plan has 16"):
        cal.calibrate_accel(accel_run.accel, labels, accel_run.references)


def test_motion_during_a_static_step(accel_run: simcal.CalibrationRun) -> None:
    acc = accel_run.accel.copy()
    idx = np.flatnonzero(accel_run.labels == 5)
    # a slow 1° tilt during step 5: small std, but the mean moves between the halves
    ang = np.linspace(0.0, math.radians(1.0), len(idx))
    g = np.linalg.norm(accel_run.references[5])
    acc[idx, 0] += g * np.sin(ang)
    with pytest.raises(cal.CalibrationError, match=r"step 5: the mean moved"):
        cal.calibrate_accel(acc, accel_run.labels, accel_run.references)
    # a shake (vibration) during step 7
    acc = accel_run.accel.copy()
    idx = np.flatnonzero(accel_run.labels == 7)
    acc[idx, 2] += 0.5 * np.sin(np.arange(len(idx)))
    with pytest.raises(cal.CalibrationError, match=r"step 7: motion during the step"):
        cal.calibrate_accel(acc, accel_run.labels, accel_run.references)


def test_saturated_samples(accel_run: simcal.CalibrationRun) -> None:
    flags = np.zeros(len(accel_run.labels), dtype=np.int64)
    flags[np.flatnonzero(accel_run.labels == 2)[10:13]] = int(ImuFlags.ACCEL_SATURATED)
    with pytest.raises(cal.CalibrationError, match=r"step 2: 3 of \d+ samples flagged saturated"):
        cal.calibrate_accel(accel_run.accel, accel_run.labels, accel_run.references, flags=flags)
    # by value: a range that the 1 g steps reach
    lim = cal.StepLimits(max_std=0.1, max_drift=0.01, saturation=9.0)
    with pytest.raises(cal.CalibrationError, match="beyond the range"):
        cal.calibrate_accel(accel_run.accel, accel_run.labels, accel_run.references, limits=lim)


def test_wrong_reference_rates_are_refused(gyro_run: simcal.CalibrationRun) -> None:
    # the book's 3/9 °/s plan applied to a 30/90 °/s log: scale factors ≈ 10 must not be written
    refs = cal.gyro_references(cal.TABLE_4_1_TILTS, (math.radians(3.0), math.radians(9.0)), gyro_run.lat)
    with pytest.raises(cal.CalibrationError, match="implausible"):
        cal.calibrate_gyro(gyro_run.gyro, gyro_run.labels, refs)
    # two positions recorded in the other order: dev far above the book's worst 4 %
    refs = cal.gyro_references(cal.TABLE_4_1_TILTS, (math.radians(30.0), math.radians(90.0)), gyro_run.lat)
    refs[[2, 3, 4, 5]] = refs[[4, 5, 2, 3]]
    with pytest.raises(cal.CalibrationError, match="do not match the plan"):
        cal.calibrate_gyro(gyro_run.gyro, gyro_run.labels, refs)


# --- magnetometer ---------------------------------------------------------------------------------


def test_mag_ellipsoid_fit_recovers_hard_and_soft_iron() -> None:
    hi = np.array([20e-6, -12e-6, 7e-6])
    si = np.array([[1.08, 0.04, -0.02], [0.04, 0.95, 0.03], [-0.02, 0.03, 1.02]])  # symmetric
    _, m = simcal.mag_rotation_run(duration=60.0, rate=20.0, hard_iron=hi, soft_iron=si, std=0.1e-6)
    fit = cal.fit_ellipsoid(m, field_norm=50e-6)
    np.testing.assert_allclose(fit.bias, hi, atol=0.05e-6)  # 50 nT (noise 100 nT per sample)
    np.testing.assert_allclose(fit.matrix, si, atol=2e-3)
    assert fit.residual_rms < 0.15e-6
    # the correction makes |x| constant
    x = cal.TriadCalibration(fit.matrix, fit.bias).correct(m)
    assert np.std(np.linalg.norm(x, axis=1)) < 0.15e-6 < np.std(np.linalg.norm(m, axis=1))


def test_mag_rotation_about_one_axis_is_refused() -> None:
    _, m = simcal.mag_rotation_run(duration=30.0, rate=20.0, hard_iron=np.array([1e-5, 0, 0]), full_sphere=False)
    with pytest.raises(cal.CalibrationError, match="rotate"):
        cal.fit_ellipsoid(m)
    with pytest.raises(cal.CalibrationError, match="at least 30"):
        cal.fit_ellipsoid(m[:10])
