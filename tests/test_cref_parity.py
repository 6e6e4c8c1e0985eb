"""The C core's settings beyond the plain GNSS/baro filter, each held against the Python ``NavCore``.

For every setting the C core supports (GNSS lever arm, GNSS σ scale, vibration noise, ``cov_every``, NHC,
ZUPT/ZARU) and the combination a shipped config uses, the same simulated stream runs through ``NavCore``
and ``CNavCore`` (double) with the measurements fed at their step; attitude, velocity, position agree to
≤ 1e-9 relative over the whole run, the biases to ≤ 1e-6, the σ to ≤ 1e-6, and the gate counters exactly.
The float build's distance from the double build is bounded (the bound of docs/ref_core.md).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts.config import AidsConfig, GnssConfig
from ins_hil.cref import CNavCore
from ins_hil.fusion.ekf import FilterConfig
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.sim.sensors import (
    GnssModel,
    baro_samples,
    corrupt_imu,
    earth_field_ned,
    gnss_fixes,
    mag_samples,
    mems_accel,
    mems_gyro,
)
from ins_hil.sim.trajectory import car_profile, generate, uav_profile
from ins_hil.types import GnssFix, ImuSample

LAT0, LON0, H0 = math.radians(50.45), math.radians(30.52), 180.0
DT = 0.02
LEVER = np.array((0.3, -0.2, -0.5))


class Stream:
    def __init__(self, kind: str, duration: float, gnss: bool = True, mag: bool = False) -> None:
        prof = car_profile(speed=12.0, t_start=5.0, t_stop=60.0) if kind == "car" else uav_profile()
        self.truth = generate(prof, duration, DT, LAT0, LON0, H0)
        rng = np.random.default_rng(3)
        self.imu = corrupt_imu(self.truth, mems_gyro(rng), mems_accel(rng), seed=4)
        fixes = gnss_fixes(self.truth, GnssModel(rate=5.0, lever_arm_b=LEVER), seed=5)
        baro = baro_samples(self.truth, rate=10.0, std=0.5, seed=6)
        # a magnetometer at 10 Hz off the IMU grid (its samples are rolled back to their step)
        mags = (
            [dataclasses.replace(m, t=m.t - 0.013) for m in mag_samples(self.truth, rate=10.0, seed=7)] if mag else []
        )
        self.meas = sorted([*(fixes if gnss else []), *baro, *mags], key=lambda m: m.t)
        tr = self.truth
        self.init = StrapdownState(tr.q_nb[0].copy(), tr.vel_ned[0].copy(), LAT0, LON0, H0, tr.t[0])

    def sample(self, k: int) -> ImuSample:
        return ImuSample(t=float(self.imu.t[k]), dt=DT, dtheta=self.imu.dtheta[k], dvel=self.imu.dvel[k])


@pytest.fixture(scope="module")
def uav() -> Stream:
    return Stream("uav", 240.0)


@pytest.fixture(scope="module")
def car() -> Stream:
    return Stream("car", 90.0)


def _cfg(filter_kw: dict[str, Any] | None = None, **kw: Any) -> NavConfig:
    return NavConfig(filter=FilterConfig(**(filter_kw or {})), **kw)


def run_both(
    st: Stream, cfg: NavConfig, precision: str = "double", latency: float = 0.0
) -> tuple[np.ndarray, NavCore, CNavCore]:
    """Both cores over the stream; worst [|Δq|, rel v, rel lat/lon, rel h, rel bias, rel σ] over the run.
    ``latency``: the GNSS fixes arrive this long (s) after their time of validity (delayed fusion)."""
    py = NavCore(st.init, cfg)
    c = CNavCore(st.init, cfg, dt=DT, precision=precision)  # type: ignore[arg-type]
    worst = np.zeros(6)
    j = 0
    arrivals = sorted(
        [(m.t + (latency if isinstance(m, GnssFix) else 0.0), i) for i, m in enumerate(st.meas)]
    )  # fmt: skip
    for k in range(len(st.imu.t)):
        s = st.sample(k)
        py.step(s)
        c.step(s)
        while j < len(arrivals) and arrivals[j][0] <= s.t + 1e-9:
            m = st.meas[arrivals[j][1]]
            py.fuse(m)
            c.fuse(m)
            j += 1
        if k % 25 == 24:
            a, b = py.state(), c.state()
            bias_a = np.r_[a.gyro_bias, a.accel_bias]
            bias_b = np.r_[b.gyro_bias, b.accel_bias]
            sd_a = np.r_[a.std_pos, a.std_vel, a.std_att]
            sd_b = np.r_[b.std_pos, b.std_vel, b.std_att]
            worst = np.maximum(worst, [
                float(np.max(np.abs(a.q_nb - b.q_nb))),
                float(np.max(np.abs(a.vel_ned - b.vel_ned)) / max(1.0, float(np.max(np.abs(a.vel_ned))))),
                max(abs(a.lat - b.lat) / abs(a.lat), abs(a.lon - b.lon) / abs(a.lon)),
                abs(a.h - b.h) / max(1.0, abs(a.h)),
                float(np.max(np.abs(bias_a - bias_b) / np.maximum(1e-6, np.abs(bias_a)))),
                float(np.max(np.abs(sd_a / sd_b - 1.0))),
            ])  # fmt: skip
    return worst, py, c


def _counts(py: NavCore, c: CNavCore, kinds: tuple[str, ...]) -> tuple[list[int], list[int]]:
    e = c._core.ekf
    names = ("gnss_pos", "gnss_vel", "baro", "nhc", "zupt", "mag", "hold")
    pa = [py.stats[k].accepted for k in kinds] + [py.stats[k].rejected for k in kinds]
    ca = [int(e.accepted[names.index(k)]) for k in kinds] + [int(e.rejected[names.index(k)]) for k in kinds]
    return pa, ca


def _assert_parity(worst: np.ndarray) -> None:
    assert np.all(worst[:4] <= 1e-9), worst
    assert np.all(worst[4:] <= 1e-6), worst


UAV_CASES = {
    "lever_arm": _cfg(gnss=GnssConfig(lever_arm_b=LEVER)),
    "std_scale": _cfg(gnss=GnssConfig(std_scale=2.0)),
    "vibration": _cfg({"gyro_vib_gain": 0.4, "accel_vib_gain": 0.6}),
    "cov_every": _cfg({"cov_every": 10}),
    # px4_quad's C-supported part: vibration (the mems preset's gains) and σ × 2
    "px4_quad_like": _cfg({"gyro_vib_gain": 0.5, "accel_vib_gain": 0.5}, gnss=GnssConfig(std_scale=2.0)),
}


@pytest.mark.parametrize("case", sorted(UAV_CASES))
def test_c_matches_python_per_setting_uav(uav: Stream, case: str) -> None:
    cfg = UAV_CASES[case]
    worst, py, c = run_both(uav, cfg)
    pa, ca = _counts(py, c, ("gnss_pos", "gnss_vel", "baro"))
    assert pa == ca
    assert sum(pa[:3]) > 3000  # the filter really fuses
    _assert_parity(worst)
    # the setting really acts: the C state differs from the plain filter's
    b, p0 = c.state(), _run_c(uav, NavConfig())
    assert max(abs(b.h - p0.h), float(np.max(np.abs(b.std_vel / p0.std_vel - 1.0)))) > 1e-4


def _run_c(st: Stream, cfg: NavConfig) -> Any:
    c = CNavCore(st.init, cfg, dt=DT)
    j = 0
    for k in range(len(st.imu.t)):
        c.step(st.sample(k))
        while j < len(st.meas) and st.meas[j].t <= st.imu.t[k] + 1e-9:
            c.fuse(st.meas[j])
            j += 1
    return c.state()


CAR_CASES = {
    "nhc": _cfg(aids=AidsConfig(nhc=True)),
    "nhc_lateral_only": _cfg(aids=AidsConfig(nhc=True, nhc_vertical=False)),
    "zupt": _cfg(aids=AidsConfig(zupt=True)),
    "zupt_no_zaru": _cfg(aids=AidsConfig(zupt=True, zaru=False)),
    # drive0708's C-supported part: lever arm, vibration, NHC + ZUPT
    "drive_like": _cfg(
        {"gyro_vib_gain": 0.4, "accel_vib_gain": 0.6},
        gnss=GnssConfig(lever_arm_b=LEVER),
        aids=AidsConfig(nhc=True, zupt=True),
    ),
    # drive0708's filter: the 21 states (gyro and accelerometer scale factors) with its own priors
    "scale_factors": _cfg(
        {"scale_factors": True, "init_accel_sf": (0.01, 0.002, 0.002), "gyro_vib_gain": 0.4},
        gnss=GnssConfig(lever_arm_b=LEVER),
        aids=AidsConfig(nhc=True, zupt=True),
    ),
    "scale_factors_cov_every": _cfg({"scale_factors": True, "cov_every": 4}, aids=AidsConfig(nhc=True)),
}


@pytest.mark.parametrize("case", sorted(CAR_CASES))
def test_c_matches_python_per_setting_car(car: Stream, case: str) -> None:
    cfg = CAR_CASES[case]
    worst, py, c = run_both(car, cfg)
    kinds = ("gnss_pos", "gnss_vel", "baro", "nhc", "zupt")
    pa, ca = _counts(py, c, kinds)
    assert pa == ca
    if cfg.aids.nhc:
        assert py.stats["nhc"].accepted > 300
    if cfg.aids.zupt:
        assert py.stats["zupt"].accepted > 20
    _assert_parity(worst)


@pytest.mark.parametrize("latency", [0.11, 0.25])
def test_delayed_fusion_rolls_back_like_python(uav: Stream, latency: float) -> None:
    """GNSS fixes arriving ``latency`` s after their time (px4_quad's 0.11 s): both cores roll back. At 0.25 s
    (longer than the 0.2-s fix interval) a roll-back replays the span of the previous one (the log's order:
    the measurements of a step before its IMU sample, DelayedHistory.sort_log)."""
    cfg = UAV_CASES["px4_quad_like"]
    worst, py, c = run_both(uav, cfg, latency=latency)
    pa, ca = _counts(py, c, ("gnss_pos", "gnss_vel", "baro"))
    assert pa == ca and pa[0] > 1000
    assert int(c._hist.rollbacks) >= pa[0] + pa[3] - 2  # every fix (but the first) was fused at its step
    _assert_parity(worst)


def test_velocity_delay_and_ground_aids_like_python(car: Stream) -> None:
    """drive0708's C-supported part with its velocity delay (0.13 s: a roll-back for every velocity)."""
    cfg = dataclasses.replace(CAR_CASES["drive_like"], gnss=GnssConfig(lever_arm_b=LEVER, vel_delay=0.13))
    worst, py, c = run_both(car, cfg)
    pa, ca = _counts(py, c, ("gnss_pos", "gnss_vel", "baro", "nhc", "zupt"))
    assert pa == ca and py.stats["gnss_vel"].accepted > 300
    assert int(c._hist.rollbacks) >= py.stats["gnss_vel"].accepted
    _assert_parity(worst)


@pytest.mark.parametrize("yaw_gsf", [False, True])
def test_alignment_then_c_like_python(car: Stream, yaw_gsf: bool) -> None:
    """The static alignment (levelling at rest; yaw from the GNSS course, or from the GNSS-velocity yaw bank as
    px4_quad) in NavCore, then the C core from its state: as NavCore over the whole run (with drive0708's lever
    arm, vibration, NHC, ZUPT)."""
    base = CAR_CASES["drive_like"]
    al = dataclasses.replace(base.alignment, mode="static", time=3.0, yaw_gsf=yaw_gsf)
    cfg = dataclasses.replace(base, alignment=al)
    worst, py, c = run_both(car, cfg)
    assert py.phase == "nav" and c.phase == "nav" and c._align is None
    pa, ca = _counts(py, c, ("gnss_pos", "gnss_vel", "baro", "nhc", "zupt"))
    assert pa == ca and pa[0] > 300
    _assert_parity(worst)


@pytest.fixture(scope="module")
def uav_mag() -> Stream:
    return Stream("uav", 120.0, mag=True)


@pytest.fixture(scope="module")
def hover() -> Stream:
    return Stream("uav", 40.0, gnss=False, mag=True)


def _static(cfg: NavConfig, **kw: Any) -> NavConfig:
    return dataclasses.replace(cfg, alignment=dataclasses.replace(cfg.alignment, mode="static", time=5.0, **kw))


def test_magnetometer_like_python(uav_mag: Stream) -> None:
    """ardupilot_copter's set: static alignment (yaw from the magnetometer), vibration, the magnetometer against
    its reference (samples off the IMU grid: rolled back one step), fixes 0.11 s late (a roll-back through the
    magnetometer's)."""
    mag = dataclasses.replace(NavConfig().mag, ref_ned=earth_field_ned())
    cfg = _static(_cfg({"gyro_vib_gain": 0.5, "accel_vib_gain": 0.5}, mag=mag))
    worst, py, c = run_both(uav_mag, cfg, latency=0.11)
    pa, ca = _counts(py, c, ("gnss_pos", "gnss_vel", "baro", "mag"))
    assert pa == ca and py.stats["mag"].accepted > 900
    _assert_parity(worst)


def test_no_aid_hold_like_python(hover: Stream) -> None:
    """px4_hover's set: no GNSS, the constant-position hold at the configured start, the magnetometer, baro."""
    mag = dataclasses.replace(NavConfig().mag, ref_ned=earth_field_ned())
    hold = dataclasses.replace(NavConfig().hold, enabled=True, after=0.0)
    pos = (math.degrees(LAT0), math.degrees(LON0), H0)
    cfg = _static(_cfg({"gyro_vib_gain": 0.5, "accel_vib_gain": 0.5}, mag=mag, hold=hold), position=pos)
    worst, py, c = run_both(hover, cfg)
    pa, ca = _counts(py, c, ("baro", "mag", "hold"))
    assert pa == ca and py.stats["hold"].accepted > 100
    _assert_parity(worst)


@pytest.mark.parametrize("case", ["drive_like", "scale_factors"])
def test_float_build_with_the_settings_is_bounded(car: Stream, case: str) -> None:
    """Float vs double with lever arm, vibration, NHC, ZUPT, and with the 21 states (scale factors): the bound
    docs/ref_core.md gives."""
    cfg = CAR_CASES[case]
    d = CNavCore(car.init, cfg, dt=DT)
    f = CNavCore(car.init, cfg, dt=DT, precision="float")
    worst = np.zeros(3)
    j = 0
    for k in range(len(car.imu.t)):
        s = car.sample(k)
        a, b = d.step(s), f.step(s)
        while j < len(car.meas) and car.meas[j].t <= s.t + 1e-9:
            d.fuse(car.meas[j])
            f.fuse(car.meas[j])
            j += 1
        a, b = d.state(), f.state()
        dp = earth.ned_from_geodetic(b.lat, b.lon, b.h, a.lat, a.lon, a.h)
        dq, dv = float(np.max(np.abs(a.q_nb - b.q_nb))), float(np.max(np.abs(a.vel_ned - b.vel_ned)))
        worst = np.maximum(worst, [dq, dv, float(np.linalg.norm(dp))])
    assert worst[0] < 1e-3 and worst[1] < 0.05 and worst[2] < 0.5, worst


def test_still_refused_settings_name_themselves(car: Stream) -> None:
    bad = {
        "filter.gyro_gsens": _cfg({"gyro_gsens": True}),
        "filter.mag_bias": _cfg({"mag_bias": True}),
        "filter.wind_states": _cfg({"wind_states": True}, aids=AidsConfig(drag=True)),
        "aids.nhc_lever_b": _cfg(aids=AidsConfig(nhc=True, nhc_lever_b=np.array((1.0, 0.0, 0.0)))),
        "aids.long_accel_std": _cfg(aids=AidsConfig(nhc=True, long_accel_std=0.1)),
        "adaptive": _cfg(adaptive=True),
    }
    for name, cfg in bad.items():
        with pytest.raises(ValueError, match=rf"not supported by the C core: {name.replace('.', '[.]')}"):
            CNavCore(car.init, cfg)


def test_gate_events_like_python(uav: Stream) -> None:
    """The gates of each update (``cref_gfuse_*``) give NavCore's fault events: GNSS positions 50 m off for 3 fixes
    (rejected, then accepted again), velocities 5 m/s off for 2, a baro 30 m off, with the velocity delay (the
    position and the velocity as two updates); test ratios of the same groups."""
    cfg = _cfg(gnss=GnssConfig(vel_delay=0.1))
    meas = []
    for m in uav.meas:
        if isinstance(m, GnssFix) and 100.0 <= m.t < 100.7:
            m = dataclasses.replace(m, lat=m.lat + 50.0 / earth.A_WGS84)
        elif isinstance(m, GnssFix) and 150.0 <= m.t < 150.5 and m.vel_ned is not None:
            m = dataclasses.replace(m, vel_ned=m.vel_ned + 5.0)
        elif m.kind == "baro" and 120.0 <= m.t < 120.1:
            m = dataclasses.replace(m, altitude=m.altitude + 30.0)
        meas.append(m)
    py, c = NavCore(uav.init, cfg), CNavCore(uav.init, cfg, dt=DT)
    ev_py: list[tuple[Any, ...]] = []
    ev_c: list[tuple[Any, ...]] = []
    j = 0
    for k in range(len(uav.imu.t)):
        s = uav.sample(k)
        py.step(s)
        c.step(s)
        while j < len(meas) and meas[j].t <= s.t + 1e-9:
            py.fuse(meas[j])
            c.fuse(meas[j])
            j += 1
            assert c.state().test_ratios.keys() == py.state().test_ratios.keys()
        for ev, core in ((ev_py, py), (ev_c, c)):
            ev += [(e.t, e.sensor, e.mode, e.detail, e.magnitude, e.isolated, e.cleared) for e in core.drain_events()]
    # NavCore's event of a first rejection carries the largest innovation (the C core's: NaN)
    assert [e[:4] + e[5:] for e in ev_py] == [e[:4] + e[5:] for e in ev_c]
    assert {e[3].split(" ")[0] for e in ev_py} >= {"gnss_pos", "gnss_vel", "baro"} and len(ev_py) >= 6
