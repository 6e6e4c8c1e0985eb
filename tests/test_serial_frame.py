"""Serial IMU frame codec (drivers/SERIAL_FRAME.md)."""

from __future__ import annotations

import numpy as np
import pytest
from ins_hil.drivers import serial_frame as sf

from ins_hil.types import ImuSample


def _sample(seq: int = 7, t: float = 12.345678) -> ImuSample:
    return ImuSample(
        t=t,
        dt=0.001,
        dtheta=np.array([1e-3, -2e-3, 3e-4]),
        dvel=np.array([0.01, 0.0, -0.0098]),
        imu_id=2,
        seq=seq,
        temperature=31.25,
        flags=1,
    )


def test_crc_check_value() -> None:
    assert sf.crc16_ccitt(b"123456789") == 0x29B1


def test_round_trip() -> None:
    b = sf.encode(_sample())
    assert len(b) == sf.FRAME_LEN == 41
    s = sf.decode(b)
    assert (s.imu_id, s.seq, s.flags) == (2, 7, 1)
    assert s.t == pytest.approx(12.345678, abs=1e-6)
    np.testing.assert_allclose(s.dtheta, [1e-3, -2e-3, 3e-4], rtol=1e-7)
    assert s.temperature == pytest.approx(31.25)


def test_parser_resyncs_and_counts() -> None:
    p = sf.FrameParser()
    frames = [sf.encode(_sample(seq=i, t=1 + i * 1e-3)) for i in range(5)]
    bad = bytearray(frames[2])
    bad[20] ^= 0x40
    stream = b"\x00\xa5\x5a\x13" + frames[0] + frames[1] + bytes(bad) + frames[3] + frames[3] + frames[4]
    out = []
    for i in range(0, len(stream), 7):
        out += p.feed(stream[i : i + 7])
    assert [s.seq for s in out] == [0, 1, 3, 4]
    assert p.counts["crc"] == 2  # the false sync word in the leading garbage, and the bit flip
    assert p.counts["duplicate"] == 1
    assert p.counts["seq_gap"] == 1
    assert p.counts["garbage_bytes"] >= 4
