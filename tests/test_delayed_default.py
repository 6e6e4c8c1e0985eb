"""GNSS fused at its time of validity by default: the default config, the roll-back in segments that a
1 kHz loop can run between IMU samples, and the bias it removes on the simulated default flight."""

from __future__ import annotations

import tomllib
from typing import Any

import numpy as np
import pytest
from runtime_helpers import sim_config_dict

from ins_hil.config import default_path, from_dict
from ins_hil.core import NavCore
from ins_hil.evaluation.sim_flight import fly_sim
from ins_hil.runtime.pipeline import Pipeline
from ins_hil.runtime.replay import errors, score
from ins_hil.sim.devices import send_order
from ins_hil.types import GnssFix, ImuSample


def test_default_config_fuses_late_fixes_at_their_time() -> None:
    cfg = from_dict(tomllib.loads(default_path().read_text()), "default")
    p = Pipeline(cfg.pipeline)
    assert cfg.pipeline.nav.delay.compensation is True
    assert p._aid_mon is not None and not p._aid_mon.cfg.late_fix_as_current  # the monitor follows the core


def _core_at_a_late_fix(seconds: float = 14.051) -> tuple[NavCore, list[Any], GnssFix]:
    """The default pipeline's core flown for ``seconds`` s, the IMU samples that follow, and a late fix
    (valid 50 ms before the current step, as the simulator delivers them)."""
    d = sim_config_dict()
    cfg = from_dict(d, "test")
    pipe = Pipeline(cfg.pipeline)
    later: list[ImuSample] = []
    fix: GnssFix | None = None
    for s in send_order(cfg.sim, seconds + 1.0):
        if isinstance(s, ImuSample):
            if s.t <= seconds:
                pipe.imu(s)
            else:
                later.append(s)
        elif isinstance(s, GnssFix) and abs(seconds - 0.05 - s.t) < 0.0015:
            fix = s  # delivered after ``seconds``: held back
        elif s.t <= seconds:
            pipe.aid(s)
    pipe.flush()
    assert isinstance(pipe.core, NavCore) and fix is not None and seconds - fix.t > 0.04
    return pipe.core, later, fix


def _same(a: NavCore, b: NavCore) -> bool:
    sa, sb = a.state(), b.state()
    return (
        sa.t == sb.t and sa.lat == sb.lat and sa.lon == sb.lon and sa.h == sb.h
        and np.array_equal(sa.q_nb, sb.q_nb) and np.array_equal(sa.vel_ned, sb.vel_ned)
        and np.array_equal(a.kf.P, b.kf.P) and np.array_equal(sa.gyro_bias, sb.gyro_bias)
    )  # fmt: skip


def test_rollback_runs_in_segments_and_equals_the_one_piece_rollback() -> None:
    """A late fix's roll-back yields every REPLAY_SEGMENT replayed IMU steps (a 1 kHz loop runs one segment
    per gap); IMU steps run between its segments (the core live meanwhile) are replayed too, and the end
    state is bit for bit that of the whole roll-back at once followed by the same steps."""
    import copy

    core, later, fix = _core_at_a_late_fix()
    ref = copy.deepcopy(core)
    n_prop = [0]
    orig = core.propagate

    def counting(imu: ImuSample) -> None:
        n_prop[0] += 1
        orig(imu)

    core.propagate = counting  # type: ignore[method-assign]
    per_segment = []
    live_t = []
    steps = iter(later)
    t_before = core.state().t
    for _ in core.fuse_steps(fix):
        per_segment.append(n_prop[0])
        n_prop[0] = 0
        st = core.step(next(steps))  # the live loop's next IMU sample, between two segments
        live_t.append(st.t)
    per_segment.append(n_prop[0])
    assert len(per_segment) >= 6  # ~50 steps to replay, 8 per segment
    assert max(per_segment) <= NavCore.REPLAY_SEGMENT
    assert live_t[0] > t_before and np.all(np.diff(live_t) > 0)  # the live state advanced meanwhile
    # the same fix fused at once, then the same IMU steps
    ref.fuse(fix)
    for s in later[: len(live_t)]:
        ref.step(s)
    assert _same(core, ref)
    # and afterwards the two cores stay identical (history, snapshots and log consistent)
    for s in later[len(live_t) : len(live_t) + 300]:
        core.step(s)
        ref.step(s)
    assert _same(core, ref)


@pytest.mark.slow
def test_default_flight_has_no_lag_bias() -> None:
    """The simulated default flight (20 m/s, GNSS 50 ms late): the along-track bias was ≈ −1 m (v × latency)
    when late fixes were fused as current; fused at their time it is below 0.1 m."""
    d = sim_config_dict()
    states, truth, counts = fly_sim(d, seed=3, duration=30.0)
    m = score(errors([s for s in states if s.t >= 18.0], truth))
    assert counts["fused_GnssFix"] > 140
    assert abs(m["along_bias_m"]) < 0.1, m
    d["core"]["nav"]["delay"] = {"compensation": False}  # the old default: the lag is back
    states, truth, _ = fly_sim(d, seed=3, duration=30.0)
    m_old = score(errors([s for s in states if s.t >= 18.0], truth))
    assert m_old["along_bias_m"] < -0.5, m_old
