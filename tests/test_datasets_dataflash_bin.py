"""The DataFlash ``.bin`` reader's own sequential parser (``dataflash.binary_rows``): the same values as
pymavlink's DFReader on the shipped log, a resync after damaged bytes, and an end on any damaged FMT length."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from ins_hil.datasets import dataflash
from ins_hil.datasets.dataset import read_dataset

IMU_COLS = "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"


def _fmt(mid: int, name: str, length: int, form: str, cols: str) -> bytes:
    return b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", mid, length, name.encode(), form.encode(), cols.encode())


def _imu(t_us: int) -> bytes:
    return b"\xa3\x95\x81" + struct.pack("<Qffffff", t_us, 0.01, 0.0, 0.0, 0.0, 0.0, -9.8)


def _log(n: int = 50) -> bytearray:
    return bytearray(_fmt(0x81, "IMU", 35, "Qffffff", IMU_COLS) + b"".join(_imu(10_000 * k) for k in range(n)))


def test_binary_rows_agree_with_pymavlink_on_the_shipped_log(shared_dir: Path):
    from pymavlink import DFReader

    p = shared_dir / "data/uav/ardupilot_copter_150s/flight.bin"
    want = {"IMU", "GPS", "BARO", "MSG"}
    ours = dataflash.binary_rows(p.read_bytes(), want)
    r = DFReader.DFReader_binary(str(p), zero_time_base=True)
    theirs: dict[str, list[dict[str, object]]] = {k: [] for k in want}
    while (m := r.recv_match(type=list(want))) is not None:
        theirs[m.get_type()].append(m.to_dict())
    assert len(ours["IMU"]) > 1000 and len(ours["GPS"]) > 100
    assert ours == theirs


def test_a_damaged_byte_costs_one_message_not_the_rest_of_the_log(tmp_path: Path):
    b = _log()
    b[89 + 35 * 5 + 2] = 0x90  # the 6th IMU message's id: a message no FMT defines
    p = tmp_path / "d.bin"
    p.write_bytes(bytes(b))
    ds = read_dataset(p)  # pymavlink's index stopped there: 4 samples
    assert len(ds.imu) == 48  # 50 messages, one lost, the first has no interval
    assert all(s.dt > 0 for s in ds.imu)


@pytest.mark.parametrize("length", [0, 1, 2])
def test_a_fmt_length_below_the_header_ends(tmp_path: Path, length: int):
    b = _log() + _fmt(0x82, "XXX", length, "", "") + b"\xa3\x95\x82" * 10 + _imu(600_000)
    rows = dataflash.binary_rows(bytes(b), {"IMU", "XXX"})
    assert len(rows["IMU"]) == 51 and rows["XXX"] == []


def test_text_rows_agree_with_pymavlink_on_the_shipped_logs_text_export(shared_dir: Path, tmp_path: Path):
    from pymavlink import DFReader
    from test_datasets_readers import _dataflash_text

    p = tmp_path / "flight.log"
    want = ["IMU", "GPS", "BARO", "MSG", "NKF1"]
    _dataflash_text(shared_dir / "data/uav/ardupilot_copter_150s/flight.bin", p, want)
    ours = dataflash.text_rows(p, p.read_bytes(), set(want))
    r = DFReader.DFReader_text(str(p), zero_time_base=True)
    theirs: dict[str, list[dict[str, object]]] = {k: [] for k in want}
    while (m := r.recv_match(type=want)) is not None:
        theirs[m.get_type()].append(m.to_dict())
    assert len(ours["IMU"]) > 1000 and ours == theirs


def test_text_rows_errors_name_the_line(tmp_path: Path):
    p = tmp_path / "d.log"
    head = "FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns\nFMT, 129, 35, IMU, Qffffff, " + IMU_COLS + "\n"
    for body, match in (("IMU, 10000, 0.01, 0, 0, 0, 0, x\n", r":3: a IMU message that does not parse"),
                        ("FMT, 1x, 35, BAD, Qf, A,B\n", r":3: an FMT line that does not parse"),
                        ("FMT, 140, 35, BAD, Qy, A,B\n", r":3: an FMT line that does not parse")):  # fmt: skip
        p.write_text(head + body)
        with pytest.raises(dataflash.DatasetError, match=match):
            dataflash.text_rows(p, p.read_bytes(), {"IMU"})
    p.write_bytes(head.encode() + b"IMU, 1\xff\n")
    with pytest.raises(dataflash.DatasetError, match=r":3: not UTF-8 text"):
        dataflash.text_rows(p, p.read_bytes(), {"IMU"})


def test_a_fmt_with_more_columns_than_values_is_refused_naming_the_file(tmp_path: Path):
    b = bytearray(_fmt(0x81, "IMU", 35, "Qffffff", IMU_COLS + ",Extra") + b"".join(_imu(10_000 * k) for k in range(5)))
    p = tmp_path / "cols.bin"
    p.write_bytes(bytes(b))
    with pytest.raises(dataflash.DatasetError, match=rf"^{p}: IMU message at byte 89: 8 columns for 7 values"):
        read_dataset(p)


def test_the_readers_format_definitions_are_pymavlinks(shared_dir: Path):
    """``dataflash.DFFormat`` (the parsers' own, no pymavlink import) defines each FMT of the shipped log and every
    format character as pymavlink's ``DFReader.DFFormat``; an unknown character is refused by both."""
    from pymavlink import DFReader

    data = (shared_dir / "data/uav/ardupilot_copter_150s/flight.bin").read_bytes()
    defs: list[tuple[int, object, int, str, str]] = []
    off = data.find(b"\xa3\x95\x80")
    while off >= 0:  # every FMT message (id 128, body BBnNZ) of the log
        ty, ln, name, fm, cols = struct.unpack_from("<BB4s16s64s", data, off + 3)
        defs.append((ty, name, ln, DFReader.null_term(fm), DFReader.null_term(cols)))
        off = data.find(b"\xa3\x95\x80", off + 89)
    defs += [(200, b"ALL\0xx", 3, "".join(DFReader.FORMAT_TO_STRUCT), ",".join(DFReader.FORMAT_TO_STRUCT)),
             (201, "EMPTY", 3, "", "")]  # fmt: skip
    assert len(defs) > 50
    for d in defs:
        ours, theirs = dataflash.DFFormat(*d), DFReader.DFFormat(*d)
        for k in ("type", "name", "len", "format", "columns", "colhash", "msg_struct", "msg_fmts", "msg_types",
                  "msg_mults"):  # fmt: skip
            assert getattr(ours, k) == getattr(theirs, k), (d, k)
    with pytest.raises(ValueError):
        dataflash.DFFormat(202, "BAD", 4, "x", "A")
    with pytest.raises(Exception):  # noqa: B017 - pymavlink raises a plain Exception
        DFReader.DFFormat(202, "BAD", 4, "x", "A")
    assert dataflash.null_term(b"ab\xffc\0junk") == DFReader.null_term(b"ab\xffc\0junk")
