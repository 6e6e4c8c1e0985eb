"""The 1 % corruption experiment of `ins-hil bench-drivers`: correctness only (no timing)."""

from __future__ import annotations

from ins_hil.bench.drivers import corruption


def test_one_percent_corruption_every_frame_counted_none_accepted() -> None:
    rows = corruption(n=2000, rate=0.01, seed=11)
    assert [r["transport"] for r in rows] == ["serial frame", "DroneCAN RawIMU", "DBC IMU", "MAVLink HIGHRES_IMU"]
    for r in rows:
        assert r["corrupted"] > 10, r
        assert r["accepted_corrupted"] == 0 and r["lost_good"] == 0, r
        assert r["accepted"] == 2000 - r["corrupted"], r
        c = r["counters"]
        crc = c.get("crc", 0) + c.get("transfer_crc", 0)
        assert crc == r["corrupted"], r  # one CRC failure per damaged frame/transfer
