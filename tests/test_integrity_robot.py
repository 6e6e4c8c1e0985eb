"""Issue 40's targets on a simulated slow ground robot (0.3–0.6 m/s weaving ±5° about 88°, 0.5 m/s² and 0.5 °/s of white
vibration on a MEMS IMU at 100 Hz, 20-Hz position-only GNSS σ 2 cm with 1 % of fixes jumping 0.5–1 m, the drive's
outage protocol: 15-s outages every 45 s from 40 s): the yaw aligns from a track, the outages with NHC (and with the
longitudinal-acceleration prior: every outage below holding the last fix), and a tactical noise preset on this MEMS
IMU does not diverge (the start-up check inflates it to the measured noise)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ins_hil.core import NavConfig, NavCore
from ins_hil.core_parts import sensor_check
from ins_hil.core_parts.config import AidsConfig, AlignmentConfig
from ins_hil.datasets.config import GRADES
from ins_hil.fusion.ekf import FilterConfig
from ins_hil.nav import earth
from ins_hil.nav.rotation import euler_from_quat
from ins_hil.sim import sensors as se
from ins_hil.sim import trajectory as tr
from ins_hil.types import GnssFix, Vec

DEG = math.pi / 180
LAT, LON, H = math.radians(47.0), math.radians(8.0), 400.0
DT = 0.01
OUTAGES = ((40.0, 55.0), (85.0, 100.0), (130.0, 145.0), (175.0, 190.0), (220.0, 235.0))


def robot_profile(t: Vec) -> tr.Kinematics:
    """At rest 5 s, the speed ramps in over 2 s to 0.45 ± 0.15 m/s, heading 88° ± 5° (no sideslip, level)."""
    t = np.asarray(t, dtype=np.float64)
    x = np.clip((t - 5.0) / 2.0, 0.0, 1.0)
    on = x * x * (3.0 - 2.0 * x)
    don = np.where((x > 0.0) & (x < 1.0), 3.0 * x * (1.0 - x), 0.0)
    V = on * (0.45 + 0.15 * np.sin(0.4 * t))
    dV = don * (0.45 + 0.15 * np.sin(0.4 * t)) + on * 0.06 * np.cos(0.4 * t)
    psi = 88 * DEG + on * 5 * DEG * np.sin(0.3 * t)
    dpsi = don * 5 * DEG * np.sin(0.3 * t) + on * 5 * DEG * 0.3 * np.cos(0.3 * t)
    z = np.zeros_like(t)
    c, s = np.cos(psi), np.sin(psi)
    vel = np.stack([V * c, V * s, z], -1)
    acc = np.stack([dV * c - V * s * dpsi, dV * s + V * c * dpsi, z], -1)
    return tr.Kinematics(np.stack([z, z, psi], -1), np.stack([z, z, dpsi], -1), vel, acc)


@dataclasses.dataclass
class RobotRun:
    core: NavCore
    outages: list[tuple[float, float, float, float]]  # per outage: INS RMS, hold-the-last-fix RMS, end along/cross m
    max_err: float  # m, horizontal, while navigating


def run_robot(seed: int, filt: FilterConfig, seconds: float = 250.0, aids: AidsConfig | None = None) -> RobotRun:
    """The robot with ``filt`` (``aids``: NHC on by default; static alignment); horizontal errors every 0.1 s."""
    truth = tr.generate(robot_profile, seconds, DT, LAT, LON, H)
    rng = np.random.default_rng(seed)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=seed + 10)
    imu.dtheta = imu.dtheta + rng.normal(0.0, 0.5 * DEG, imu.dtheta.shape) * DT
    imu.dvel = imu.dvel + rng.normal(0.0, 0.5, imu.dvel.shape) * DT
    fixes = se.gnss_fixes(truth, se.GnssModel(rate=20, std_ne=0.02, std_d=0.04, outages=list(OUTAGES)), seed=seed + 20)
    m, n = earth.radii(LAT)
    gnss: list[GnssFix] = []
    for f in fixes:
        lat, lon = f.lat, f.lon
        if rng.random() < 0.01:
            a, size = rng.uniform(0.0, 2 * math.pi), rng.uniform(0.5, 1.0)
            lat += size * math.cos(a) / (m + H)
            lon += size * math.sin(a) / ((n + H) * math.cos(LAT))
        gnss.append(dataclasses.replace(f, lat=lat, lon=lon, vel_ned=None))
    aids = AidsConfig(nhc=True) if aids is None else aids
    cfg = NavConfig(filter=filt, alignment=AlignmentConfig(mode="static"), aids=aids)
    core = NavCore(None, cfg)
    fi = 0
    rows = []
    for k, s in enumerate(imu.samples()):
        core.step(s)
        while fi < len(gnss) and gnss[fi].t <= s.t + 1e-9:
            core.fuse(gnss[fi])
            fi += 1
        j = k + 1
        if j % 10 == 0 and core.phase == "nav":
            st = core.state()
            d = earth.ned_from_geodetic(st.lat, st.lon, st.h, truth.lat[j], truth.lon[j], truth.h[j])
            rows.append((s.t, j, float(d[0]), float(d[1])))
    arr = np.array(rows)
    out = []
    for a, b in OUTAGES:
        if b > seconds:
            break
        sel = (arr[:, 0] >= a) & (arr[:, 0] < b)
        ins = float(np.sqrt(np.mean(arr[sel, 2] ** 2 + arr[sel, 3] ** 2)))
        k0 = round((a - 0.05) / DT)  # the last fix before the outage
        hold = [earth.ned_from_geodetic(truth.lat[int(j)], truth.lon[int(j)], H, truth.lat[k0], truth.lon[k0], H)[:2]
                for j in arr[sel, 1]]  # fmt: skip
        held = float(np.sqrt(np.mean(np.sum(np.square(hold), axis=1))))
        jl = int(arr[sel, 1][-1])
        psi = truth.euler[jl, 2]
        e = arr[sel][-1, 2:4]
        along = float(e[0] * math.cos(psi) + e[1] * math.sin(psi))
        cross = float(-e[0] * math.sin(psi) + e[1] * math.cos(psi))
        out.append((ins, held, along, cross))
    return RobotRun(core, out, float(np.max(np.hypot(arr[:, 2], arr[:, 3]))))


def test_the_robot_with_nhc_dead_reckons_its_outages_below_holding_the_last_fix() -> None:
    """The MEMS preset with NHC: the cross-track error at each outage's end stays below 2 m (the yaw from the track and
    the NHC hold the heading: measured ≤ 1.6 m on 8 seeds), and the outage RMS is below holding the last fix in 9 of
    these 10 (on 8 seeds: 34 of 40). Without a model of the forward motion the misses are along the track, up to
    13 m (docs/integrity.md: the preset's gyro-bias random walk and the vibration-limited forward specific force);
    the longitudinal-acceleration prior (the test below) removes them."""
    grade = FilterConfig(**GRADES["mems"])
    runs = [run_robot(seed, grade) for seed in (0, 3)]
    res = [o for r in runs for o in r.outages]
    assert all(abs(cross) < 2.0 for *_, cross in res), res
    assert sum(ins < held for ins, held, *_ in res) >= 9, res
    assert float(np.mean([ins / held for ins, held, *_ in res])) < 0.5, res
    assert all(r.core.divergences == [] and r.core.yaw_resets == [] for r in runs)


@pytest.mark.parametrize("seed", range(8))
def test_with_the_longitudinal_acceleration_prior_every_outage_is_below_holding_the_last_fix(seed: int) -> None:
    """Issue 40's target on the 8 scored seeds (0–7; the setting was chosen on seeds 10–19): NHC and the ground-vehicle
    longitudinal-acceleration prior (``long_accel_std`` 0.1 m/s², above the robot's largest forward acceleration,
    0.06 m/s²; 1 Hz). Every 15-s outage's RMS is below holding the last fix (measured: at most 0.69 of it, along-track
    error at an outage's end ≤ 4.4 m; without the prior 6 of these 40 outages miss, up to 12.9 m along the track)."""
    aids = AidsConfig(nhc=True, long_accel_std=0.1, long_accel_rate=1.0)
    run = run_robot(seed, FilterConfig(**GRADES["mems"]), aids=aids)
    assert all(ins < held for ins, held, *_ in run.outages), run.outages
    assert all(abs(cross) < 2.5 for *_, cross in run.outages), run.outages
    assert run.core.divergences == [] and run.core.yaw_resets == []
    st = run.core.stats["long_accel"]
    assert st.accepted > 200 and st.rejected < 0.05 * st.accepted, (st.accepted, st.rejected)


@pytest.mark.parametrize("seed", [0, 2])
def test_a_tactical_preset_on_this_mems_imu_does_not_diverge(seed: int) -> None:
    """Issue 40 item 4: ``grade = "tactical"`` (FilterConfig's defaults) on the robot's vibrating MEMS IMU. The start-up
    check measures ≈ 20× the preset's gyro and accelerometer noise at rest, says so and inflates the densities: no
    divergence, ≈ 1 % of fixes rejected (the jumps), every outage below holding the last fix. Without the inflation
    (the check's factor out of reach) the same run diverged 1–4 times, rejected ≈ 10 % of the fixes and ended outages
    up to 20 m off."""
    run = run_robot(seed, FilterConfig())
    core = run.core
    assert any(w.startswith("noise:") for w in core.sensor_warnings), core.sensor_warnings
    assert core.divergences == [], core.divergences
    st = core.stats["gnss_pos"]
    assert st.rejected < 0.03 * (st.accepted + st.rejected), (st.rejected, st.accepted)
    assert run.max_err < 8.0


def test_without_the_inflation_the_tactical_preset_diverges(monkeypatch: pytest.MonkeyPatch) -> None:
    """The finding behind the test above: the same run with the noise check's factor out of reach (a warning-only
    check would do the same) diverges."""
    monkeypatch.setattr(sensor_check, "NOISE_FACTOR", math.inf)
    run = run_robot(2, FilterConfig())
    assert len(run.core.divergences) >= 1
    st = run.core.stats["gnss_pos"]
    assert st.rejected > 0.05 * (st.accepted + st.rejected)


def test_the_robot_aligns_its_yaw_from_a_track() -> None:
    """The yaw at alignment is within 10° of the truth, taken after the robot moved (not from one pair of fixes)."""
    truth = tr.generate(robot_profile, 12.0, DT, LAT, LON, H)
    run_core = run_robot(4, FilterConfig(**GRADES["mems"]), seconds=12.0).core
    assert run_core.phase == "nav"
    err = math.remainder(euler_from_quat(run_core.ins.state.q_nb)[2] - truth.euler[-1, 2], math.tau)
    assert abs(err) < 10 * DEG, math.degrees(err)
