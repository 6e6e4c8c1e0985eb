"""``Trajectory.t_valid_end`` from what a log says: ArduPilot's land detector (``EV``) and EKF solution status
(``NKF4``/``XKF4`` ``SS``), PX4's ``vehicle_local_position`` validity flags. The onboard-estimator comparison ends
there (``compare.valid_span``)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ins_hil.datasets import compare, dataflash, px4
from ins_hil.datasets.dataset import read_dataset

NKF1_COLS = "TimeUS,Roll,Pitch,Yaw,VN,VE,VD,PN,PE,PD"


def _fmt(mid: int, name: str, form: str, cols: str) -> bytes:
    length = 3 + struct.calcsize("<" + form)
    return b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", mid, length, name.encode(), form.encode(), cols.encode())


def _msg(mid: int, form: str, *v: float) -> bytes:
    return b"\xa3\x95" + bytes([mid]) + struct.pack("<" + form, *v)


def _bin(tmp: Path, ss_at: dict[int, int], events: list[tuple[int, int]]) -> Path:
    """A 10-s log: IMU 100 Hz, NKF1 and NKF4 10 Hz (SS from ``ss_at``: time µs → status from then on), ``events``
    (time µs, EV Id)."""
    b = bytearray(_fmt(0x81, "IMU", "Qffffff", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ"))
    b += _fmt(0x82, "NKF1", "Qfffffffff", NKF1_COLS) + _fmt(0x83, "NKF4", "QH", "TimeUS,SS")
    b += _fmt(0x84, "EV", "QB", "TimeUS,Id")
    ss = 0
    for k in range(1000):
        t = 10_000 * (k + 1)
        b += _msg(0x81, "Qffffff", t, 0.0, 0.0, 0.0, 0.0, 0.0, -9.8)
        if k % 10 == 0:
            ss = max(((tt, s) for tt, s in ss_at.items() if tt <= t), default=(0, ss))[1]
            b += _msg(0x82, "Qfffffffff", t, *([0.0] * 9)) + _msg(0x83, "QH", t, ss)
        for te, i in events:
            if te == t:
                b += _msg(0x84, "QB", t, i)
    p = tmp / "f.bin"
    p.write_bytes(bytes(b))
    return p


def test_dataflash_ekf_status_invalid_to_the_end(tmp_path: Path) -> None:
    """NKF4 SS loses its horizontal-position bit at 7.01 s and keeps it lost: the onboard estimate ends there."""
    ds = read_dataset(_bin(tmp_path, {0: 9087, 7_010_000: 9087 & ~0b10000}, []))
    assert ds.onboard is not None
    assert abs(ds.onboard.t_valid_end - 7.01) < 1e-9  # type: ignore[operator]
    a, b, why = compare.valid_span(ds.onboard, 0.5, 10.0)
    assert (a, b) == (0.5, ds.onboard.t_valid_end) and "status says invalid" in why


def test_dataflash_land_detector(tmp_path: Path) -> None:
    """EV NOT_LANDED at 2 s, LAND_COMPLETE at 8 s (status valid throughout): the comparison ends at the landing; a
    landing before the last take-off does not count, a status that recovers does not either."""
    ds = read_dataset(_bin(tmp_path, {0: 9087, 3_000_000: 0, 4_000_000: 9087},
                           [(1_000_000, 18), (2_000_000, 28), (8_000_000, 18)]))  # fmt: skip
    assert ds.onboard is not None and ds.onboard.t_valid_end is not None
    assert abs(ds.onboard.t_valid_end - 8.0) < 1e-9


def test_dataflash_valid_to_the_end_and_without_status(tmp_path: Path) -> None:
    ds = read_dataset(_bin(tmp_path, {0: 9087}, [(2_000_000, 28)]))
    assert ds.onboard is not None and ds.onboard.t_valid_end is None
    assert dataflash.valid_end({"EV": [], "NKF4": []}, "NKF4") is None


def test_the_shipped_arducopter_log_ends_at_its_landing(shared_dir: Path) -> None:
    """The ArduCopter flight's land detector says LAND_COMPLETE at 375.27 s (after its NOT_LANDED at 228.08 s); its
    EKF2 status stays valid (SS 9087) to the end."""
    ds = read_dataset(shared_dir / "data/uav/ardupilot_copter_150s/flight.bin")
    assert ds.onboard is not None and ds.onboard.t_valid_end is not None
    assert abs(ds.onboard.t_valid_end - 375.270177) < 1e-6


def test_px4_status_end() -> None:
    t = np.arange(10.0)
    one, zero = np.ones(10), np.zeros(10)
    xy = np.array([0, 1, 1, 1, 1, 1, 0, 1, 0, 0])
    assert px4.status_end(t, [xy, one, None]) == 8.0  # the last invalid run, after a valid sample
    assert px4.status_end(t, [one, one]) is None  # valid to the end
    assert px4.status_end(t, [zero, one]) is None  # xy never valid (no GNSS): left out, the rest valid
    assert px4.status_end(t, [zero, np.r_[one[:5], zero[:5]]]) == 5.0
