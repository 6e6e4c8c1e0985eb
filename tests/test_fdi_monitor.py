"""Runtime FDI monitor: every failure mode on every configuration, reconfiguration, re-admission."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ins_hil.fdi.geometry import CONFIGS, SensorGeometry, by_name, skewed6
from ins_hil.fdi.monitor import FdiConfig, FdiMonitor
from ins_hil.fdi.parity import cone_geometry
from ins_hil.nav.mechanization import StrapdownNED, StrapdownState
from ins_hil.nav.rotation import quat_angle_between
from ins_hil.sim.faults import FaultSpec, inject
from ins_hil.sim.redundant import RedundantSeries, simulate
from ins_hil.sim.sensors import ImuErrorModel, mems_accel, mems_gyro
from ins_hil.sim.trajectory import TruthSeries, generate, uav_profile
from ins_hil.types import FaultMode, ImuSample

DT = 0.005
T_FAULT = 2.5
DURATION = 6.0
DEG = math.pi / 180
G, A = mems_gyro(), mems_accel()
SIG = {"gyro": G.noise_density / math.sqrt(DT), "accel": A.noise_density / math.sqrt(DT)}
MODES = [
    FaultMode.STEP_BIAS,
    FaultMode.RAMP,
    FaultMode.STUCK,
    FaultMode.DROPOUT,
    FaultMode.NOISE_BURST,
    FaultMode.SATURATION,
    FaultMode.SCALE_FACTOR,
]
# classification is best effort: modes that look alike over a short window are accepted
ACCEPT = {
    FaultMode.STEP_BIAS: {FaultMode.STEP_BIAS},
    FaultMode.RAMP: {FaultMode.RAMP, FaultMode.STEP_BIAS},
    FaultMode.STUCK: {FaultMode.STUCK, FaultMode.SATURATION},
    FaultMode.DROPOUT: {FaultMode.DROPOUT},
    FaultMode.NOISE_BURST: {FaultMode.NOISE_BURST},
    FaultMode.SATURATION: {FaultMode.SATURATION, FaultMode.STUCK},
    FaultMode.SCALE_FACTOR: {FaultMode.SCALE_FACTOR, FaultMode.RAMP, FaultMode.STEP_BIAS},
}
# worst acceptable time from onset to exclusion (s)
LIMIT = {
    FaultMode.STEP_BIAS: 20 * DT,
    FaultMode.RAMP: 3.0,
    FaultMode.STUCK: 12 * DT,
    # a dropout is declared after FdiConfig.dropout_samples missing epochs (shorter gaps are bridged)
    FaultMode.DROPOUT: FdiConfig.dropout_samples * DT,
    FaultMode.NOISE_BURST: 0.5,
    FaultMode.SATURATION: 2.0,
    FaultMode.SCALE_FACTOR: 2.0,
}


def config(geo: SensorGeometry, **kw) -> FdiConfig:
    return FdiConfig(geo, DT, G.noise_density, A.noise_density, G.bias_instability, A.bias_instability, **kw)


@pytest.fixture(scope="module")
def truth() -> TruthSeries:
    # manoeuvring from the start: turns of period 20 s (rates up to ~28 °/s, bank up to 45°)
    return generate(uav_profile(turn_period=20.0, t_takeoff=0.0, ramp=2.0), DURATION, DT, 0.8, 0.5, 100.0)


@pytest.fixture(scope="module")
def series(truth) -> dict[str, RedundantSeries]:
    return {name: simulate(truth, make(), seed=11) for name, make in CONFIGS.items()}


def fault_size(mode: FaultMode, group: str, clean: Vec) -> float:
    sig = SIG[group]
    if mode in (FaultMode.STEP_BIAS, FaultMode.NOISE_BURST):
        return 10 * sig
    if mode == FaultMode.RAMP:
        return 10 * DEG / 60 if group == "gyro" else 0.05  # per second
    if mode == FaultMode.SATURATION:
        on = clean[int(T_FAULT / DT) :] / DT
        return 0.5 * float(np.median(np.abs(on)))  # clip at half the sensor's typical reading
    if mode == FaultMode.SCALE_FACTOR:
        return 0.05 if group == "gyro" else 0.02
    return 0.0


Vec = np.ndarray


def run(mon: FdiMonitor, s: RedundantSeries) -> tuple[Vec, Vec]:
    est_g = np.empty((len(s.t), 3))
    est_a = np.empty((len(s.t), 3))
    for k in range(len(s.t)):
        est_g[k], est_a[k], _ = mon.process_arrays(s.t[k], DT, s.gyro[k], s.accel[k])
    return est_g, est_a


@pytest.mark.parametrize("group", ["gyro", "accel"])
@pytest.mark.parametrize("mode", MODES, ids=lambda m: m.name)
@pytest.mark.parametrize("cname", list(CONFIGS))
def test_mode_on_config(series, truth, cname: str, mode: FaultMode, group: str) -> None:
    base = series[cname]
    geo = base.geometry
    # each sensor in turn across the matrix
    sensor = (MODES.index(mode) + list(CONFIGS).index(cname) + (group == "accel") * 3) % geo.n
    arr = base.gyro if group == "gyro" else base.accel
    if mode == FaultMode.SCALE_FACTOR:
        # a scale-factor error is only observable on a sensor that reads something: skip axes whose
        # signal times the scale error stays below 3σ (e.g. a lateral accelerometer in coordinated turns)
        while 0.02 * float(np.median(np.abs(arr[int(T_FAULT / DT) :, sensor]))) / DT < 3 * SIG[group]:
            sensor = (sensor + 1) % geo.n
    clean = arr[:, sensor]
    spec = FaultSpec(mode, sensor, T_FAULT, fault_size(mode, group, clean), group=group)
    s = inject(base, spec, seed=5)
    mon = FdiMonitor(config(geo))
    est_g, est_a = run(mon, s)
    evs = [e for e in mon.events if not e.cleared]
    assert evs, f"{mode.name} on {geo.row_name(group, sensor)} not detected"
    ev = evs[0]
    assert ev.t >= T_FAULT, f"false alarm before the fault: {ev}"
    assert ev.isolated and ev.sensor == geo.row_name(group, sensor), ev
    assert ev.t - T_FAULT <= LIMIT[mode] + 1e-9, f"isolated after {ev.t - T_FAULT:.3f} s"
    assert ev.mode in ACCEPT[mode], ev
    assert len(evs) == 1, evs  # nothing else excluded
    assert mon.excluded == [geo.row_name(group, sensor)]
    # reconstruction from the healthy sensors after exclusion tracks the truth
    est = est_g if group == "gyro" else est_a
    ref = truth.dtheta if group == "gyro" else truth.dvel
    after = np.asarray(s.t) > ev.t + 0.1
    err = (est[after] - ref[after]) / DT
    assert np.sqrt(np.mean(err**2)) < 1.5 * SIG[group]  # LS of ≥ 4 healthy sensors: ≈ σ per axis


@pytest.mark.parametrize("cname", list(CONFIGS))
def test_nominal_no_false_alarm(series, cname: str) -> None:
    mon = FdiMonitor(config(series[cname].geometry))
    run(mon, series[cname])
    assert mon.events == []


def test_process_samples_and_dropout_by_absence(series) -> None:
    s = series["dual_imu"]
    m1, m2 = FdiMonitor(config(s.geometry)), FdiMonitor(config(s.geometry))
    for k in range(200):
        out, ev = m1.process(s.epoch(k))
        dth, dv, _ = m2.process_arrays(s.t[k], DT, s.gyro[k], s.accel[k])
        assert np.array_equal(out.dtheta, dth) and np.array_equal(out.dvel, dv) and out.t == s.t[k]
        assert ev == []
    ev = []
    for k in range(200, 200 + FdiConfig.dropout_samples):  # IMU 1 missing: bridged, then a DROPOUT
        out, e = m1.process(s.epoch(k)[:1])
        assert np.isfinite(out.dtheta).all()
        ev += e
    assert {e.sensor for e in ev} == {"imu1.gyro", "imu1.accel"} and all(e.mode == FaultMode.DROPOUT for e in ev)
    assert np.isfinite(out.dtheta).all()
    with pytest.raises(ValueError, match="imu_id 7"):
        bad = s.epoch(210)
        bad[0].imu_id = 7
        m1.process(bad)


def test_readmission_after_noise_burst(series) -> None:
    s = series["skew6"]
    f = inject(s, FaultSpec(FaultMode.NOISE_BURST, 2, 1.0, 10 * SIG["gyro"], duration=0.5), seed=1)
    mon = FdiMonitor(config(s.geometry, readmit_after=1.0))
    run(mon, f)
    names = [(e.sensor, e.mode, e.cleared) for e in mon.events]
    assert names == [("gyro[2]", FaultMode.NOISE_BURST, False), ("gyro[2]", FaultMode.NOISE_BURST, True)]
    cleared = mon.events[1]
    assert 2.5 <= cleared.t <= 4.0
    assert mon.excluded == []


def test_detection_only_with_four_sensors(truth) -> None:
    a = cone_geometry(4)
    geo = SensorGeometry("cone4", "array", a, a.copy())
    s = inject(simulate(truth, geo, seed=3), FaultSpec(FaultMode.STEP_BIAS, 1, T_FAULT, 20 * SIG["gyro"]))
    mon = FdiMonitor(config(geo))
    run(mon, s)
    assert len(mon.events) == 1
    ev = mon.events[0]
    assert not ev.isolated and ev.sensor == "gyro" and ev.t >= T_FAULT
    assert mon.excluded == []


def test_exclude_whole_imu(series) -> None:
    s = inject(series["triple_imu"], FaultSpec(FaultMode.STEP_BIAS, 4, T_FAULT, 10 * SIG["gyro"]))
    mon = FdiMonitor(config(s.geometry, exclude_unit=True))
    run(mon, s)
    assert sorted(mon.excluded) == ["imu1.gyro.x", "imu1.gyro.y", "imu1.gyro.z"]
    assert [e.sensor for e in mon.events] == ["imu1.gyro.y"]


def test_config_errors_name_the_key() -> None:
    with pytest.raises(ValueError, match="p_false_alarm"):
        config(skewed6(), p_false_alarm=0.0)
    with pytest.raises(ValueError, match=r"FdiConfig\.dt"):
        FdiConfig(skewed6(), 0.0, 1e-3, 1e-3)
    with pytest.raises(ValueError, match="persistence"):
        config(skewed6(), persistence=0)
    with pytest.raises(ValueError, match="unknown redundant configuration"):
        by_name("nope")


@pytest.mark.parametrize(
    "mode,size", [(FaultMode.STEP_BIAS, 50 * SIG["gyro"]), (FaultMode.RAMP, 20 * DEG / 60)], ids=["step", "ramp"]
)
def test_closed_loop_navigation_after_isolation(truth, mode: FaultMode, size: float) -> None:
    """Mechanization on the monitor's output vs the same run with the failed sensor simply absent
    (the leak compensation takes back what the fault put into the output before its exclusion)."""
    geo = skewed6()
    base = simulate(truth, geo, seed=21)
    f = inject(base, FaultSpec(mode, 0, T_FAULT, size))
    mon = FdiMonitor(config(geo))
    Zg_abs = np.linalg.pinv(geo.gyro_axes[1:])
    Za_abs = np.linalg.pinv(geo.accel_axes[1:])

    def nav() -> StrapdownNED:
        return StrapdownNED(
            StrapdownState(truth.q_nb[0].copy(), truth.vel_ned[0].copy(), truth.lat[0], truth.lon[0], truth.h[0])
        )

    n_mon, n_abs, n_raw = nav(), nav(), nav()
    Zg_all, Za_all = np.linalg.pinv(geo.gyro_axes), np.linalg.pinv(geo.accel_axes)
    for k in range(len(f.t)):
        dth, dv, _ = mon.process_arrays(f.t[k], DT, f.gyro[k], f.accel[k])
        n_mon.step(dth, dv, DT)
        n_abs.step(Zg_abs @ f.gyro[k, 1:], Za_abs @ f.accel[k, 1:], DT)
        n_raw.step(Zg_all @ f.gyro[k], Za_all @ f.accel[k], DT)
    q_true = truth.q_nb[-1]
    e_mon = quat_angle_between(n_mon.state.q_nb, q_true)
    e_abs = quat_angle_between(n_abs.state.q_nb, q_true)
    e_raw = quat_angle_between(n_raw.state.q_nb, q_true)
    assert e_mon <= 1.5 * e_abs + 1e-5  # ≤ 1.5× the error without the sensor (plus a µrad floor)
    assert e_raw > 5 * e_mon  # and far better than using the faulty sensor
    v_mon = np.linalg.norm(n_mon.state.vel_ned - truth.vel_ned[-1])
    v_abs = np.linalg.norm(n_abs.state.vel_ned - truth.vel_ned[-1])
    assert v_mon <= 1.5 * v_abs + 1e-3


def test_monitor_ignores_quantised_but_consistent_noise_free_input(truth) -> None:
    """Noise-free consistent outputs never trip the parity tests (p = 0, eq. 5.12)."""
    geo = skewed6()
    s = simulate(truth, geo, ImuErrorModel(), ImuErrorModel(), seed=0)
    mon = FdiMonitor(config(geo, stuck_samples=0))
    est_g, _ = run(mon, s)
    assert mon.events == []
    assert np.allclose(est_g, truth.dtheta, atol=1e-15)


def test_leak_compensation_repairs_integrated_angle(series) -> None:
    """What a slow fault put into the output before its exclusion is taken back once: the integrated
    delta angle (≈ attitude) matches the run with the sensor absent to noise level only with compensation."""
    s = inject(series["skew6"], FaultSpec(FaultMode.RAMP, 3, T_FAULT, 5 * DEG / 60))
    others = [0, 1, 2, 4, 5]
    absent = s.gyro[:, others] @ np.linalg.pinv(s.geometry.gyro_axes[others]).T
    diff = {}
    for comp in (True, False):
        mon = FdiMonitor(config(s.geometry, compensate_leak=comp))
        est_g, _ = run(mon, s)
        assert mon.excluded == ["gyro[3]"]
        diff[comp] = float(np.linalg.norm((est_g - absent).sum(axis=0)))
    # uncompensated: the leaked angle (ramp over ~1 s before exclusion: ~1e-4 rad); compensated: noise only
    assert diff[False] > 3e-5
    assert diff[True] < 0.3 * diff[False]


def test_closed_loop_with_navcore_and_gnss(truth) -> None:
    """Monitor → NavCore (EKF) with GNSS: after the isolation the fused solution matches the run
    with the failed gyro absent; without FDI the fault corrupts it."""
    from ins_hil.core import NavCore
    from ins_hil.sim.sensors import GnssModel, gnss_fixes

    geo = skewed6()
    s = inject(simulate(truth, geo, seed=4), FaultSpec(FaultMode.STEP_BIAS, 2, T_FAULT, 100 * SIG["gyro"]))
    fixes = gnss_fixes(truth, GnssModel(rate=5.0), seed=2)
    mon = FdiMonitor(config(geo))
    init = StrapdownState(truth.q_nb[0].copy(), truth.vel_ned[0].copy(), truth.lat[0], truth.lon[0], truth.h[0])
    cores = [NavCore(init) for _ in range(3)]
    others = [0, 1, 3, 4, 5]
    Zg_abs, Za_abs = np.linalg.pinv(geo.gyro_axes[others]), np.linalg.pinv(geo.accel_axes[others])
    Zg, Za = np.linalg.pinv(geo.gyro_axes), np.linalg.pinv(geo.accel_axes)
    fi = 0
    for k in range(len(s.t)):
        tk = float(s.t[k])
        dth, dv, _ = mon.process_arrays(tk, DT, s.gyro[k], s.accel[k])
        incs = [(dth, dv), (Zg_abs @ s.gyro[k, others], Za_abs @ s.accel[k, others]), (Zg @ s.gyro[k], Za @ s.accel[k])]
        for c, (a, b) in zip(cores, incs):
            c.step(ImuSample(tk, DT, a, b))
        while fi < len(fixes) and fixes[fi].t <= tk + 1e-9:
            for c in cores:
                c.fuse(fixes[fi])
            fi += 1
    assert [e.sensor for e in mon.events] == ["gyro[2]"]
    err = [quat_angle_between(c.state().q_nb, truth.q_nb[-1]) for c in cores]
    assert err[0] <= 1.5 * err[1] + 2e-4  # within 1.5× (plus 0.01°) of the sensor-absent run
    assert err[2] > 3 * err[0]


def test_lost_frames_on_separate_links_are_bridged_not_excluded(series, truth) -> None:
    """Dual IMU on two links: single lost frames (one unit, then the other) exclude nothing and the
    output stays finite and on the truth; a gap of dropout_samples epochs is a DROPOUT, after which
    a lost frame of the remaining unit is bridged by the dropped-out unit's sample when it has one."""
    s = series["dual_imu"]
    mon = FdiMonitor(config(s.geometry))
    lost = {400: (0, 1, 2), 401: (3, 4, 5), 600: (3, 4, 5), 900: (0, 1, 2)}  # rows of imu0 / imu1
    for k in range(1000):
        yg, ya = s.gyro[k].copy(), s.accel[k].copy()
        for r in lost.get(k, ()):
            yg[r] = ya[r] = np.nan
        g, a, _ = mon.process_arrays(s.t[k], DT, yg, ya)
        assert np.all(np.isfinite(g)) and np.all(np.isfinite(a)), k
        if k in lost:
            assert np.allclose(g / DT, truth.dtheta[k] / DT, atol=0.05), (k, g / DT, truth.dtheta[k] / DT)
    assert mon.events == [] and mon.excluded == []
    # imu1 silent for dropout_samples epochs: excluded as DROPOUT ...
    for k in range(1000, 1000 + FdiConfig.dropout_samples):
        yg, ya = s.gyro[k].copy(), s.accel[k].copy()
        yg[3:] = ya[3:] = np.nan
        mon.process_arrays(s.t[k], DT, yg, ya)
    assert {e.mode for e in mon.events} == {FaultMode.DROPOUT} and all("imu1" in x for x in mon.excluded)
    # ... then imu0 loses one frame while imu1 is back: imu1's sample bridges the epoch
    k = 1000 + FdiConfig.dropout_samples
    yg, ya = s.gyro[k].copy(), s.accel[k].copy()
    yg[:3] = ya[:3] = np.nan
    g, a, _ = mon.process_arrays(s.t[k], DT, yg, ya)
    assert np.all(np.isfinite(g)) and np.allclose(g / DT, truth.dtheta[k] / DT, atol=0.05)


@pytest.mark.parametrize("cname", [*sorted(CONFIGS), "cone4"])
@pytest.mark.parametrize("exclude_unit", [False, True])
def test_warm_up_exercises_the_exclusion_path_and_leaves_the_monitor_untouched(cname: str, exclude_unit: bool) -> None:
    """FdiMonitor runs its isolation/classification path once at construction on a throwaway group
    (so the first real fault pages in no new code); it must run on every configuration and touch nothing."""
    from ins_hil.fdi.monitor import _warm_up

    a4 = cone_geometry(4)
    geo = SensorGeometry("cone4", "array", a4, a4.copy()) if cname == "cone4" else by_name(cname)
    for classify_time in (0.0, 1.0):
        cfg = FdiConfig(geo, DT, G.noise_density, A.noise_density, exclude_unit=exclude_unit,
                        classify_time=classify_time)  # fmt: skip
        assert _warm_up(cfg, geo.gyro_axes, cfg.gyro_noise, cfg.gyro_bias) == 2  # both history layouts
        mon = FdiMonitor(cfg)
        assert mon.excluded == [] and mon.events == [] and not mon.gyro.pending and not mon.gyro.leak_on
