"""The static alignment's levelling on the C core (``ins_level_t``, ``ins_imu_check_t``: firmware_ref/src/align.c,
through ``CNavCore``: a run of samples in one C call, ``run_states``, or one at a time, ``step``) held against the
Python levelling of ``NavCore`` (``core_parts/alignment.py``, ``core_parts/sensor_check.py``)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from ins_hil.core import NavConfig, NavCore
from ins_hil.cref import CNavCore, _CAlignment
from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_from_euler
from ins_hil.types import GnssFix, ImuSample, MagSample

LAT, LON, H = 0.8, 0.2, 100.0
MAG_REF = (0.2, 0.01, 0.45)


def _stream(rate: float, seconds: float, gnss_from: float, mag: bool, turn: float | None = 6.0,
            seed: int = 2) -> list[Any]:  # fmt: skip
    """A vehicle at rest (roll 0.03, pitch −0.02, yaw 1.0 rad) with a vibrating MEMS IMU, turning at 0.5 rad/s
    about its z axis for 0.5 s from ``turn`` s (the IMU's motion test fires; the GNSS speed stays 0); GNSS fixes at
    5 Hz from ``gnss_from`` s (zero velocity), magnetometer samples at 10 Hz. The samples in time order."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate
    C = dcm_from_euler(0.03, -0.02, 1.0)
    f_b = C.T @ np.array((0.0, 0.0, -earth.normal_gravity(LAT, H))) + np.array((0.02, -0.03, 0.01))
    w_b = C.T @ earth.earth_rate_ned(LAT) + np.array((2e-4, -1e-4, 3e-4))
    out: list[Any] = []
    for k in range(1, int(seconds * rate) + 1):
        t = 100.0 + k * dt
        w = w_b + (np.array((0.0, 0.0, 0.5)) if turn is not None and 100.0 + turn <= t < 100.5 + turn else 0.0)
        out.append(ImuSample(t=t, dt=dt, dtheta=(w + rng.normal(0.0, 2e-3, 3)) * dt,
                             dvel=(f_b + rng.normal(0.0, 0.08, 3)) * dt))  # fmt: skip
        tk = round((t - 100.0) * rate)
        if t - 100.0 >= gnss_from and tk % round(rate / 5) == 0:
            out.append(GnssFix(t=t, lat=LAT + rng.normal(0.0, 1e-7), lon=LON, h=H, vel_ned=np.zeros(3), std_ne=1.0,
                               std_d=2.0, std_vel=0.1))  # fmt: skip
        if mag and tk % round(rate / 10) == 0:
            out.append(MagSample(t=t, field_b=C.T @ np.array(MAG_REF) + rng.normal(0.0, 0.003, 3)))
    return out


def _cfg(time: float = 2.0, mag: bool = False) -> NavConfig:
    base = NavConfig()
    cfg = dataclasses.replace(base, alignment=dataclasses.replace(base.alignment, mode="static", time=time))
    if mag:
        cfg = dataclasses.replace(cfg, mag=dataclasses.replace(cfg.mag, ref_ned=np.array(MAG_REF)))
    return cfg


def _drive(core: Any, stream: list[Any], runs: bool, seed: int = 5) -> tuple[list[Any], list[str], int]:
    """Feed ``stream``: each aiding sample after the IMU sample before it; with ``runs`` the IMU samples between
    two aiding samples through ``run_states`` in runs of random length while ``can_run`` (a run may stop early:
    the rest is handed over again). Per IMU sample the state ``step_begin`` returns (``run_states``' states) and the
    phase after it; the runs on C."""
    rng = np.random.default_rng(seed)
    states: list[Any] = []
    phases: list[str] = []
    n_runs = 0
    k = 0
    while k < len(stream):
        s = stream[k]
        if s.kind != "imu":
            core.fuse(s)
            k += 1
            continue
        if runs and core.can_run():
            j, lim = k, k + int(rng.integers(1, 40))
            while j < min(lim, len(stream)) and stream[j].kind == "imu":
                j += 1
            part = stream[k:j]
            inc = np.array([np.r_[p.dtheta, p.dvel] for p in part])
            got = core.run_states(inc, np.array([p.t for p in part]), np.array([p.dt for p in part]))
            assert 1 <= len(got) <= len(part)
            states += list(got)
            phases += [core.phase] * len(got)
            n_runs += 1
            k += len(got)
            continue
        states.append(core.step_begin(s))
        phases.append(core.phase)
        k += 1
    return states, phases, n_runs


def _worst(a: list[Any], b: list[Any]) -> float:
    """The largest relative difference of two state sequences (q; v / max(1, |v|); lat, lon / max(0.1, |value|):
    0 before the first position; h / max(1, |h|); the gyro bias / 1e-3 and the attitude σ), or inf when a time
    differs."""
    w = 0.0
    for x, y in zip(a, b, strict=True):
        if x.t != y.t:
            return math.inf
        d = [np.asarray(getattr(x, f)) - np.asarray(getattr(y, f)) for f in ("q_nb", "vel_ned", "gyro_bias", "std_att")]
        v = float(np.max(np.abs(np.asarray(x.vel_ned))))
        w = max(
            w,
            float(np.max(np.abs(d[0]))),
            float(np.max(np.abs(d[1]))) / max(1.0, v),
            abs(x.lat - y.lat) / max(abs(x.lat), 0.1),
            abs(x.lon - y.lon) / max(abs(x.lon), 0.1),
            abs(x.h - y.h) / max(1.0, abs(x.h)),
            float(np.max(np.abs(d[2]))) / 1e-3,
            float(np.max(np.abs(d[3]))),
        )
    return w


def _levelled(core: NavCore) -> dict[str, Any]:
    """What the levelling left in the alignment (the window's sums, the motion test, the levelled tilt)."""
    a = core.align
    return {"t_win": a.t_win, "f_sum": a.f_sum, "w_sum": a.w_sum, "dev_w": a.dev_w, "dev_f": a.dev_f, "fb": a.fb,
            "C": a.C, "t_end": a.t_end, "moving": a.moving, "imu_moving": a.imu_moving}  # fmt: skip


@pytest.mark.parametrize(
    ("case", "rate", "seconds", "gnss_from", "mag", "time"),
    [
        # levelled when the IMU sees the turn (the window slides till then), then the heading phase; dt = 2⁻⁸ s, so
        # the window's length hits its bounds exactly (an off-by-one in the window shows)
        ("motion test", 256.0, 8.0, 0.0, False, 2.0),
        ("frozen window", 200.0, 10.0, 8.0, False, 2.0),  # the turn before any position: the window frozen till 8 s
        ("magnetometer", 256.0, 6.0, 0.0, True, 2.0),  # levelled at rest with the yaw: navigating from inside a run
        ("ring full", 1000.0, 12.0, 0.0, True, 10.0),  # 11.5 s of window at 1 kHz: more than INS_LEVEL_N samples
    ],
)
def test_the_c_levelling_is_navcores(case: str, rate: float, seconds: float, gnss_from: float, mag: bool,
                                     time: float) -> None:  # fmt: skip
    cfg = _cfg(time, mag)
    stream = _stream(rate, seconds, gnss_from, mag, turn=None if case == "ring full" else 6.0)
    py = NavCore(None, cfg)
    want, want_ph, _ = _drive(py, stream, runs=False)
    for runs in (True, False):
        c = CNavCore(None, cfg, fixed_step=False)
        nav = c._align  # the alignment's NavCore (kept after the hand-over)
        assert isinstance(nav.align, _CAlignment)
        got, got_ph, n_runs = _drive(c, stream, runs=runs)
        assert got_ph == want_ph  # the same sample ends the levelling (and, with the magnetometer, the alignment)
        assert "heading" in want_ph or "nav" in want_ph
        assert _worst(want, got) <= 1e-9, (case, runs)
        lv_py, lv_c = _levelled(py), _levelled(nav)
        for key, v in lv_py.items():
            assert np.allclose(lv_c[key], v, rtol=1e-9, atol=1e-15), (case, runs, key, lv_c[key], v)
        if nav.align.on_c:  # the motion test's statistics: plain products on both sides, the same bits on any host
            assert (lv_c["dev_w"], lv_c["dev_f"]) == (lv_py["dev_w"], lv_py["dev_f"]), (case, runs)
        assert nav.sensor_warnings == py.sensor_warnings and np.array_equal(nav.kf.qc, py.kf.qc)
        if runs:
            assert n_runs > (10 if case != "ring full" else 3)
        assert nav.align.on_c is (case != "ring full")  # a full ring: the window went on in Python
    if case == "motion test":
        assert py.align.imu_moving and py.align.moving
    if case == "frozen window":  # levelled at the first fix, 2 s after the IMU saw the turn
        assert py.align.imu_moving and want_ph[int(8.0 * rate)] == "heading" and want_ph[int(7.9 * rate)] == "level"


def test_a_run_stops_before_the_levelling_that_navigates() -> None:
    """With the magnetometer the levelling starts navigation: a run that reaches that sample stops before it (the
    states it returns were all published while aligning), and the next run levels at its first sample."""
    cfg = _cfg(2.0, True)
    stream = _stream(200.0, 5.0, 0.0, True)
    imu = [s for s in stream if s.kind == "imu"]
    c = CNavCore(None, cfg, fixed_step=False)
    for s in stream:  # the aiding samples first: the position and the field are known from the start
        if s.kind != "imu":
            c.fuse(s)
            if s.t > 100.1:
                break
    inc = np.array([np.r_[p.dtheta, p.dvel] for p in imu])
    t = np.array([p.t for p in imu])
    dt = np.array([p.dt for p in imu])
    first = c.run_states(inc, t, dt)
    assert 0 < len(first) < len(imu) and c.phase == "level" and not any(st.aligned for st in first)
    rest = c.run_states(inc[len(first) :], t[len(first) :], dt[len(first) :])
    assert c.phase == "nav" and len(rest) == len(imu) - len(first)
    assert c.run_out.shape == (len(rest), 32) and rest[0].t == t[len(first)]
