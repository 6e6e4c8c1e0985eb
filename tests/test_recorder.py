"""Recorder (.ihlog): exact round trip, size rotation, truncated tail, replay across parts."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ins_hil.runtime.pipeline import PipelineConfig
from ins_hil.runtime.recorder import Recorder, parts_of, read_header, read_records
from ins_hil.runtime.replay import replay_log
from ins_hil.sim.devices import SimConfig, truth_chunks
from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample


def _samples() -> list:
    rng = np.random.default_rng(3)
    return [
        ImuSample(0.001, 0.001, rng.normal(size=3) * 1e-3, rng.normal(size=3), 2, 65535, math.nan, 5, 123456789),
        ImuSample(1e9 + 0.1, 0.0025, rng.normal(size=3), rng.normal(size=3), 0, 7, 21.5, 0, 2**62),
        GnssFix(0.2, 0.88, 0.53, 181.25, rng.normal(size=3), 1.5, 2.5, 0.2, FixType.RTK_FIXED, 17, 3, 99),
        GnssFix(0.4, -0.1, 3.1, -20.0, None, 2.5, 5.0, 0.3, FixType.FIX_2D, 0, 0, 0),
        BaroSample(0.04, 98765.4321, 181.2, math.nan, 1, 5),
        MagSample(0.02, rng.normal(size=3) * 1e-5, 4, 6),
    ]


def _same(a: object, b: object) -> bool:
    for f in a.__slots__:  # type: ignore[attr-defined]
        x, y = getattr(a, f), getattr(b, f)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if x is None or y is None or not np.array_equal(x, y):
                return False
        elif isinstance(x, float) and math.isnan(x):
            if not math.isnan(y):
                return False
        elif x != y:
            return False
    return True


def test_round_trip_is_exact(tmp_path: Path) -> None:
    rec = Recorder(tmp_path / "a", header={"hello": "world"})
    src = _samples()
    for s in src:
        rec.write(s)
    rec.close()
    assert rec.paths == [tmp_path / "a.ihlog"]
    back = list(read_records(tmp_path / "a.ihlog"))
    assert len(back) == len(src)
    for a, b in zip(src, back):
        assert type(a) is type(b) and _same(a, b), (a, b)
    assert read_header(tmp_path / "a.ihlog")["hello"] == "world"


def test_truncated_last_record_is_ignored(tmp_path: Path) -> None:
    rec = Recorder(tmp_path / "t.ihlog")
    for s in _samples():
        rec.write(s)
    rec.flush()  # killed: flushed, never closed (no end frame)
    data = (tmp_path / "t.ihlog").read_bytes()
    (tmp_path / "t.ihlog").write_bytes(data[:-7])  # killed in the middle of the last record
    assert len(list(read_records(tmp_path / "t.ihlog"))) == len(_samples()) - 1


def _sim_inputs(seconds: float) -> list:
    """Simulated IMU/GNSS/baro inputs in the time order a live loop would consume them."""
    cfg = SimConfig(imu_rate=200.0, chunk_s=seconds, imu_errors="mems")
    _, imu, fixes, baro = next(truth_chunks(cfg))
    items = [(float(imu.t[k]), 0, k) for k in range(len(imu.t))]
    items += [(f.t + 0.05, 1, i) for i, f in enumerate(fixes)] + [(b.t, 2, i) for i, b in enumerate(baro)]
    out = []
    for _, kind, i in sorted(items):
        if kind == 0:
            out.append(ImuSample(float(imu.t[i]), imu.dt, imu.dtheta[i], imu.dvel[i], 0, i & 0xFFFF))
        else:
            out.append(fixes[i] if kind == 1 else baro[i])
    return out


@pytest.mark.slow
def test_rotation_by_size_and_replay_across_parts(tmp_path: Path) -> None:
    inputs = _sim_inputs(20.0)
    header = {"pipeline": PipelineConfig().to_dict()}
    big = Recorder(tmp_path / "one.ihlog", header=header)
    small = Recorder(tmp_path / "rot.ihlog", header=header, max_bytes=64 * 1024)
    for k, s in enumerate(inputs):
        big.write(s)
        small.write(s)
        if k % 50 == 0:  # the loop flushes every 50 ms
            big.flush()
            small.flush()
    big.close()
    small.close()
    parts = parts_of(tmp_path / "rot.ihlog")
    assert len(parts) == len(small.paths) > 3
    assert all(p.stat().st_size <= 64 * 1024 for p in parts)
    assert parts[1].name == "rot.1.ihlog"
    assert len(list(read_records(tmp_path / "rot.ihlog"))) == len(inputs)
    # reading from any part finds the whole session
    assert parts_of(parts[2]) == parts
    a = replay_log(tmp_path / "one.ihlog")
    b = replay_log(tmp_path / "rot.ihlog")
    assert b.parts == len(parts) and len(a.states) == len(b.states) > 3000
    for x, y in zip(a.states, b.states):
        assert x.t == y.t and np.array_equal(x.q_nb, y.q_nb) and x.lat == y.lat and x.h == y.h
