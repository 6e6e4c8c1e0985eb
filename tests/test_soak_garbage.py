"""Soak finding: ``imu0.driver_garbage_bytes`` grew by a few bytes a second although every frame
arrived intact. A read that ended exactly at the end of a frame whose last CRC byte is 0xA5 kept
that (already decoded) byte as a possible sync start; the next read then counted it as garbage."""

from __future__ import annotations

import numpy as np
from ins_hil.drivers.serial_frame import FrameParser, encode

from ins_hil.types import ImuSample


def _frame(seq: int) -> bytes:
    return encode(ImuSample(seq * 1e-3, 1e-3, np.array((1e-4, 2e-4, 3e-4)), np.array((0.0, 0.0, -9.8e-3)), 0, seq))


def test_a_frame_ending_in_0xa5_at_a_read_boundary_is_not_garbage() -> None:
    seq = next(k for k in range(1, 5000) if _frame(k)[-1] == 0xA5)
    p = FrameParser()
    out = p.feed(_frame(seq))  # one read ends exactly with the frame (its CRC ends in 0xA5)
    out += p.feed(_frame(seq + 1))
    assert len(out) == 2
    assert p.counts.get("garbage_bytes", 0) == 0


def test_a_split_sync_word_is_still_kept_across_reads() -> None:
    p = FrameParser()
    f1, f2 = _frame(1), _frame(2)
    out = p.feed(f1 + f2[:1])  # the next frame's first sync byte (0xA5) ends this read
    out += p.feed(f2[1:])
    assert len(out) == 2 and p.counts.get("garbage_bytes", 0) == 0
