"""Dataset readers: the shipped PX4 ULog, PX4 ulog2csv folder and ArduPilot DataFlash logs, folders and CSVs
the tests write, detection and the one-line errors."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from ins_hil.datasets import dataset as dsm
from ins_hil.datasets import generic_csv, px4
from ins_hil.datasets.dataset import Dataset, DatasetError, read_dataset
from ins_hil.geoid import undulation
from ins_hil.types import BaroSample, GnssFix, ImuSample, MagSample


@pytest.fixture(scope="module")
def uav(shared_dir: Path) -> Path:
    d = shared_dir / "data" / "uav"
    assert (d / "px4_hover_92s" / "hover.ulg").is_file(), f"{d} lacks the UAV logs"
    return d


def test_px4_ulog_hover(uav: Path):
    ds = read_dataset(uav / "px4_hover_92s" / "hover.ulg")
    assert ds.meta["format"] == "px4-ulog"
    r = ds.meta["rates_hz"]
    assert 210 < r["imu"] < 230 and 4.5 < r["baro"] < 5.5 and 1.8 < r["mag"] < 2.2
    assert ds.gnss == [] and any("never had a 3-D fix" in n for n in ds.meta["notes"])
    # increments over µs dt, level at rest: Δv_z ≈ −g dt
    s = ds.imu[0]
    assert 0.003 < s.dt < 0.006 and s.dvel[2] / s.dt == pytest.approx(-9.78, abs=0.1)
    assert all(b.t > a.t for a, b in zip(ds.imu[:500], ds.imu[1:501]))
    m = np.linalg.norm(ds.mag[0].field_b)
    assert 2e-5 < m < 7e-5  # gauss → tesla
    ob = ds.onboard
    assert ob is not None and ob.q_nb is not None and ob.pos_ned is not None
    np.testing.assert_allclose(np.linalg.norm(ob.q_nb, axis=1), 1.0, atol=1e-4)
    assert np.all(np.isnan(ob.pos_ned[:, :2])) and np.all(np.isfinite(ob.pos_ned[:, 2]))  # horizontal invalid
    assert ds.event("takeoff") is not None and ds.event("landing") > ds.event("takeoff")


def test_px4_csv_folder_quad(uav: Path):
    ds = read_dataset(uav / "px4_quad_157s")
    assert ds.meta["format"] == "px4-csv"
    assert 235 < ds.meta["rates_hz"]["imu"] < 245 and 4.5 < ds.meta["rates_hz"]["gnss"] < 5.0
    assert ds.mag == [] and ds.onboard is None
    f = ds.gnss[0]
    assert int(f.fix_type) == 4 and f.vel_ned is not None and 0.3 < f.std_ne < 1.0
    assert math.degrees(f.lat) == pytest.approx(29.8044569, abs=1e-6)
    assert f.h == pytest.approx(220.999, abs=1e-3)  # alt_ellipsoid in mm
    assert ds.event("takeoff") - ds.t0 == pytest.approx(3.6, abs=0.5)


def _write_topic(path: Path, cols: dict[str, list[float]]) -> None:
    names = list(cols)
    rows = zip(*cols.values())
    path.write_text(",".join(names) + "\n" + "\n".join(",".join(repr(x) for x in r) for r in rows) + "\n")


def _sensor_combined(n: int, dt_field: float) -> dict[str, list[float]]:
    return {"timestamp": [1_000_000 + 5000 * k for k in range(n)], "gyro_rad[0]": [0.1] * n, "gyro_rad[1]": [0.0] * n,
            "gyro_rad[2]": [-0.2] * n, "gyro_integral_dt": [dt_field] * n, "accelerometer_timestamp_relative": [0] * n,
            "accelerometer_m_s2[0]": [0.5] * n, "accelerometer_m_s2[1]": [0.0] * n,
            "accelerometer_m_s2[2]": [-9.8] * n, "accelerometer_integral_dt": [dt_field] * n}  # fmt: skip


def test_px4_csv_folder_written_topic_names_and_dt_units(tmp_path: Path):
    a, b = tmp_path / "new", tmp_path / "old"
    a.mkdir()
    b.mkdir()
    _write_topic(a / "log_7_2024-1-1-10-00-00_sensor_combined_0.csv", _sensor_combined(20, 5000))  # µs
    _write_topic(b / "sensor_combined_0.csv", _sensor_combined(20, 0.005))  # float s (PX4 ≤ 1.7)
    # a setpoint topic whose name contains 'vehicle_attitude' must not be read as the attitude
    _write_topic(a / "log_7_2024-1-1-10-00-00_vehicle_attitude_setpoint_0.csv",
                 {"timestamp": [1_000_000], "q_d[0]": [1.0]})  # fmt: skip
    assert px4.topic_files(a) == {"sensor_combined": a / "log_7_2024-1-1-10-00-00_sensor_combined_0.csv"}
    da, db = read_dataset(a), read_dataset(b)
    assert da.onboard is None and len(da.imu) == len(db.imu) == 20
    for x, y in zip(da.imu, db.imu):
        assert x.dt == pytest.approx(0.005) and y.dt == pytest.approx(0.005)
        np.testing.assert_allclose(x.dtheta, (0.0005, 0.0, -0.001))
        np.testing.assert_allclose(x.dvel, y.dvel)
    assert da.imu[0].t == pytest.approx(1.0)  # µs since boot → s, the interval end


def test_px4_vehicle_imu_is_the_imu_without_sensor_combined(tmp_path: Path, uav: Path):
    # a ulog2csv folder whose IMU is vehicle_imu at its full rate: deltas over µs, stamped at timestamp_sample
    n = 20
    _write_topic(tmp_path / "vehicle_imu_0.csv", {
        "timestamp": [1_000_150 + 5000 * k for k in range(n)],
        "timestamp_sample": [1_000_000 + 5000 * k for k in range(n)],
        "accel_device_id": [4259850] * n, "delta_angle[0]": [0.0005] * n, "delta_angle[1]": [0.0] * n,
        "delta_angle[2]": [-0.001] * n, "delta_velocity[0]": [0.0025] * n, "delta_velocity[1]": [0.0] * n,
        "delta_velocity[2]": [-0.049] * n, "delta_angle_dt": [5000] * n, "delta_velocity_dt": [5000] * n,
        "delta_angle_clipping": [0] * (n - 1) + [1], "delta_velocity_clipping": [0] * n,
    })  # fmt: skip
    ds = read_dataset(tmp_path)
    assert ds.meta["format"] == "px4-csv" and len(ds.imu) == n
    assert ds.imu[0].t == pytest.approx(1.0) and ds.imu[0].dt == pytest.approx(0.005)
    np.testing.assert_allclose(ds.imu[3].dtheta, (0.0005, 0.0, -0.001))
    np.testing.assert_allclose(ds.imu[3].dvel, (0.0025, 0.0, -0.049))
    assert ds.imu[-1].flags != 0 and ds.imu[0].flags == 0  # clipping carried over
    assert any("IMU from vehicle_imu" in x and "4259850" in x for x in ds.meta["notes"])
    # a second instance, and sensor_selection naming it: that one is read
    rows = (tmp_path / "vehicle_imu_0.csv").read_text().replace("4259850", "2490378").replace(",0.0005,", ",0.002,")
    (tmp_path / "vehicle_imu_1.csv").write_text(rows)
    _write_topic(tmp_path / "sensor_selection_0.csv", {"timestamp": [900_000], "accel_device_id": [2490378],
                                                       "gyro_device_id": [2490378]})  # fmt: skip
    ds = read_dataset(tmp_path)
    np.testing.assert_allclose(ds.imu[3].dtheta, (0.002, 0.0, -0.001))
    assert any("accelerometer 2490378" in x for x in ds.meta["notes"])
    # the real hover log: vehicle_imu of the selected accelerometer is what sensor_combined carries, to 1e-6
    from pyulog import ULog

    u = ULog(str(uav / "px4_hover_92s" / "hover.ulg"), ["sensor_combined", "vehicle_imu"])
    sc = next(d.data for d in u.data_list if d.name == "sensor_combined")
    vi = next(d.data for d in u.data_list if d.name == "vehicle_imu" and d.multi_id == 0)
    conv = px4.sensor_combined_from_vehicle_imu(vi, min_cover=0.0)
    k = np.searchsorted(sc["timestamp"], conv["timestamp"])
    np.testing.assert_allclose(sc["timestamp"][k], conv["timestamp"], atol=1.0)  # µs
    for i in range(3):
        np.testing.assert_allclose(conv[f"gyro_rad[{i}]"], sc[f"gyro_rad[{i}]"][k], atol=1e-6)
        np.testing.assert_allclose(conv[f"accelerometer_m_s2[{i}]"], sc[f"accelerometer_m_s2[{i}]"][k], atol=1e-5)
    # as PX4 logs it by default (one interval in ~100), it is no IMU: a one-line error
    with pytest.raises(DatasetError, match=r"vehicle_imu's intervals cover 1% of its 92 s .*not a continuous IMU"):
        px4.dataset_from_topics({"vehicle_imu": vi}, "hover.ulg", "px4-ulog")
    with pytest.raises(DatasetError, match="no sensor_combined or vehicle_imu topic"):
        px4.dataset_from_topics({}, "x.ulg", "px4-ulog")


def test_ardupilot_dataflash_crash_is_end_of_valid_data(uav: Path):
    ds = read_dataset(uav / "ardupilot_copter_150s" / "flight.bin")
    assert ds.meta["format"] == "ardupilot-bin"
    assert 24 < ds.meta["rates_hz"]["imu"] < 26 and 4.5 < ds.meta["rates_hz"]["gnss"] < 5.5
    assert ds.t_end_valid is not None and ds.t_end_valid < ds.gnss[-1].t < ds.imu[-1].t
    assert ds.t1 == ds.t_end_valid and "loss of control" in ds.meta["end_of_valid_data"]
    # before the end, the flight is inside the normal envelope
    w = np.array([np.linalg.norm(s.dtheta / s.dt) for s in ds.imu if s.t < ds.t_end_valid])
    assert w.max() < 3.0
    assert 3e-5 < np.linalg.norm(ds.mag[0].field_b) < 7e-5  # milligauss → tesla
    ob = ds.onboard
    assert ob is not None and ob.name.startswith("NKF1") and ob.origin is None and len(ob.t_att) > 1000
    assert ds.meta["utc_start_s"] == pytest.approx(1.4823e9, abs=1e6)  # GPS week 1928: December 2016


def _synthetic() -> Dataset:
    imu = [ImuSample(0.01 * k, 0.01, np.array((1e-4, -2e-4, 3e-4)), np.array((0.001, 0.002, -0.098)))
           for k in range(1, 101)]  # fmt: skip
    gnss = [GnssFix(0.2 * k, math.radians(45.0), math.radians(7.0), 300.0, np.array((0.1, -0.2, 0.0)), 1.5, 3.0, 0.2)
            for k in range(5)]  # fmt: skip
    gnss.append(GnssFix(1.0, math.radians(45.0), math.radians(7.0), 300.0, None, 1.5, 3.0, 0.2))
    return Dataset(imu, gnss, [BaroSample(0.1, math.nan, 12.5)], [MagSample(0.1, np.array((2e-5, 1e-6, 4e-5)))])


def _dataflash_text(src: Path, dst: Path, types: list[str]) -> None:
    """Write ``src`` (a DataFlash .bin) as a text log (Mission Planner's layout: every FMT, then one line per
    message of ``types``, its values in their units)."""
    from pymavlink import DFReader

    r = DFReader.DFReader_binary(str(src), zero_time_base=True)
    with dst.open("w") as f:
        for fm in {fm.name: fm for fm in r.formats.values()}.values():
            f.write(f"FMT, {fm.type}, {fm.len}, {fm.name}, {fm.format}, {','.join(fm.columns)}\n")
        while (m := r.recv_match(type=types)) is not None:
            f.write(", ".join([m.get_type()] + [str(getattr(m, c)) for c in m.fmt.columns]) + "\n")


def test_ardupilot_dataflash_text_log_reads_as_the_bin(tmp_path: Path, uav: Path):
    src = uav / "ardupilot_copter_150s" / "flight.bin"
    log = tmp_path / "flight.log"
    _dataflash_text(src, log, ["IMU", "GPS", "GPA", "BARO", "MAG", "NKF1", "MSG", "PARM"])
    assert dsm.detect_format(log) == "ardupilot-log"
    a, b = read_dataset(src), read_dataset(log)
    assert b.meta["format"] == "ardupilot-log" and b.meta["firmware"] == a.meta["firmware"]
    assert (len(b.imu), len(b.gnss), len(b.baro), len(b.mag)) == (len(a.imu), len(a.gnss), len(a.baro), len(a.mag))
    for x, y in zip(a.imu, b.imu):
        assert x.t == y.t and np.array_equal(x.dtheta, y.dtheta) and np.array_equal(x.dvel, y.dvel)
    assert [(f.t, f.lat, f.lon, f.h, f.std_ne) for f in a.gnss] == [(f.t, f.lat, f.lon, f.h, f.std_ne) for f in b.gnss]
    assert b.t_end_valid == a.t_end_valid and b.meta["utc_start_s"] == a.meta["utc_start_s"]
    assert a.onboard is not None and b.onboard is not None
    np.testing.assert_array_equal(a.onboard.q_nb, b.onboard.q_nb)
    # a .log replayed with the .bin's dataset config is read by the text reader
    from ins_hil.datasets import config, report

    cfg = config.load(Path(__file__).resolve().parents[1] / "configs" / "datasets" / "ardupilot_copter.toml")
    assert cfg.format == "ardupilot-bin" and report.load(log, cfg).meta["format"] == "ardupilot-log"
    bad = tmp_path / "other.log"
    bad.write_text("2016-12-23 12:00:00 boot\n")
    with pytest.raises(DatasetError, match="its name says ardupilot-log but its content is not an ArduPilot"):
        report.load(bad, cfg)


def _ardupilot4_text_log(path: Path, n: int = 40) -> None:
    """An ArduPilot 4.x text log: two IMUs, two GPS, two baros and two compasses, each one message name with
    an instance field I, interleaved; EKF3 with two cores (C). Instance 1 carries other values."""
    fmt = [
        "FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns",
        "FMT, 129, 67, IMU, QBffffffIIfBBHH, TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz",
        "FMT, 130, 58, GPS, QBBIHBcLLeffffB, TimeUS,I,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt,Spd,GCrs,VZ,Yaw,U",
        "FMT, 131, 47, BARO, QBffcfIffB, TimeUS,I,Alt,Press,Temp,CRt,SMS,Offset,GndTemp,Health",
        "FMT, 132, 39, MAG, QBhhhhhhhhhBI, TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S",
        "FMT, 133, 63, XKF1, QBccCfffffffccce, TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH",
        "FMT, 134, 75, MSG, QZ, TimeUS,Message",
        "FMT, 135, 25, ORGN, QBLLe, TimeUS,Type,Lat,Lng,Alt",
    ]
    lines = [*fmt, "MSG, 1000, ArduCopter V4.5.1 (12345678)", "ORGN, 2000, 0, 47.0, 8.0, 500.0",
             "ORGN, 3000, 1, 47.1, 8.1, 501.0"]  # the EKF origin, then the AHRS home  # fmt: skip
    for k in range(n):
        t = 1_000_000 + 2500 * k  # 400 Hz
        for i, (g, a) in enumerate(((0.01, -9.8), (0.5, -8.0))):
            lines.append(f"IMU, {t + i * 100}, {i}, {g}, 0, 0, 0, 0, {a}, 0, 0, 25, 1, 1, 400, 400")
        if k % 20 == 0:
            for i, lat in enumerate((47.0, 48.0)):
                lines.append(f"GPS, {t}, {i}, 3, {t // 1000}, 2300, 12, 0.8, {lat}, 8.0, 500.0, 0, 0, 0, 0, 1")
                lines.append(f"BARO, {t}, {i}, {1.0 + 9 * i}, 95000, 20, 0, {t // 1000}, 0, 20, 1")
                lines.append(f"MAG, {t}, {i}, {200 + 300 * i}, 0, 400, 0, 0, 0, 0, 0, 0, 1, {t}")
                lines.append(f"XKF1, {t}, {i}, 1.0, {2.0 + 10 * i}, 90.0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0")
    path.write_text("\n".join(lines) + "\n")


def test_ardupilot4_instances_the_first_of_each_sensor(tmp_path: Path):
    log = tmp_path / "00000042.log"
    _ardupilot4_text_log(log)
    ds = read_dataset(log)
    assert ds.meta["format"] == "ardupilot-log" and ds.meta["firmware"].startswith("ArduCopter V4.5.1")
    assert len(ds.imu) == 39 and all(s.dt == pytest.approx(0.0025) for s in ds.imu)  # instance 0 only
    assert all(s.dtheta[0] / s.dt == pytest.approx(0.01) and s.dvel[2] / s.dt == pytest.approx(-9.8) for s in ds.imu)
    assert len(ds.gnss) == 2 and all(math.degrees(f.lat) == pytest.approx(47.0) for f in ds.gnss)
    assert [b.altitude for b in ds.baro] == [1.0, 1.0] and all(m.field_b[0] == pytest.approx(2e-5) for m in ds.mag)
    assert ds.onboard is not None and ds.onboard.name.startswith("XKF1")
    assert len(ds.onboard.t_att) == 2  # core 0
    assert ds.onboard.origin is not None and math.degrees(ds.onboard.origin[0]) == pytest.approx(47.0)  # not home
    # ORGN and GPS Alt are MSL: the origin and the fixes on the WGS84 datum the solution is on (EGM96 N ≈ 48.4 m)
    n = undulation(math.radians(47.0), math.radians(8.0))
    assert n == pytest.approx(48.4, abs=0.5)
    assert ds.onboard.origin[2] == pytest.approx(500.0 + n)
    assert all(f.h == pytest.approx(500.0 + undulation(f.lat, f.lon)) for f in ds.gnss)
    bad = tmp_path / "bad.log"
    bad.write_text(log.read_text().replace("IMU, 1002500, 0, 0.01,", "IMU, 1002500, 0, 0.0x1,"))
    with pytest.raises(DatasetError, match=r"bad\.log:\d+: a IMU message that does not parse"):
        read_dataset(bad)


def test_a_config_reads_its_flight_stacks_other_form_and_refuses_another(tmp_path: Path, uav: Path):
    from ins_hil.datasets import config, report

    root = Path(__file__).resolve().parents[1] / "configs" / "datasets"
    log = tmp_path / "flight.log"
    _dataflash_text(uav / "ardupilot_copter_150s" / "flight.bin", log, ["IMU", "GPS", "MSG"])
    own = tmp_path / "my_copter.toml"  # a copy of the shipped config whose own path is the text log
    own.write_text((root / "ardupilot_copter.toml").read_text().replace(
        'path = "../../../shared/data/uav/ardupilot_copter_150s/flight.bin"', f'path = "{log}"'))  # fmt: skip
    cfg = config.load(own)
    assert cfg.format == "ardupilot-bin" and cfg.path == log
    assert report.load(log, cfg).meta["format"] == "ardupilot-log"
    drive = config.load(root / "drive0708.toml")
    with pytest.raises(DatasetError, match=r"hover\.ulg: a px4-ulog recording, but the dataset config names format "
                                           r"= 'rtklib'"):  # fmt: skip
        report.load(uav / "px4_hover_92s" / "hover.ulg", drive)
    hover = config.load(root / "px4_hover.toml")
    with pytest.raises(DatasetError, match=r"flight\.bin: an ardupilot-bin recording, but the dataset config names "
                                           r"format = 'px4-ulog'"):  # fmt: skip
        report.load(uav / "ardupilot_copter_150s" / "flight.bin", hover)
    quad = config.load(root / "px4_quad.toml")
    topic = uav / "px4_quad_157s" / "sensor_combined_0.csv"
    with pytest.raises(DatasetError, match="give the folder"):
        report.load(topic, quad)


def test_generic_csv_round_trip(tmp_path: Path):
    ds = _synthetic()
    p = tmp_path / "mine.csv"
    generic_csv.write_generic_csv(p, ds)
    assert dsm.detect_format(p) == "csv"
    back = read_dataset(p)
    assert len(back.imu) == 100 and len(back.gnss) == 6 and back.reference is None
    for a, b in zip(ds.imu, back.imu):
        assert b.t == pytest.approx(a.t) and b.dt == pytest.approx(a.dt)
        np.testing.assert_allclose(b.dtheta, a.dtheta, rtol=1e-6)
        np.testing.assert_allclose(b.dvel, a.dvel, rtol=1e-6)
    assert back.gnss[-1].vel_ned is None and back.gnss[0].lat == pytest.approx(ds.gnss[0].lat, abs=1e-10)
    np.testing.assert_allclose(back.mag[0].field_b, ds.mag[0].field_b, rtol=1e-5)
    assert back.baro[0].altitude == pytest.approx(12.5)


def test_generic_csv_written_to_a_str_path(tmp_path: Path):
    """docs/datasets.md's `write_generic_csv(path, dataset)` with a plain string path (was AttributeError)."""
    p = tmp_path / "mine.csv"
    generic_csv.write_generic_csv(str(p), _synthetic())
    assert len(read_dataset(p).imu) == 100


def test_generic_csv_reference_and_onboard(tmp_path: Path):
    p = tmp_path / "ref.csv"
    p.write_text(generic_csv.MAGIC + "\nimu,0.01,0.01,0,0,0,0,0,-9.8\nref,0.0,45,7,300,1,0,0,0,0,90\n"
                 "ref,1.0,45.00001,7,300,1,0,0,0,0,90\nonboard,0.5,45,7,300,,,,1,2,3\n")  # fmt: skip
    ds = read_dataset(p)
    assert ds.reference is not None and ds.reference.pos_ned[1, 0] == pytest.approx(1.11, abs=0.01)
    assert ds.reference.q_nb is not None and ds.onboard is not None and ds.onboard.vel_ned is None


@pytest.mark.parametrize(
    "body, match",
    [
        ("imu,0.01,0.01,0,0,0\n", r":2: imu: expected t and 8 fields"),
        ("imu,0.01,0.01,0,0,0,0,0,x\n", r":2: imu: a field is not a number"),
        ("attitude,0.01,1\n", r":2: unknown record kind 'attitude'"),
        ("imu,0.01,0,0,0,0,0,0,-9.8\n", r"dt=0.0 \(expected > 0 s\)"),
    ],
)
def test_generic_csv_errors_name_the_line(tmp_path: Path, body: str, match: str):
    p = tmp_path / "bad.csv"
    p.write_text(generic_csv.MAGIC + "\n" + body)
    with pytest.raises(DatasetError, match=match):
        read_dataset(p)


def test_unsupported_and_wrong_files(tmp_path: Path, uav: Path):
    p = tmp_path / "notes.txt"
    p.write_text("hello\n")
    with pytest.raises(DatasetError, match=r"not a supported dataset \(expected .*PX4 \.ulg"):
        read_dataset(p)
    with pytest.raises(DatasetError, match=r"not a supported dataset \(expected .*DataFlash \.bin"):
        read_dataset(p)
    damaged = tmp_path / "flight.ulg"
    damaged.write_bytes(b"\x00" * 64)
    with pytest.raises(DatasetError, match=r"flight\.ulg: its name says px4-ulog but its content is not a PX4 \.ulg"):
        read_dataset(damaged)
    topic = uav / "px4_quad_157s" / "sensor_combined_0.csv"
    folder = re.escape(str(topic.parent))
    with pytest.raises(DatasetError, match=rf"one file of a PX4 ulog2csv folder .*: give the folder {folder}$"):
        read_dataset(topic)
    with pytest.raises(DatasetError, match="not a PX4 ULog file"):
        read_dataset(p, "px4-ulog")
    with pytest.raises(DatasetError, match="not an ArduPilot DataFlash"):
        read_dataset(uav / "px4_hover_92s" / "hover.ulg", "ardupilot-bin")
    with pytest.raises(DatasetError, match="unknown dataset format 'rosbag'"):
        read_dataset(p, "rosbag")
    with pytest.raises(DatasetError, match="no such file"):
        read_dataset(tmp_path / "missing.ulg")
    empty = tmp_path / "empty_dir"
    empty.mkdir()
    with pytest.raises(DatasetError, match="not a supported dataset"):
        read_dataset(empty)


def test_px4_logging_gaps_bridged_or_reported(tmp_path: Path):
    cols = _sensor_combined(30, 5000)
    ts = cols["timestamp"]
    ts[10:] = [x + 5000 for x in ts[10:]]  # one dropped message (5 ms): bridged
    ts[20:] = [x + 200_000 for x in ts[20:]]  # 200 ms of lost data: not integrated, reported
    _write_topic(tmp_path / "sensor_combined_0.csv", cols)
    ds = read_dataset(tmp_path)
    assert ds.imu[10].dt == pytest.approx(0.010) and ds.imu[10].dtheta[0] == pytest.approx(0.001)
    assert ds.imu[20].dt == pytest.approx(0.005)
    assert any("2 logging gaps" in n and "1 longer (up to 0.20 s)" in n for n in ds.meta["notes"]), ds.meta["notes"]


def test_px4_reader_takes_px4s_corrected_accelerometer_and_field(uav: Path):
    """sensor_combined and vehicle_magnetometer are PX4's corrected data (what EKF2 fuses): the raw sensor_accel /
    sensor_mag with the log's CAL_ACC0 / SENS_BOARD_*_OFF and CAL_MAG0 / magnetometer_bias_estimate applied
    once give what the reader hands the core; applied a second time they would move y by ~0.6 m/s²."""
    from pyulog import ULog

    from ins_hil.nav.rotation import dcm_from_euler

    path = uav / "px4_hover_92s" / "hover.ulg"
    ds = read_dataset(path)
    u = ULog(str(path), ["sensor_accel", "sensor_mag", "magnetometer_bias_estimate"])
    d = {x.name: x.data for x in u.data_list if x.multi_id == 0}
    prm = u.initial_parameters
    t_off = ds.event("takeoff")
    assert t_off is not None
    # accelerometer: board ∘ (scale ⊙ (raw − offset)), PX4's calibration::Accelerometer, at rest before take-off
    sa = d["sensor_accel"]
    rest = sa["timestamp_sample"] * 1e-6 < t_off - 0.5
    raw = np.column_stack([sa[c][rest] for c in "xyz"]).astype(np.float64)
    off = np.array([prm[f"CAL_ACC0_{c}OFF"] for c in "XYZ"])
    scale = np.array([prm[f"CAL_ACC0_{c}SCALE"] for c in "XYZ"])
    board = dcm_from_euler(*(math.radians(prm[f"SENS_BOARD_{c}_OFF"]) for c in "XYZ"))
    cal = ((raw - off) * scale) @ board.T
    t_imu = np.array([s.t for s in ds.imu])
    f = np.array([s.dvel / s.dt for s in ds.imu])
    near = np.array([f[abs(t_imu - t) < 0.01].mean(axis=0) for t in sa["timestamp_sample"][rest] * 1e-6])
    assert len(cal) >= 4
    np.testing.assert_allclose(near.mean(axis=0), cal.mean(axis=0), atol=0.04)
    twice = (((cal - off) * scale) @ board.T).mean(axis=0)
    assert abs(twice[1] - near.mean(axis=0)[1]) > 0.3
    # field: S (raw − offset) − the pre-flight bias estimate (gauss), S with CAL_MAG0 scales and off-diagonals
    sm, be = d["sensor_mag"], d["magnetometer_bias_estimate"]
    o = [prm[f"CAL_MAG0_{c}ODIAG"] for c in "XYZ"]
    s = np.diag([prm[f"CAL_MAG0_{c}SCALE"] for c in "XYZ"])
    s[0, 1] = s[1, 0] = o[0]
    s[0, 2] = s[2, 0] = o[1]
    s[1, 2] = s[2, 1] = o[2]
    moff = np.array([prm[f"CAL_MAG0_{c}OFF"] for c in "XYZ"])
    bias = np.array([be[f"bias_{c}[0]"][0] for c in "xyz"])
    assert be["valid[0]"][0] == 1
    rest = sm["timestamp_sample"] * 1e-6 < t_off - 0.5
    want = (np.column_stack([sm[c][rest] for c in "xyz"]).astype(np.float64) - moff) @ s.T - bias
    got = np.array([m.field_b for m in ds.mag if m.t < t_off - 0.5]) * 1e4  # T → G
    assert len(want) >= 4 and len(got) >= 8
    np.testing.assert_allclose(got.mean(axis=0), want.mean(axis=0), atol=0.01)
    assert np.linalg.norm(((want - moff) @ s.T - bias).mean(axis=0) - got.mean(axis=0)) > 0.05  # applied twice


def test_px4_onboard_notes_explain_ekf2_at_rest_and_its_drift(uav: Path):
    """EKF2's tilt at rest is the reader's levelled specific force less EKF2's bias estimate at the start (the
    note's figures); its unaided velocity in the hover is reported as dead reckoning."""
    from ins_hil.datasets.run import euler_series
    from ins_hil.nav.alignment import coarse_level

    ds = read_dataset(uav / "px4_hover_92s" / "hover.ulg")
    chk = ds.meta["onboard_check"]
    assert chk["accel_device_id"]["sensor_combined"] == chk["accel_device_id"]["ekf2_primary"]
    t_off = ds.event("takeoff")
    assert t_off is not None and ds.onboard is not None and ds.onboard.q_nb is not None
    f = np.mean([s.dvel / s.dt for s in ds.imu if s.t < t_off - 0.5], axis=0)
    ba = np.array(chk["ekf2_accel_bias_start_mps2"])
    rest = ds.onboard.t_att < t_off - 0.5
    ekf2 = np.degrees(euler_series(ds.onboard.q_nb[rest]).mean(axis=0))
    ours = np.degrees(coarse_level(f))
    less = np.degrees(coarse_level(f - ba))
    assert np.max(abs(ours - ekf2[:2])) > 0.4  # the levelled specific force alone is not EKF2's tilt
    np.testing.assert_allclose(less, ekf2[:2], atol=0.1)  # less EKF2's bias, it is
    assert any("EKF2 starts with an accelerometer bias" in n for n in ds.meta["notes"])
    assert chk["ekf2_unaided_speed_mps"] > 10.0 and any("dead-reckons" in n for n in ds.meta["notes"])


def test_px4_onboard_notes_on_written_topics():
    """Different IMUs are named; a zero bias and a valid velocity give no note."""
    n = 5
    topics = {
        "sensor_selection": {"timestamp": np.zeros(1), "accel_device_id": np.array([11.0])},
        "estimator_selector_status": {"timestamp": np.zeros(1), "accel_device_id": np.array([22.0])},
        "estimator_sensor_bias": {"timestamp": np.zeros(1), "accel_device_id": np.array([22.0]),
                                  **{f"accel_bias[{i}]": np.zeros(1) for i in range(3)}},
        "vehicle_local_position": {"timestamp": np.arange(n) * 1e6, "vx": np.full(n, 30.0), "vy": np.zeros(n),
                                   "v_xy_valid": np.ones(n)},
    }  # fmt: skip
    notes, chk = px4.onboard_notes(topics)
    assert len(notes) == 1 and "accelerometer 11" in notes[0] and "fuses 22" in notes[0]
    assert chk["ekf2_accel_bias_start_mps2"] == [0.0, 0.0, 0.0] and "ekf2_unaided_speed_mps" not in chk
    topics["vehicle_local_position"]["v_xy_valid"] = np.zeros(n)
    topics["vehicle_local_position"]["vx"] = np.arange(n) * 2.0  # 8 m/s after 4 s: 2 m/s²
    notes, chk = px4.onboard_notes(topics)
    assert chk["ekf2_unaided_accel_error_mps2"] == pytest.approx(2.0) and "dead-reckons" in notes[-1]


def test_end_of_valid_data_names_a_corrupted_rate_without_printing_inf():
    """A corrupted IMU value (±inf, or components near 1e308 whose norm overflows) ends the valid data like an
    impact, and the message a replay prints says so in words: "inf" printed as a figure is what the replay's
    contract forbids (the fuzz campaign's replay_dataset found it on a mutated DataFlash log)."""
    from ins_hil.datasets.dataflash import end_of_valid_data
    from ins_hil.fuzz.targets import replay_oracle

    t = np.arange(4.0)
    acc = np.tile([0.0, 0.0, -9.8], (4, 1))
    for bad, shown in (([np.inf, 0.0, 0.0], "|ω| not finite"), ([1.7e308, 1.7e308, 0.0], "|ω| ≥ 1.7e+308 rad/s"),
                       ([3.0e7, 0.0, 0.0], "|ω| 3e+07 rad/s"), ([40.0, 0.0, 0.0], "|ω| 40.0 rad/s")):  # fmt: skip
        gyro = np.zeros((4, 3))
        gyro[2] = bad
        t_end, why = end_of_valid_data(t, gyro, acc, 3.5)
        assert t_end == 1.5 and "loss of control from 2.00 s (|f| 10 m/s², " in why and shown in why, why
        assert replay_oracle(0, f"end of valid data: {why}", "", Path("x")) == []


def test_rtklib_imu_csv_fields_converted_at_once_as_line_by_line(tmp_path: Path):
    """The IMU csv's fields are converted at once; the result (values, bad-line count, the kept lines' end offsets)
    is that of reading each line alone (``_csv_rows``), with damaged lines of every kind, CRLF ends and no newline at
    the end; a field that does not convert (an underscore in a number that Python's float takes: ``1_0``; a letter)
    sends the whole file line by line, with the same result."""
    from ins_hil.datasets import rtklib

    good = "0.119,0.027,1.013,-0.671,3.082,0.198,261906"
    lines = [good[:20], good, good + "\r", "1,2,3,4,5,6", "nan,0,0,0,0,0,1", "1e999,0,0,0,0,0,2", "", "a,b,c,d,e,f,g",
             " 1.5 ,2,3,4,5,6,7 ", "1,2,3,4,5,6,7,8", "-0.0,+1,.5,5.,1e-3,2E2,3", good]  # fmt: skip
    for tail, extra in (("", []), ("\n", []), ("\n", ["1_0,2,3,4,5,6,7"]), ("", ["x1,2,3,4,5,6,7"])):
        p = tmp_path / "imu.csv"
        p.write_bytes(("\n".join(lines + extra) + tail).encode())
        ends: list[int] = []
        acc, gyro, tick, bad = rtklib.read_imu_csv(p, ends)
        raw = p.read_bytes().split(b"\n")
        if raw[-1] == b"":
            raw.pop()
        kept, rows = rtklib._csv_rows(raw, 7)
        assert np.array_equal(np.column_stack([acc, gyro, tick]), rows)
        assert bad == len(raw) - len(kept)
        starts = np.cumsum([0] + [len(r) + 1 for r in raw])
        assert ends == [v for i in kept for v in (int(starts[i]) + len(raw[i].rstrip(b"\r")), i)]
        assert len(kept) == 5 + (1 if extra and extra[0].startswith("1_0") else 0)
