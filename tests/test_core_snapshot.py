"""NavCore.snapshot()/restore(): a restored core runs on bit for bit like the one the snapshot was taken of
(each collaborator's state is in its own NamedTuple: strapdown, filter, aids, baro datum)."""

from __future__ import annotations

import numpy as np

from ins_hil.core import CoreSnapshot, NavConfig, NavCore
from ins_hil.core_parts.config import AidsConfig, DelayConfig
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import quat_from_euler
from ins_hil.types import BaroSample, GnssFix, ImuSample

G = 9.80665


def _inputs(k0: int, k1: int) -> list[ImuSample | GnssFix | BaroSample]:
    rng = np.random.default_rng(k0)
    out: list[ImuSample | GnssFix | BaroSample] = []
    for k in range(k0, k1):
        out.append(ImuSample(t=k * 1e-2, dt=1e-2, dtheta=rng.normal(0, 1e-4, 3),
                             dvel=np.array((0.0, 0.0, -G * 1e-2)) + rng.normal(0, 1e-3, 3)))  # fmt: skip
        if k % 10 == 0:
            out.append(BaroSample(t=k * 1e-2, pressure=float("nan"), altitude=0.3 + rng.normal(0, 0.1)))
        if k % 50 == 0:
            out.append(GnssFix(t=k * 1e-2, lat=0.87, lon=0.52 + 1e-8 * k, h=100.5, vel_ned=(5.0, 1.0, 0.0)))
    return out


def _run(core: NavCore, inputs: list[ImuSample | GnssFix | BaroSample]) -> list[tuple[float, ...]]:
    rows = []
    for m in inputs:
        if isinstance(m, ImuSample):
            st = core.step(m)
            rows.append((st.t, *st.q_nb, *st.vel_ned, st.lat, st.lon, st.h, *st.gyro_bias, *st.std_pos))
        else:
            core.fuse(m)
    return rows


def _flat(d: object) -> list[object]:
    """The leaves of a (nested) snapshot, arrays as bytes."""
    if isinstance(d, tuple):
        return [x for v in d for x in _flat(v)]
    return [d.tobytes() if isinstance(d, np.ndarray) else d]


def test_restore_replays_bit_for_bit() -> None:
    init = StrapdownState(quat_from_euler(0.01, -0.02, 0.3), np.array((5.0, 1.0, 0.0)), 0.87, 0.52, 100.0, 0.0)
    # aids and baro datum carry state too; no delayed fusion: the history (log, snapshots) is not restored
    # (the longitudinal-acceleration prior: its averaging window, 0.7 s, straddles the snapshot)
    aids = AidsConfig(nhc=True, zupt=True, long_accel_std=0.5, long_accel_rate=1 / 0.7)
    core = NavCore(init, NavConfig(aids=aids, delay=DelayConfig(compensation=False)))
    _run(core, _inputs(1, 300))
    snap = core.snapshot()
    assert isinstance(snap, CoreSnapshot) and snap.sources[0].offset is not None  # the baro datum
    later = _inputs(300, 500)
    first = _run(core, later)
    end = _flat(core.snapshot())
    core.restore(snap)
    assert _run(core, later) == first
    assert _flat(core.snapshot()) == end  # every field of every part, not only the published state
    assert core.stats["long_accel"].accepted > 4
