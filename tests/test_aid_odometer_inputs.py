"""The odometer aid's inputs: MAVLink WHEEL_DISTANCE through the MAVLink driver with the registry's decoders."""

from __future__ import annotations

import pytest
from ins_hil.drivers.mavlink_in import MavlinkDriver
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from ins_hil import aids
from ins_hil.aids.odometer import OdometerSample
from ins_hil.runtime.pipeline import nav_config


def test_wheel_distance_to_speed() -> None:
    drv = MavlinkDriver("udpin:127.0.0.1:0", system_id=1)
    drv.set_decoders(aids.decoders("mavlink", nav_config({"odometer": {"enabled": True}})))
    got: list = []
    drv._sink = got.append
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)

    def feed(t_s: float, *dist: float) -> None:
        m = mav.wheel_distance_encode(round(t_s * 1e6), len(dist), [*dist] + [0.0] * (16 - len(dist)))
        drv.feed(m.pack(mav), now_ns=round((100.0 + t_s) * 1e9))
        mav.seq = (mav.seq + 1) % 256

    feed(1.0, 10.0, 10.4)  # the first: nothing to difference against
    feed(1.1, 11.0, 11.6)  # left 10 m/s, right 12 m/s
    feed(1.1, 11.0, 11.6)  # the same time again: no speed
    feed(1.3, 10.6, 11.2)  # reversing at 2 m/s
    feed(2.5, 20.0, 20.0)  # after a 1.2 s gap: no speed
    assert [type(s) for s in got] == [OdometerSample, OdometerSample]
    a, b = got
    assert a.speed_mps == pytest.approx(11.0) and b.speed_mps == pytest.approx(-2.0)
    assert b.t - a.t == pytest.approx(0.15)  # the middles of (1.0, 1.1) and (1.1, 1.3)
    assert a.t_arrival_ns == round(101.1e9)
    assert aids.source_of(a).validate(None, a) is None
    assert aids.decoders("mavlink", nav_config({"odometer": {"enabled": False}})) == {}
