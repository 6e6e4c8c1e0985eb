"""The calibration file (TOML/JSON), its application to IMU/mag samples, and `ins-hil calibrate` end to end."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ins_hil.calibration.files import load_calibration, save_calibration
from ins_hil.calibration.logs import read_csv_log, write_csv_log
from ins_hil.cli import main
from ins_hil.nav import calibration as cal
from ins_hil.sim import calibration as simcal
from ins_hil.sim.sensors import ImuErrorModel, corrupt_imu, mems_accel, mems_gyro
from ins_hil.sim.trajectory import generate, uav_profile
from ins_hil.types import ImuSample, MagSample


def _example() -> cal.SensorCalibration:
    rng = np.random.default_rng(1)
    g = cal.TriadCalibration(np.eye(3) + 1e-3 * rng.standard_normal((3, 3)), [1e-3, -2e-3, 3e-3], "rad/s", 0.5, 1.6, 84)
    a = cal.TriadCalibration(np.eye(3) + 1e-3 * rng.standard_normal((3, 3)), [0.1, -0.2, 0.15], "m/s^2")
    m = cal.TriadCalibration([[1.08, 0.04, 0], [0.04, 0.95, 0], [0, 0, 1.0]], [2e-5, -1e-5, 0], "T")
    return cal.SensorCalibration(
        accel=a, gyro=g, mag=m, imu_id=2, noise={"gyro": {"random_walk": 4e-5}}, created="x", source="y"
    )


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_round_trip(tmp_path: Path, suffix: str) -> None:
    c = _example()
    p = tmp_path / f"cal{suffix}"
    save_calibration(c, p)
    r = load_calibration(p)
    assert r.imu_id == 2 and r.noise == c.noise and r.source == "y"
    for name in cal.SENSORS:
        np.testing.assert_array_equal(getattr(r, name).matrix, getattr(c, name).matrix)
        np.testing.assert_array_equal(getattr(r, name).bias, getattr(c, name).bias)
    assert r.gyro is not None and r.gyro.dev_percent == 0.5 and r.gyro.n_equations == 84
    assert r.accel is not None and math.isnan(r.accel.dev_percent)


def test_apply_undoes_the_sensor_model() -> None:
    # a moving trajectory; increments corrupted by A, b only (no noise): apply() must give the truth back
    truth = generate(uav_profile(), 5.0, 0.01, math.radians(50.0), 0.5, 100.0)
    rng = np.random.default_rng(3)
    gm, am = mems_gyro(rng), mems_accel(rng)
    for m in (gm, am):
        m.noise_density = m.bias_instability = 0.0
    imu = corrupt_imu(truth, gm, am, seed=0)
    c = cal.SensorCalibration(
        accel=cal.TriadCalibration(am.matrix(), am.bias), gyro=cal.TriadCalibration(gm.matrix(), gm.bias), imu_id=0
    )
    assert c.applies_to(0) and not c.applies_to(1)
    for k in range(0, len(imu.t), 37):
        s = ImuSample(t=float(imu.t[k]), dt=imu.dt, dtheta=imu.dtheta[k], dvel=imu.dvel[k], seq=k, flags=0)
        out = c.apply(s)
        np.testing.assert_allclose(out.dtheta, truth.dtheta[k], atol=1e-13)
        np.testing.assert_allclose(out.dvel, truth.dvel[k], atol=1e-12)
        assert out.seq == k and out.t == s.t and out is not s
    ms = MagSample(t=1.0, field_b=np.array([1.08 * 3e-5 + 2e-5, 0.04 * 3e-5 - 1e-5, 0.0]))
    np.testing.assert_allclose(_example().apply_mag(ms).field_b, [3e-5, 0, 0], atol=1e-15)


def test_bad_files_name_the_problem(tmp_path: Path) -> None:
    d = _example().to_dict()
    cases = [
        ({**d, "format": "x"}, "'format'"),
        ({**d, "version": 2}, "'version'"),
        ({**d, "gyro": {**d["gyro"], "matrix": [[1, 0], [0, 1]]}}, r"\[gyro\]: key 'matrix'"),
        ({**d, "accel": {**d["accel"], "bias": [0, 0, "a"]}}, r"\[accel\]: key 'bias'"),
        ({**d, "accel": {**d["accel"], "unit": "g"}}, r"\[accel\]: key 'unit'"),
        ({**d, "mag": {**d["mag"], "matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 0]]}}, "singular"),
        ({**d, "imu_id": -1}, "'imu_id'"),
        ({**d, "gyros": {}}, "unknown key"),
    ]
    for bad, msg in cases:
        p = tmp_path / "bad.json"
        p.write_text(json.dumps(bad))
        with pytest.raises(cal.CalibrationError, match=msg):
            load_calibration(p)
    p = tmp_path / "bad.toml"
    p.write_text("format = [")
    with pytest.raises(cal.CalibrationError, match="not valid TOML"):
        load_calibration(p)
    with pytest.raises(cal.CalibrationError, match="cannot read"):
        load_calibration(tmp_path / "missing.toml")
    with pytest.raises(cal.CalibrationError, match=r"\.toml or \.json"):
        load_calibration(tmp_path / "cal.yaml")


def test_csv_reader_errors(tmp_path: Path) -> None:
    p = tmp_path / "x.csv"
    p.write_text("t,gyro_x,gyro_y\n0,1,2\n")
    with pytest.raises(cal.CalibrationError, match=r"\['gyro_z'\] missing"):
        read_csv_log(p)
    p.write_text("time,a\n0,1\n")
    with pytest.raises(cal.CalibrationError, match="column 't'"):
        read_csv_log(p)


@pytest.mark.slow
def test_command_accel_then_mag_writes_a_calibration_the_gateway_applies(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rng = np.random.default_rng(21)
    acc = mems_accel(rng)
    acc.bias = np.array([0.2, -0.15, 0.25])
    run = simcal.accel_static_run(ImuErrorModel(), acc, dt=0.05, step_time=12.0, transit_time=2.0, seed=5)
    log = tmp_path / "accel.csv"
    write_csv_log(log, run.imu.t, run.imu.dt, {"dtheta": run.imu.dtheta, "dvel": run.imu.dvel, "step": run.labels})
    out = tmp_path / "imu.toml"
    assert main(["calibrate", "accel", str(log), "-o", str(out), "--lat", "50.45", "--imu-id", "1"]) == 0
    c = load_calibration(out)
    assert c.imu_id == 1 and c.accel is not None and c.gyro is None
    np.testing.assert_allclose(np.diag(c.accel.matrix), np.diag(acc.matrix()), atol=2e-4)
    np.testing.assert_allclose(c.accel.bias, acc.bias, rtol=0.02)
    rep = tmp_path / "imu_report"
    assert (rep / "accel.md").read_text().count("dev = ") == 1 and (rep / "accel_steps.png").stat().st_size > 10_000
    # the gateway side: a sample from step 3 corrected back to the reference specific force
    k = int(np.flatnonzero(run.labels == 3)[0])
    s = c.apply(ImuSample(t=0.0, dt=run.imu.dt, dtheta=run.imu.dtheta[k], dvel=run.imu.dvel[k], imu_id=1))
    np.testing.assert_allclose(s.dvel / s.dt, run.references[3], atol=0.05)  # one noisy sample
    # a magnetometer calibration is merged into the same file
    _, mag = simcal.mag_rotation_run(duration=30.0, hard_iron=np.array([1e-5, 2e-5, -5e-6]))
    mlog = tmp_path / "mag.csv"
    write_csv_log(mlog, np.arange(1, len(mag) + 1) * 0.05, 0.05, {"mag": mag})
    assert main(["calibrate", "mag", str(mlog), "-o", str(out), "--field", "50"]) == 0
    c2 = load_calibration(out)
    assert c2.accel is not None and c2.mag is not None and c2.imu_id == 1
    np.testing.assert_allclose(c2.mag.bias, [1e-5, 2e-5, -5e-6], atol=1e-7)
    assert "updating" in capsys.readouterr().out
    # the file belongs to IMU 1: a log of IMU 2 must not be merged into it
    before = out.read_text()
    assert main(["calibrate", "mag", str(mlog), "-o", str(out), "--imu-id", "2"]) == 1
    assert "holds the calibration of IMU 1" in capsys.readouterr().err
    assert out.read_text() == before


def test_command_refuses_bad_data_and_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = simcal.accel_static_run(ImuErrorModel(), mems_accel(), dt=0.05, step_time=8.0, transit_time=2.0, seed=6)
    dv = run.imu.dvel.copy()
    idx = np.flatnonzero(run.labels == 4)
    dv[idx, 1] += np.linspace(0, 0.02, len(idx)) * run.imu.dt * 9.8  # the sensor tilts ~1° during step 4
    log = tmp_path / "moved.csv"
    write_csv_log(log, run.imu.t, run.imu.dt, {"dtheta": run.imu.dtheta, "dvel": dv, "step": run.labels})
    out = tmp_path / "c.toml"
    assert main(["calibrate", "accel", str(log), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "step 4" in err and "no calibration written" in err
    assert not out.exists()


@pytest.mark.slow
def test_command_allan(tmp_path: Path) -> None:
    dt = 0.1
    gy = simcal.static_noise_record(3000.0, dt, 1e-3, 0.0, 1e-4, seed=2)
    ac = simcal.static_noise_record(3000.0, dt, 1e-3, 0.0, 0.0, seed=3)
    log = tmp_path / "static.csv"
    write_csv_log(log, dt * np.arange(1, len(gy) + 1), dt, {"dtheta": gy, "dvel": ac})
    out = tmp_path / "c.json"
    assert main(["calibrate", "allan", str(log), "-o", str(out)]) == 0
    c = load_calibration(out)
    assert c.noise["gyro"]["random_walk"] == pytest.approx(1e-3, rel=0.1)
    assert c.noise["accel"]["random_walk"] == pytest.approx(1e-3, rel=0.1)
    assert (tmp_path / "c_report" / "allan_gyro.png").exists()


def test_command_six_position_plan_without_step_column(tmp_path: Path) -> None:
    # the common 6-position test (each axis up and down) from a --plan CSV; steps detected from the signal
    six = [(0.0, 0.0), (math.pi, 0.0), (math.pi / 2, 0.0), (-math.pi / 2, 0.0), (0.0, math.pi / 2), (0.0, -math.pi / 2)]
    rng = np.random.default_rng(8)
    acc = mems_accel(rng)
    acc.bias_instability = 0.0
    run = simcal.accel_static_run(ImuErrorModel(), acc, positions=six, dt=0.05, step_time=15.0, seed=9)
    log = tmp_path / "six.csv"
    write_csv_log(log, run.imu.t, run.imu.dt, {"accel": run.accel})  # rates, no step column
    plan = tmp_path / "plan.csv"
    rows = "\n".join(f"{k},{float(r[0])!r},{float(r[1])!r},{float(r[2])!r}" for k, r in enumerate(run.references))
    plan.write_text("step,ref_x,ref_y,ref_z\n" + rows + "\n")
    out = tmp_path / "six.toml"
    assert main(["calibrate", "accel", str(log), "--plan", str(plan), "-o", str(out)]) == 0
    c = load_calibration(out)
    assert c.accel is not None and c.accel.n_equations == 18
    np.testing.assert_allclose(c.accel.matrix, acc.matrix(), atol=2e-4)
    np.testing.assert_allclose(c.accel.bias, acc.bias, atol=2e-3)


def test_recorded_samples_and_imu_selection(tmp_path: Path) -> None:
    # .ihlog recordings arrive as ImuSample/MagSample records (ins_hil.runtime.recorder.read_records)
    from ins_hil.calibration.logs import log_from_records
    from ins_hil.types import GnssFix

    recs: list[object] = []
    for k in range(100):
        for i in (0, 1):
            recs.append(ImuSample(t=0.01 * k, dt=0.01, dtheta=np.full(3, 1e-4 * (i + 1)), dvel=np.zeros(3), imu_id=i))
        recs.append(MagSample(t=0.01 * k, field_b=np.array([2e-5, 0.0, 4e-5])))
    recs.append(GnssFix(t=0.5, lat=0.8, lon=0.1, h=100.0))
    with pytest.raises(cal.CalibrationError, match=r"IMUs \[0, 1\]; choose one with --imu-id"):
        log_from_records(recs)
    log = log_from_records(recs, imu_id=1)
    assert log.imu_id == 1 and log.dt == pytest.approx(0.01) and log.gyro is not None and log.mag is not None
    np.testing.assert_allclose(log.gyro, 0.02)
    assert log.mag.shape == (100, 3)
    with pytest.raises(cal.CalibrationError, match="no samples of IMU 3"):
        log_from_records(recs, imu_id=3)
    # CSV with an imu_id column: the same selection
    p = tmp_path / "two.csv"
    p.write_text("t,gyro_x,gyro_y,gyro_z,imu_id\n0.01,1,2,3,0\n0.01,4,5,6,1\n0.02,1,2,3,0\n0.02,4,5,6,1\n")
    with pytest.raises(cal.CalibrationError, match="choose one with --imu-id"):
        read_csv_log(p)
    one = read_csv_log(p, imu_id=1)
    assert one.imu_id == 1 and one.gyro is not None
    np.testing.assert_allclose(one.gyro, [[4, 5, 6], [4, 5, 6]])
    # a calibration for IMU 1 leaves IMU 0's samples alone
    c = cal.SensorCalibration(gyro=cal.TriadCalibration(np.eye(3) * 2.0, np.zeros(3)), imu_id=1)
    s0 = ImuSample(t=0.0, dt=0.01, dtheta=np.ones(3), dvel=np.zeros(3), imu_id=0)
    assert c.apply(s0) is s0
    np.testing.assert_allclose(
        c.apply(ImuSample(t=0.0, dt=0.01, dtheta=np.ones(3), dvel=np.zeros(3), imu_id=1)).dtheta, 0.5
    )


def test_nav_calibration_does_no_file_io() -> None:
    """nav/ is pure maths: the calibration file and logs are read and written by ins_hil.calibration."""
    import ast

    src = (Path(__file__).parents[1] / "ins_hil" / "nav" / "calibration.py").read_text()
    tree = ast.parse(src)
    mods = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    mods |= {(n.module or "").split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not mods & {"json", "tomllib", "pathlib", "csv", "io", "os"}
    calls = {
        n.func.attr if isinstance(n.func, ast.Attribute) else getattr(n.func, "id", "")
        for n in ast.walk(tree)
        if isinstance(n, ast.Call)
    }
    assert not calls & {"open", "read_text", "write_text", "loadtxt", "savetxt", "genfromtxt"}
