"""Hostile input to the dataset readers (issue 39): every failure is a one-line DatasetError naming the file and
what was expected, never an escaped exception; a damaged time stamp costs its sample, not the rest of the log."""

from __future__ import annotations

import itertools
import math
import struct
from pathlib import Path

import pytest
from test_datasets_readers import _ardupilot4_text_log, _sensor_combined, _write_topic

from ins_hil.datasets import dataset as dsm
from ins_hil.datasets import rtklib
from ins_hil.datasets.dataset import DatasetError, increasing, read_dataset
from ins_hil.types import FixType

MAGIC = "# ins-hil dataset csv 1"
IMU = "".join(f"imu,{0.01 * k:.2f},0.01,0.01,0,0,0,0,-9.8\n" for k in range(1, 30))


def _csv(tmp_path: Path, body: str | bytes, name: str = "d.csv") -> Path:
    p = tmp_path / name
    p.write_bytes((MAGIC + "\n").encode() + (body if isinstance(body, bytes) else body.encode()))
    return p


def _one_line_naming(e: pytest.ExceptionInfo[DatasetError], path: Path) -> None:
    msg = str(e.value)
    assert "\n" not in msg and str(path) in msg, msg


def test_generic_csv_non_utf8_is_a_dataset_error(tmp_path: Path):
    p = _csv(tmp_path, IMU.encode() + b"gnss,0.5,47.0,8.0,400\xff\xfe,,,,,,\n")
    with pytest.raises(DatasetError, match=r"d\.csv:31: not UTF-8") as e:
        read_dataset(p)
    _one_line_naming(e, p)


def test_generic_csv_fix_type_no_gps_is_no_fix_and_junk_is_refused(tmp_path: Path):
    # MAVLink's NO_GPS = 0 and NO_FIX = 1 are no fix (the record is skipped), not an escaped ValueError
    ds = read_dataset(_csv(tmp_path, IMU + "gnss,0.1,47,8,400,,,,1,2,0.3,0\ngnss,0.2,47,8,400,,,,1,2,0.3,1\n"
                           "gnss,0.3,47,8,400,,,,1,2,0.3,6\n"))  # fmt: skip
    assert [f.fix_type for f in ds.gnss] == [FixType.RTK_FIXED]
    for bad in ("inf", "1e300", "2.5", "-3", "99"):
        p = _csv(tmp_path, IMU + f"gnss,0.1,47,8,400,,,,1,2,0.3,{bad}\n", f"f{bad}.csv")
        with pytest.raises(DatasetError, match=r"fix type .*expected an integer 0") as e:
            read_dataset(p)
        _one_line_naming(e, p)
    assert dsm.fix_type_of(0, "x") is None and dsm.fix_type_of(8.0, "x") == FixType.RTK_FIXED


def test_generic_csv_infinite_values_are_refused(tmp_path: Path):
    p = _csv(tmp_path, IMU + "imu,0.5,0.01,inf,0,0,0,0,-9.8\n")
    with pytest.raises(DatasetError, match=r":31: imu: .*finite") as e:
        read_dataset(p)
    _one_line_naming(e, p)


def _px4(tmp_path: Path, cols: dict[str, list[float]], name: str = "px4") -> Path:
    d = tmp_path / name
    d.mkdir()
    _write_topic(d / "sensor_combined_0.csv", cols)
    return d


def test_px4_header_wider_than_its_data(tmp_path: Path):
    d = _px4(tmp_path, _sensor_combined(20, 5000))
    f = d / "sensor_combined_0.csv"
    lines = f.read_text().splitlines()
    f.write_text("\n".join([lines[0] + ",extra", *lines[1:]]) + "\n")
    with pytest.raises(DatasetError, match=r"values a row, 11 columns in the header") as e:
        read_dataset(d)
    _one_line_naming(e, f)


def test_px4_missing_column_and_empty_topic(tmp_path: Path):
    cols = _sensor_combined(20, 5000)
    del cols["gyro_rad[1]"]
    d = _px4(tmp_path, cols)
    with pytest.raises(DatasetError, match=r"sensor_combined: expected timestamp, gyro_rad\[0\.\.2\]") as e:
        read_dataset(d)
    _one_line_naming(e, d)
    empty = _px4(tmp_path, {k: [] for k in _sensor_combined(1, 5000)}, "empty")  # a header, no rows
    with pytest.raises(DatasetError, match=r"no IMU samples") as e:
        read_dataset(empty)
    _one_line_naming(e, empty)


def test_px4_non_utf8_topic_and_gps_without_longitude(tmp_path: Path):
    d = _px4(tmp_path, _sensor_combined(20, 5000))
    (d / "vehicle_gps_position_0.csv").write_bytes(b"timestamp,lat,lon\n1000000,470000000,\xff80000000\n")
    with pytest.raises(DatasetError, match=r"vehicle_gps_position_0\.csv:2: not UTF-8"):
        read_dataset(d)
    _write_topic(d / "vehicle_gps_position_0.csv", {"timestamp": [1_000_000], "latitude_deg": [47.0]})
    with pytest.raises(DatasetError, match=r"expected longitude_deg") as e:  # was an AssertionError
        read_dataset(d)
    _one_line_naming(e, d)
    _write_topic(d / "vehicle_gps_position_0.csv", {"timestamp": [1_000_000, 1_100_000], "lat": [470000000] * 2,
                 "lon": [80000000] * 2, "fix_type": [0, 3], "satellites_used": [9, math.nan]})  # fmt: skip
    with pytest.raises(DatasetError, match=r"record 1 .*satellites_used: nan"):
        read_dataset(d)


def test_px4_one_timestamp_an_hour_ahead_costs_one_sample(tmp_path: Path):
    cols = _sensor_combined(200, 5000)
    cols["timestamp"][50] += 3_600_000_000
    ds = read_dataset(_px4(tmp_path, cols))
    assert len(ds.imu) == 199  # was 50: every sample after the jump dropped
    t = [s.t for s in ds.imu]
    assert all(b > a for a, b in itertools.pairwise(t)) and t[-1] < 2.0


def test_increasing_keeps_the_longest_run():
    assert increasing([1, 2, 3600, 4, 5]).tolist() == [True, True, False, True, True]
    assert increasing([5, 6, 1, 2, 3, 4]).tolist() == [False, False, True, True, True, True]
    assert increasing([1, 2, 2, math.nan, 3]).tolist() == [True, True, False, False, True]


def _fmt_without(path: Path, field: str) -> Path:
    _ardupilot4_text_log(path)
    lines = path.read_text().splitlines()
    out = []
    for ln in lines:
        if ln.startswith("FMT, 129"):  # the IMU's FMT: one field dropped (its values then one fewer)
            head, cols = ln.rsplit(", ", 1)
            names = cols.split(",")
            i = names.index(field)
            parts = head.split(", ")
            parts[4] = parts[4][:i] + parts[4][i + 1 :]
            ln = ", ".join(parts) + ", " + ",".join(names[:i] + names[i + 1 :])
        elif ln.startswith("IMU,"):
            v = ln.split(", ")
            del v[1 + 7]  # AccZ is the 8th column
            ln = ", ".join(v)
        out.append(ln)
    path.write_text("\n".join(out) + "\n")
    return path


def test_dataflash_fmt_without_a_needed_field(tmp_path: Path):
    p = _fmt_without(tmp_path / "nofield.log", "AccZ")
    with pytest.raises(DatasetError, match=r"IMU message 0: field AccZ missing") as e:  # was a KeyError
        read_dataset(p)
    _one_line_naming(e, p)


def test_dataflash_gps_status_nan_and_instance_nan(tmp_path: Path):
    p = tmp_path / "a.log"
    _ardupilot4_text_log(p)
    text = p.read_text()
    gps = next(ln for ln in text.splitlines() if ln.startswith("GPS,"))
    v = gps.split(", ")
    v[3] = "nan"  # Status
    bad = tmp_path / "status.log"
    bad.write_text(text.replace(gps, ", ".join(v)))
    with pytest.raises(DatasetError, match=r"a GPS message that does not parse") as e:
        read_dataset(bad)
    _one_line_naming(e, bad)
    v[3] = "300"  # was read as RTK fixed
    bad.write_text(text.replace(gps, ", ".join(v)))
    with pytest.raises(DatasetError, match=r"GPS message 0 .*fix type 300: expected an integer") as e:
        read_dataset(bad)
    _one_line_naming(e, bad)


def test_dataflash_imu_time_backwards_is_never_integrated(tmp_path: Path):
    p = tmp_path / "a.log"
    _ardupilot4_text_log(p)
    lines = p.read_text().splitlines()
    k = [i for i, ln in enumerate(lines) if ln.startswith("IMU, ") and ln.split(", ")[2] == "0"]
    for i in (20, 21):  # two IMU stamps 30 ms back: the second was taken, its time running backwards
        v = lines[k[i]].split(", ")
        v[1] = str(int(v[1]) - 30_000)
        lines[k[i]] = ", ".join(v)
    p.write_text("\n".join(lines) + "\n")
    ds = read_dataset(p)
    t = [s.t for s in ds.imu]
    assert all(b > a for a, b in itertools.pairwise(t)) and all(s.dt > 0 for s in ds.imu)
    assert len(ds.imu) == 37 and max(s.dt for s in ds.imu) == pytest.approx(0.0075)  # two samples lost


def test_rtklib_header_without_data(tmp_path: Path):
    d = tmp_path / "rtk"
    d.mkdir()
    (d / "imu.csv").write_text("".join(f"0,0,1,0,0,0,{10 * k}\n" for k in range(50)))
    hdr = b"TIMETAG".ljust(60, b" ") + struct.pack("<IId", 0, 1_700_000_000, 0.0)
    (d / "imu.csv.tag").write_bytes(hdr)
    (d / "sol.pos").write_text("% GPST latitude(deg) longitude(deg) height(m) Q ns sdn(m) sde(m) sdu(m)\n")
    with pytest.raises(DatasetError, match=r"imu\.csv\.tag: a time-tag header without records") as e:
        read_dataset(d, "rtklib")
    _one_line_naming(e, d)
    size = (d / "imu.csv").stat().st_size
    (d / "imu.csv.tag").write_bytes(hdr + struct.pack("<II", 0, 0) + struct.pack("<II", 500, size))
    with pytest.raises(DatasetError, match=r"sol\.pos: a header without solution lines"):
        read_dataset(d, "rtklib")
    with pytest.raises(ValueError, match="without solution lines"):
        rtklib.read_pos(d / "sol.pos")


def test_an_unforeseen_reader_failure_is_one_line_naming_the_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    p = _csv(tmp_path, IMU)
    r = dsm.READERS["csv"]

    def broken(path: Path) -> dsm.Dataset:
        return {}["x"]  # type: ignore[no-any-return]

    readers = dsm.READERS.copy()
    readers.register("csv", dsm.Reader(r.name, r.expects, r.detect, broken))
    monkeypatch.setattr(dsm, "READERS", readers)
    with pytest.raises(DatasetError, match=r"damaged or not an ins-hil dataset CSV .*KeyError") as e:
        read_dataset(p)
    _one_line_naming(e, p)


#: four float splices into the first 120 kB of the shipped hover.ulg (found by the reader_px4_ulog fuzz target):
#: pyulog's resync then seeks back for ever in its definitions section
STUCK_ULOG = [(6364, b"\x00\x00\x00\x80"), (23348, b"\x00\x00\x00?"), (33104, b"\x00\x00\x00\x80"),
              (105936, b"\xea\x8c\xa09Y>)F")]  # fmt: skip


def test_a_ulog_pyulog_never_finishes_is_refused(tmp_path: Path, shared_dir: Path):
    import subprocess
    import sys

    b = bytearray((shared_dir / "data/uav/px4_hover_92s/hover.ulg").read_bytes()[:120_000])
    for off, v in STUCK_ULOG:
        b[off : off + len(v)] = v
    p = tmp_path / "stuck.ulg"
    p.write_bytes(bytes(b))
    code = "import sys; from ins_hil.datasets.dataset import read_dataset; read_dataset(sys.argv[1])"
    r = subprocess.run([sys.executable, "-c", code, str(p)], capture_output=True, text=True, timeout=600)  # hang guard
    assert r.returncode == 1 and "DatasetError" in r.stderr
    assert f"{p}: cannot parse as ULog (the parser does not advance in a damaged part)" in r.stderr
