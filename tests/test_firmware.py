"""The C reference core (firmware_ref/, via the cffi extension) held against the Python.

* mechanization: the same 10-minute simulated flight (UAV profile, MEMS errors) through
  ``NavCore`` and ``CNavCore`` (double) agrees to ≤ 1e-9 relative (it is in fact bit-identical:
  same formulas, same order, same libm);
* float build: its divergence from the double build is bounded (free-inertial and with GNSS);
* the C EKF against a dense numpy evaluation of the equations it documents (Φ = I + FΔt,
  ΦPΦᵀ + Q, Joseph scalar updates, feedback), and its closed-loop accuracy with GNSS;
* the book's attitude update (eqs. 2.18/2.19), the offline parity projector and the
  bench log tool on serial frames.
"""

from __future__ import annotations

import importlib.util
import math
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from ins_hil.drivers.serial_frame import encode

from ins_hil.core import NavConfig, NavCore
from ins_hil.cref import RUN_COLUMNS, CNavCore, make_core
from ins_hil.fusion.ekf import FilterConfig
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownNED, StrapdownState
from ins_hil.nav.rotation import quat_angle_between, quat_mul, quat_normalize
from ins_hil.sim.sensors import GnssModel, corrupt_imu, gnss_fixes, mems_accel, mems_gyro
from ins_hil.sim.trajectory import TruthSeries, generate, uav_profile
from ins_hil.types import GnssFix, ImuSample, NavState

REPO = Path(__file__).resolve().parent.parent
LAT0, LON0, H0 = math.radians(50.45), math.radians(30.52), 180.0
DT = 0.02  # 50 Hz (keeps the 10-minute runs inside the test budget)


class Flight:
    def __init__(self, duration: float) -> None:
        self.truth: TruthSeries = generate(uav_profile(), duration, DT, LAT0, LON0, H0)
        rng = np.random.default_rng(3)
        self.imu = corrupt_imu(self.truth, mems_gyro(rng), mems_accel(rng), seed=4)
        self.fixes = gnss_fixes(self.truth, GnssModel(rate=5.0), seed=5)
        tr = self.truth
        self.init = StrapdownState(tr.q_nb[0].copy(), tr.vel_ned[0].copy(), LAT0, LON0, H0, tr.t[0])

    def sample(self, k: int) -> ImuSample:
        return ImuSample(t=float(self.imu.t[k]), dt=DT, dtheta=self.imu.dtheta[k], dvel=self.imu.dvel[k])


@pytest.fixture(scope="module")
def flight10() -> Flight:
    return Flight(600.0)


def _run_with_gnss(core: CNavCore, fl: Flight, every: int = 100) -> np.ndarray:
    """Run the C core with GNSS fused at its epochs; states every ``every`` steps."""
    out = []
    fi = 0
    n = len(fl.imu.t)
    k = 0
    while k < n:
        while fi < len(fl.fixes) and fl.fixes[fi].t <= fl.imu.t[k] - DT + 1e-9:
            core.fuse(fl.fixes[fi])
            fi += 1
        # next GNSS epoch: run the IMU steps up to it in one C call
        k_end = n
        if fi < len(fl.fixes):
            k_end = min(n, max(k + 1, round((fl.fixes[fi].t - fl.imu.t[0]) / DT) + 1))
        rows = core.run(fl.imu.dtheta[k:k_end], fl.imu.dvel[k:k_end], fl.imu.t[k:k_end])
        idx = np.arange(k, k_end)
        out.append(np.hstack((idx[:, None], rows))[(idx + 1) % every == 0])
        k = k_end
    return np.vstack(out)


def test_double_core_matches_python_mechanization_10min(flight10: Flight) -> None:
    """Free-inertial: StrapdownNED and the C mechanization (double) on the same 10-min stream, ≤ 1e-9 relative.

    (In fact bit-identical: same formulas in the same order, same libm.)"""
    ins = StrapdownNED(flight10.init.copy())
    c = make_core("c", flight10.init, filter=False)
    worst = np.zeros(4)
    for k in range(len(flight10.imu.t)):
        s = flight10.sample(k)
        a = ins.step(s.dtheta, s.dvel, s.dt)
        a.t = s.t
        b = c.step(s)
        if k % 50 == 49:
            worst = np.maximum(
                worst,
                [
                    float(np.max(np.abs(a.q_nb - b.q_nb))),  # unit quaternion: absolute = relative
                    float(np.max(np.abs(a.vel_ned - b.vel_ned)) / max(1.0, float(np.max(np.abs(a.vel_ned))))),
                    max(abs(a.lat - b.lat) / abs(a.lat), abs(a.lon - b.lon) / abs(a.lon)),
                    abs(a.h - b.h) / max(1.0, abs(a.h)),
                ],
            )
    assert b.t == a.t
    # the free-inertial MEMS solution has drifted far by now: the comparison is not trivial
    assert np.linalg.norm(a.vel_ned - flight10.truth.vel_ned[-1]) > 10.0
    assert np.all(worst <= 1e-9), worst


def test_one_call_run_equals_step_by_step(flight10: Flight) -> None:
    a = CNavCore(flight10.init, dt=DT)
    b = CNavCore(flight10.init, dt=DT)
    n = 3000
    rows = a.run(flight10.imu.dtheta[:n], flight10.imu.dvel[:n], flight10.imu.t[:n])
    assert rows.shape == (n, len(RUN_COLUMNS))
    for k in range(n):
        st = b.step(flight10.sample(k))
    np.testing.assert_array_equal(rows[-1, 1:5], st.q_nb)
    np.testing.assert_array_equal(rows[-1, 5:8], st.vel_ned)
    assert (rows[-1, 8], rows[-1, 9], rows[-1, 10], rows[-1, 0]) == (st.lat, st.lon, st.h, st.t)


def _divergence(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """max over rows of (attitude angle rad, |Δv| m/s, |Δpos| m) between two run outputs (+index col)."""
    worst = np.zeros(3)
    for ra, rb in zip(a[:, 1:], b[:, 1:]):
        att = quat_angle_between(ra[1:5], rb[1:5])
        vel = float(np.linalg.norm(ra[5:8] - rb[5:8]))
        pos = float(np.linalg.norm(earth.ned_delta_small(rb[8] - ra[8], rb[9] - ra[9], rb[10] - ra[10], ra[8], ra[10])))
        worst = np.maximum(worst, [att, vel, pos])
    return worst


def test_float_build_divergence_is_bounded(flight10: Flight) -> None:
    """Single precision against double on the same 10-min input (50 Hz).

    Measured (this seeded run): free-inertial 8.7e-5 rad / 0.24 m/s / 23 m (float rounding of
    the attitude and velocity integration, amplified by the free-inertial error dynamics);
    with GNSS at 5 Hz 4.8e-5 rad / 1.3e-4 m/s / 1.2e-4 m. The bounds are ~3x those figures.
    """
    fl = flight10
    free_d = CNavCore(fl.init, dt=DT, filter=False).run(fl.imu.dtheta, fl.imu.dvel, fl.imu.t)
    free_f = CNavCore(fl.init, dt=DT, precision="float", filter=False).run(fl.imu.dtheta, fl.imu.dvel, fl.imu.t)
    idx = np.arange(len(free_d))[:, None]
    sel = slice(99, None, 100)
    free = _divergence(np.hstack((idx, free_d))[sel], np.hstack((idx, free_f))[sel])
    assert free[0] > 0.0  # the float build really is float
    assert free[0] < 3e-4 and free[1] < 0.75 and free[2] < 75.0, free
    aided = _divergence(
        _run_with_gnss(CNavCore(fl.init, dt=DT), fl), _run_with_gnss(CNavCore(fl.init, dt=DT, precision="float"), fl)
    )
    assert aided[0] < 1.5e-4 and aided[1] < 5e-4 and aided[2] < 5e-4, aided


def test_c_filter_with_gnss_tracks_the_truth(flight10: Flight) -> None:
    """Closed loop: MEMS IMU + 5 Hz GNSS (1 m / 2 m / 0.1 m/s) over 10 min stays near the truth."""
    fl = flight10
    rows = _run_with_gnss(CNavCore(fl.init, dt=DT), fl)
    tr = fl.truth
    pos = []
    vel = []
    att = []
    for r in rows:
        k = int(r[0]) + 1
        pos.append(np.linalg.norm(earth.ned_from_geodetic(r[9], r[10], r[11], tr.lat[k], tr.lon[k], tr.h[k])))
        vel.append(np.linalg.norm(r[6:9] - tr.vel_ned[k]))
        att.append(quat_angle_between(r[2:6], tr.q_nb[k]))
    late = len(rows) // 4  # after the first 150 s
    assert np.sqrt(np.mean(np.square(pos[late:]))) < 1.0
    assert max(pos[late:]) < 3.0
    assert max(vel[late:]) < 0.2
    assert math.degrees(max(att[late:])) < 1.0


def _sd(st: NavState) -> np.ndarray:
    return np.r_[st.std_pos, st.std_vel, st.std_att]


@pytest.mark.slow
def test_c_filter_matches_python_navcore_with_gnss_and_baro_10min(flight10: Flight) -> None:
    """NavCore (ins_hil.fusion EKF) and CNavCore on the same IMU + 5 Hz GNSS + 10 Hz baro stream.

    Both start from the truth with the MEMS IMU errors unknown to the filter; measurements are
    fed at their step. Attitude, velocity, position agree to ≤ 1e-9 relative, and so do the
    estimated biases and the covariance (σ) to ≤ 1e-6 relative.
    """
    from ins_hil.sim.sensors import baro_samples

    fl = flight10
    baro = baro_samples(fl.truth, rate=10.0, std=0.5, seed=6)
    meas = sorted([*fl.fixes, *baro], key=lambda m: m.t)
    py = NavCore(fl.init)
    c = CNavCore(fl.init, dt=DT)
    worst = np.zeros(6)
    j = 0
    n_fused = 0
    for k in range(len(fl.imu.t)):
        s = fl.sample(k)
        a = py.step(s)
        b = c.step(s)
        while j < len(meas) and meas[j].t <= s.t + 1e-9:
            py.fuse(meas[j])
            c.fuse(meas[j])
            j += 1
            n_fused += 1
        if k % 50 == 49:
            a = py.state()
            b = c.state()
            worst = np.maximum(
                worst,
                [
                    float(np.max(np.abs(a.q_nb - b.q_nb))),
                    float(np.max(np.abs(a.vel_ned - b.vel_ned)) / max(1.0, float(np.max(np.abs(a.vel_ned))))),
                    max(abs(a.lat - b.lat) / abs(a.lat), abs(a.lon - b.lon) / abs(a.lon)),
                    abs(a.h - b.h) / max(1.0, abs(a.h)),
                    float(np.max(np.abs(a.gyro_bias - b.gyro_bias) / np.maximum(1e-6, np.abs(a.gyro_bias)))),
                    float(
                        np.max(
                            np.abs(np.r_[a.std_pos, a.std_vel, a.std_att] / np.r_[b.std_pos, b.std_vel, b.std_att] - 1)
                        )
                    ),
                ],
            )
    assert n_fused > 8000
    np.testing.assert_allclose(b.omega_b, a.omega_b, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(b.accel_b, a.accel_b, rtol=1e-9, atol=1e-12)
    assert set(b.test_ratios) == {"gnss_pos", "gnss_vel", "baro"}
    assert b.aligned == a.aligned
    e = c._core.ekf
    assert [py.stats[k].accepted for k in ("gnss_pos", "gnss_vel", "baro")] == [int(e.accepted[i]) for i in range(3)]
    assert [py.stats[k].rejected for k in ("gnss_pos", "gnss_vel", "baro")] == [int(e.rejected[i]) for i in range(3)]
    # the filter really works on this run (else agreement would be cheap): near the truth at the end
    dp = earth.ned_from_geodetic(b.lat, b.lon, b.h, fl.truth.lat[-1], fl.truth.lon[-1], fl.truth.h[-1])
    assert np.linalg.norm(dp) < 3.0
    assert np.all(worst[:4] <= 1e-9), worst
    assert np.all(worst[4:] <= 1e-6), worst
    np.testing.assert_allclose(c.covariance(), py.kf.P, rtol=1e-6, atol=1e-12 * float(np.max(py.kf.P)))


def test_book_attitude_update_eq_2_18_2_19() -> None:
    """The C eq. 2.18/2.19 update against a numpy evaluation with rotation.quat_mul."""
    from ins_hil._cref import ffi, lib  # type: ignore[attr-defined]

    rng = np.random.default_rng(7)
    dt = 0.01
    w = rng.normal(0, 1.0, (200, 3))
    q0 = quat_normalize(np.array([0.9, 0.1, -0.2, 0.3]))
    a = ffi.new("ins_book_att_t *")
    lib.ins_book_att_init(a, ffi.new("double[4]", list(q0)), dt)
    lam = q0.copy()
    th_prev = np.zeros(3)
    growth = 0.0
    for i in range(len(w)):
        lib.ins_book_att_step(a, ffi.new("double[3]", list(w[i])))
        if i == 0:
            th = dt * w[0]
        elif i == 1:
            th = 0.5 * dt * (w[1] + w[0])
        else:
            th = dt / 12.0 * (5 * w[i] + 8 * w[i - 1] - w[i - 2])  # book eq. 2.19
        d = np.array([1 - th @ th / 12.0, *(0.5 * th - np.cross(th, th_prev) / 24.0)])  # book eq. 2.18
        lam = quat_mul(lam, d)  # book eq. 2.15
        th_prev = th
        growth += th @ th / 24.0  # |δλ| = 1 + |θ|²/24 + O(θ⁴) for the 1/12 form
    np.testing.assert_allclose([a.lam[i] for i in range(4)], lam, rtol=0, atol=1e-13)
    # the 1/12 quaternion is not unit norm (DIGEST_000 §2.2): its norm grows by Σ|θ|²/24
    assert abs((np.linalg.norm(lam) - 1.0) / growth - 1.0) < 0.01


def test_parity_projector_and_isolation() -> None:
    """The offline U2ᵀ equals numpy's SVD of the cone geometry; J(k) and ρ as book eqs. 5.16/5.17."""
    from ins_hil._cref import ffi, lib  # type: ignore[attr-defined]

    spec = importlib.util.spec_from_file_location("gen_parity", REPO / "firmware_ref" / "tools" / "gen_parity.py")
    assert spec is not None and spec.loader is not None
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    A = gen.CONE5_AT.T
    u2t = ffi.new("double[10]")
    lib.ins_fdi_cone5_u2t(u2t)
    U2T = np.array(list(u2t)).reshape(2, 5)
    np.testing.assert_allclose(U2T, gen.parity_u2t(A), rtol=0, atol=1e-15)
    np.testing.assert_allclose(U2T @ A, 0.0, atol=1e-15)
    # printed U2ᵀ of Example 5.1 (DIGEST_000 §5.2, 4 decimals, signs included)
    printed = [[-0.0752, -0.4300, -0.6205, 0.5740, 0.3082], [0.6280, 0.4638, 0.1225, 0.2656, 0.5523]]
    np.testing.assert_allclose(U2T, printed, atol=6e-5)
    rng = np.random.default_rng(11)
    res = ffi.new("ins_fdi_result_t *")
    for failed in range(5):
        y = A @ rng.normal(0, 1, 3) + rng.normal(0, 1e-3, 5)
        y[failed] += 0.5
        lib.ins_fdi_parity(u2t, ffi.new("double[5]", list(y)), 0.01, res)
        p = U2T @ y
        J = [p @ p - (U2T[:, k] @ p) ** 2 / (U2T[:, k] @ U2T[:, k]) for k in range(5)]
        np.testing.assert_allclose(list(res.J), J, atol=1e-14)
        assert res.detected == 1 and res.isolated == failed
        assert abs(res.rho[failed] - 0.5) < 0.01


def test_log_tool_reads_serial_frames(tmp_path: Path, flight10: Flight) -> None:
    """ins_ref_log over a frame log (with line noise) = CNavCore over the decoded samples."""
    subprocess.run(["make", "-s", "-C", str(REPO / "firmware_ref"), "build/double/ins_ref_log"], check=True)
    n = 2000
    fl = flight10
    blob = bytearray()
    for k in range(n):
        blob += encode(ImuSample(t=float(fl.imu.t[k]), dt=DT, dtheta=fl.imu.dtheta[k], dvel=fl.imu.dvel[k], seq=k))
        if k == 500:
            blob += b"\xa5\x5a\x01garbage"  # a false sync: skipped byte-wise
    log = tmp_path / "imu.bin"
    log.write_bytes(bytes(blob))
    rpy = np.degrees(fl.truth.euler[0])
    v0 = fl.truth.vel_ned[0]
    proc = subprocess.run(
        [
            str(REPO / "firmware_ref" / "build" / "double" / "ins_ref_log"),
            "--lat", str(math.degrees(LAT0)), "--lon", str(math.degrees(LON0)), "--h", str(H0),
            "--rpy", ",".join(f"{x:.17g}" for x in rpy), "--vel", ",".join(f"{x:.17g}" for x in v0),
            "--every", "10", str(log),
        ],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert "2000 frames used, 1 bad frames skipped" in proc.stderr
    rows = np.loadtxt(proc.stdout.splitlines(), delimiter=",", skiprows=1)
    assert rows.shape == (200, 11)
    # reference: the same float32 increments through the extension
    from ins_hil.nav.rotation import quat_from_euler

    init = StrapdownState(quat_from_euler(*np.radians(rpy)), v0.copy(), LAT0, LON0, H0, 0.0)
    ref = CNavCore(init, dt=DT, filter=False).run(
        fl.imu.dtheta[:n].astype(np.float32), fl.imu.dvel[:n].astype(np.float32), np.round(fl.imu.t[:n] * 1e6) * 1e-6
    )[9::10]
    np.testing.assert_allclose(rows[:, 0], ref[:, 0], atol=1e-9)
    np.testing.assert_allclose(rows[:, 1:8], ref[:, 1:8], rtol=0, atol=1e-12)
    np.testing.assert_allclose(rows[:, 8:10], ref[:, 8:10], rtol=0, atol=1e-15)
    np.testing.assert_allclose(rows[:, 10], ref[:, 10], rtol=0, atol=1e-8)


def test_log_tool_rejects_bad_arguments(tmp_path: Path) -> None:
    subprocess.run(["make", "-s", "-C", str(REPO / "firmware_ref"), "build/double/ins_ref_log"], check=True)
    exe = str(REPO / "firmware_ref" / "build" / "double" / "ins_ref_log")
    p = subprocess.run([exe, "--lat", "abc", "x.bin"], capture_output=True, text=True)
    assert p.returncode == 2 and "bad number: abc" in p.stderr
    p = subprocess.run([exe, "--bogus", "1", "x.bin"], capture_output=True, text=True)
    assert p.returncode == 2 and "unknown option: --bogus" in p.stderr
    p = subprocess.run([exe, str(tmp_path / "missing.bin")], capture_output=True, text=True)
    assert p.returncode == 1 and "cannot open" in p.stderr


def test_cnavcore_interface_and_errors(flight10: Flight) -> None:
    c = CNavCore(flight10.init)
    st0 = c.state()
    assert st0.lat == LAT0 and c.dt is None
    st = c.step(flight10.sample(0))
    assert c.dt == DT and st.t == flight10.imu.t[0] and st.std_pos[0] > 0
    odd = ImuSample(t=st.t + 1.5 * DT, dt=1.5 * DT, dtheta=np.zeros(3), dvel=np.zeros(3))
    assert c.step(odd).t == odd.t and c.n_off_step == 1  # integrated over the fixed step, counted
    strict = CNavCore(flight10.init, dt=DT, on_dt_mismatch="raise")
    with pytest.raises(ValueError, match="differs from the fixed step"):
        strict.step(odd)
    with pytest.raises(ValueError, match="std_ne must be >= 0"):
        c.fuse(GnssFix(t=0.01, lat=LAT0, lon=LON0, h=H0, std_ne=-1.0))
    with pytest.raises(ValueError, match=r"not supported by the C core: filter\.wind_states, adaptive"):
        CNavCore(flight10.init, NavConfig(adaptive=True, filter=FilterConfig(wind_states=True)))
    with pytest.raises(ValueError, match="precision"):
        CNavCore(flight10.init, precision="half")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="unknown core 'rust'"):
        make_core("rust", flight10.init)
    with pytest.raises(ValueError, match="dt must be positive"):
        CNavCore(flight10.init, dt=-1.0)


def test_bench_core_command_writes_report(tmp_path: Path) -> None:
    """`ins-hil bench-core` runs end to end on a tiny workload and writes the report (no timing asserted)."""
    from ins_hil.cli import main

    out = tmp_path / "ref_core.md"
    rc = main(["bench-core", "--duration", "1", "--repeat", "1", "--no-callgrind", "--accuracy-duration", "4",
               "--no-datasets", "--out", str(out)])  # fmt: skip
    assert rc == 0
    text = out.read_text()
    assert "| Python `NavCore` (`step`, `fuse`) |" in text
    assert "| C, whole log in one call" in text
    assert "`nproc` = " in text
    m = re.search(r"C double vs Python `StrapdownNED` \(free inertial\): max \|Δq\| (\S+),", text)
    assert m is not None and float(m.group(1)) <= 1e-9
    with pytest.raises(SystemExit, match="--repeat must be >= 1"):
        main(["bench-core", "--repeat", "0", "--out", str(out)])
