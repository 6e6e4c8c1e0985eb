"""Impossible inputs through the pipeline and the core guard: the state stays finite, navigation
continues, every rejection is counted once with its reason, a core failure is recovered from.

Scenarios of issue 18 ("values that are impossible but accepted", in the pipeline/core), on the real
pipeline with both cores (Python NavCore, C CNavCore)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from ins_hil.core import NavConfig, NavCore
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.runtime.pipeline import Pipeline, PipelineConfig
from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, NavState
from ins_hil.validation import Limits

G = 9.80665
DT = 0.01  # 100 Hz keeps the tests fast; the checks scale with the learnt period
LAT, LON, H = 50.0, 30.0, 100.0
CORES = ["python", "c"]


def state_ok(st: NavState) -> bool:
    """Every number of the published state finite, |q| = 1 (independent of the pipeline's own guard)."""
    vals = [st.lat, st.lon, st.h, *st.q_nb, *st.vel_ned, *st.std_pos, *st.std_vel, *st.std_att]
    return bool(np.all(np.isfinite(vals))) and abs(float(np.linalg.norm(st.q_nb)) - 1.0) < 1e-6


def _cfg(core: str = "python", **kw: Any) -> PipelineConfig:
    return PipelineConfig(core=core, init="config", init_lat_deg=LAT, init_lon_deg=LON, init_h=H, **kw)


class Run:
    """A stationary vehicle at (LAT, LON, H): level IMU at 100 Hz, GNSS at 5 Hz, through one pipeline."""

    def __init__(self, core: str = "python", **kw: Any) -> None:
        self.p = Pipeline(_cfg(core, **kw))
        self.t = 0.0
        self.states: list[NavState] = []
        self.gnss_t = 0.0

    def imu(self, dt: float = DT, dtheta: Any = None, dvel: Any = None, t: float | None = None) -> NavState | None:
        self.t = self.t + DT if t is None else t
        s = ImuSample(
            t=self.t, dt=dt, dtheta=np.zeros(3) if dtheta is None else np.array(dtheta, dtype=float),
            dvel=np.array((0.0, 0.0, -G * DT)) if dvel is None else np.array(dvel, dtype=float),
        )  # fmt: skip
        st = self.p.imu(s)
        self.p.work()
        if st is not None:
            self.states.append(st)
        return st

    def fix(self, **kw: Any) -> GnssFix:
        args: dict[str, Any] = dict(t=self.t, lat=math.radians(LAT), lon=math.radians(LON), h=H,
                                    vel_ned=np.zeros(3), std_ne=1.0, std_d=2.0, std_vel=0.1)  # fmt: skip
        args.update(kw)
        g = GnssFix(**args)
        self.p.aid(g)
        return g

    def run(self, seconds: float, gnss: bool = True) -> None:
        for k in range(round(seconds / DT)):
            self.imu()
            if gnss and k % 20 == 19:
                self.fix()
        self.p.flush()

    @property
    def counts(self) -> dict[str, int]:
        return self.p.counts

    def assert_navigating(self) -> NavState:
        """The state is finite, at the true place, and the pipeline still produces states."""
        n = len(self.states)
        self.run(1.0)
        assert len(self.states) > n, "navigation stopped"
        st = self.states[-1]
        assert state_ok(st)
        assert abs(math.degrees(st.lat) - LAT) < 1e-4 and abs(math.degrees(st.lon) - LON) < 1e-4
        assert abs(st.h - H) < 5.0
        return st


@pytest.mark.parametrize("core", CORES)
@pytest.mark.parametrize(
    ("sample", "reason"),
    [
        ({"dtheta": (1e30, 0.0, 0.0)}, "imu_rate"),
        ({"dvel": (0.0, 1e30, 0.0)}, "imu_accel"),
        ({"dtheta": (1e308, 1e308, 0.0)}, "imu_rate"),
        ({"dt": 1e9}, "imu_dt"),
        ({"dt": 0.0}, "imu_dt"),
        ({"dt": 1.4e-45}, "imu_dt"),  # a DroneCAN integration_interval of one denormal
        ({"dtheta": (math.nan, 0.0, 0.0)}, "imu_nonfinite"),
        ({"dvel": (0.0, 0.0, -math.inf)}, "imu_nonfinite"),
    ],
)
def test_impossible_imu_sample_is_rejected_once_and_navigation_continues(
    core: str, sample: dict[str, Any], reason: str
) -> None:
    r = Run(core)
    r.run(2.0)
    assert r.imu(**sample) is None
    r.fix()  # a GNSS update right after it (LinAlgError after dt = 1.4e-45 before)
    st = r.assert_navigating()
    assert r.counts["reject_" + reason] == 1
    assert sum(v for k, v in r.counts.items() if k.startswith("reject_")) == 1
    assert "core_exception" not in r.counts and "core_bad_state" not in r.counts
    assert st.t == pytest.approx(r.t)


@pytest.mark.parametrize("core", CORES)
@pytest.mark.parametrize(
    ("fix", "reason"),
    [
        ({"h": math.nan}, "gnss_nonfinite"),
        ({"h": math.inf}, "gnss_nonfinite"),
        ({"lat": math.nan}, "gnss_nonfinite"),
        ({"vel_ned": np.array((math.nan, 0.0, 0.0))}, "gnss_velocity"),
        ({"vel_ned": np.array((0.0, math.inf, 0.0))}, "gnss_velocity"),
        ({"vel_ned": np.array((1e4, 0.0, 0.0))}, "gnss_velocity"),
        ({"std_ne": math.nan}, "gnss_std"),
        ({"std_d": math.inf}, "gnss_std"),
        ({"std_vel": -1.0}, "gnss_std"),
        ({"std_ne": 0.0}, "gnss_std"),
        ({"lat": 2.0}, "gnss_position"),
        ({"lon": -4.0}, "gnss_position"),
        ({"h": 1e6}, "gnss_height"),
        ({"fix_type": FixType.NO_FIX}, "gnss_fix_type"),
        ({"fix_type": FixType.FIX_2D}, "gnss_fix_type"),
    ],
)
def test_impossible_gnss_fix_is_rejected_once_and_navigation_continues(
    core: str, fix: dict[str, Any], reason: str
) -> None:
    r = Run(core)
    r.run(2.0)
    fused = r.counts.get("fused_GnssFix", 0)
    r.imu()
    r.fix(**fix)
    r.p.flush()
    assert r.counts.get("fused_GnssFix", 0) == fused  # not fused
    r.assert_navigating()
    assert r.counts["reject_" + reason] == 1
    assert sum(v for k, v in r.counts.items() if k.startswith("reject_")) == 1
    assert r.counts["fused_GnssFix"] > fused  # the good fixes after it are


@pytest.mark.parametrize("core", CORES)
@pytest.mark.parametrize(
    ("baro", "reason"),
    [
        ({"pressure": math.nan}, "baro_nonfinite"),
        ({"pressure": 1e5, "altitude": math.inf}, "baro_nonfinite"),
        ({"pressure": 5e6}, "baro_range"),
        ({"pressure": -1.0}, "baro_range"),
        ({"pressure": math.nan, "altitude": 1e7}, "baro_range"),
    ],
)
def test_impossible_baro_is_rejected_once(core: str, baro: dict[str, Any], reason: str) -> None:
    r = Run(core)
    r.run(1.0)
    r.imu()
    r.p.aid(BaroSample(t=r.t, **baro))
    r.assert_navigating()
    assert r.counts["reject_" + reason] == 1
    assert "fused_BaroSample" not in r.counts


@pytest.mark.parametrize("core", CORES)
def test_resent_gnss_fix_is_fused_once(core: str) -> None:
    r = Run(core)
    r.run(1.0)
    n = r.counts["fused_GnssFix"]
    r.imu()
    g = r.fix()
    r.p.aid(GnssFix(**{k: getattr(g, k) for k in g.__slots__}))  # the same fix again (a re-sent frame)
    r.p.flush()
    assert r.counts["fused_GnssFix"] == n + 1
    assert r.counts["reject_gnss_time"] == 1


@pytest.mark.parametrize(
    ("core", "fix_type"),
    [("python", FixType.NO_FIX), ("c", FixType.NO_FIX), ("python", FixType.FIX_3D), ("c", FixType.FIX_3D)],
)
def test_twelve_junk_fixes_at_zero_zero_do_not_move_the_solution(core: str, fix_type: FixType) -> None:
    """NO_FIX fixes are rejected by the validation boundary; 3-D junk by the gate, and no GNSS reset
    (neither core accepts a fix over its gate after 10 rejections unless the rejected fixes pass a
    consistency test of their own: the C core's own reset is held by its wrapper, ins_hil.cref)."""
    r = Run(core)
    r.run(2.0)
    for _ in range(12):
        for _ in range(20):
            r.imu()
        r.fix(lat=0.0, lon=0.0, h=0.0, fix_type=fix_type)
    r.p.flush()
    st = r.states[-1]
    assert abs(math.degrees(st.lat) - LAT) < 1e-4 and abs(math.degrees(st.lon) - LON) < 1e-4
    if fix_type == FixType.NO_FIX:
        assert r.counts["reject_gnss_fix_type"] == 12
    r.assert_navigating()


def _core_at(lat_deg: float, kind: str = "python") -> Any:
    s = StrapdownState(np.array([1.0, 0, 0, 0]), np.zeros(3), math.radians(lat_deg), math.radians(LON), H, 0.0)
    if kind == "c":
        from ins_hil.cref import CNavCore

        return CNavCore(s, NavConfig())
    return NavCore(s, NavConfig())


def _accepted(core: Any) -> int:
    """GNSS positions the core accepted (NavCore's stats, the C core's counter)."""
    if isinstance(core, NavCore):
        return core.stats["gnss_pos"].accepted
    return int(core._core.ekf.accepted[0])


def _drive_core(core: Any, fixes: list[GnssFix], t0: float) -> None:
    t = t0
    k = 0
    for f in fixes:
        while t < f.t - 1e-9:
            t = round(t + DT, 9)
            k += 1
            core.step(ImuSample(t=t, dt=DT, dtheta=np.zeros(3), dvel=np.array((0.0, 0.0, -G * DT))))
        core.fuse(f)


@pytest.mark.parametrize("kind", ["python", "c"])
def test_gnss_reset_needs_fixes_consistent_with_each_other(kind: str) -> None:
    """Rejected fixes that agree with each other (stationary, 200 m north of the INS) reset the filter;
    fixes that jump about by 200 m (not consistent with their own zero velocity) never do."""
    lat = math.radians(LAT)
    off = 200.0 / 6.37e6
    ok = _core_at(LAT, kind)
    fixes = [GnssFix(t=0.2 * (k + 1), lat=lat + off, lon=math.radians(LON), h=H, vel_ned=np.zeros(3),
                     std_ne=1.0, std_d=2.0, std_vel=0.1) for k in range(12)]  # fmt: skip
    _drive_core(ok, fixes, 0.0)
    assert _accepted(ok) >= 1  # the reset took the consistent fixes
    assert abs(ok.state().lat - (lat + off)) * 6.37e6 < 20.0
    bad = _core_at(LAT, kind)
    jumpy = [GnssFix(t=0.2 * (k + 1), lat=lat + off * (1 if k % 2 else -1), lon=math.radians(LON), h=H,
                     vel_ned=np.zeros(3), std_ne=1.0, std_d=2.0, std_vel=0.1) for k in range(12)]  # fmt: skip
    _drive_core(bad, jumpy, 0.0)
    assert _accepted(bad) == 0
    assert abs(bad.state().lat - lat) * 6.37e6 < 1.0


# -- the core guard: a core failure the validation boundary lets through (limits opened up) ------------
WIDE = {"limits": Limits(gyro_range_dps=1.7e308, accel_range_g=1.7e308)}  # × margin: no finite increment out of range


@pytest.mark.parametrize("core", CORES)
@pytest.mark.parametrize("dtheta", [(1e30, 0.0, 0.0), (1e308, 1e308, 0.0), (0.0, 0.0, 1e200)])
def test_core_failure_is_counted_reported_and_recovered_from(core: str, dtheta: tuple[float, ...]) -> None:
    """Increments that break the core (NaN state, or ValueError inside it) with the validation limits
    opened up: the pipeline catches it, counts it, reports a FaultEvent 'core', restarts the core from
    the last good state, and navigation continues; the fault clears after a second of good states."""
    r = Run(core, **WIDE)
    r.run(2.0)
    good = r.states[-1]
    r.imu(dtheta=dtheta)
    faults = r.counts.get("core_exception", 0) + r.counts.get("core_bad_state", 0)
    assert faults == 1
    assert r.counts["core_restart"] == 1
    ev = r.p.drain_events()
    assert [(e.sensor, e.cleared) for e in ev] == [("core", False)]
    st = r.assert_navigating()
    assert st.t > good.t
    r.run(1.0)
    assert [(e.sensor, e.cleared) for e in r.p.drain_events()] == [("core", True)]
    assert all(state_ok(s) for s in r.states)


@pytest.mark.parametrize("core", CORES)
def test_second_core_failure_before_clearing_realigns_from_gnss(core: str) -> None:
    r = Run(core, **WIDE)
    r.run(2.0)
    r.imu(dtheta=(1e30, 0.0, 0.0))
    r.imu()
    r.imu(dtheta=(1e30, 0.0, 0.0))  # again, before the first fault cleared
    assert r.counts["core_restart"] == 1 and r.counts["core_realign"] == 1
    assert r.p.core is None
    n_init = r.counts.get("init_gnss", 0)
    r.run(1.0)  # the next 3-D fix re-aligns
    assert r.counts["init_gnss"] == n_init + 1 and r.p.core is not None
    r.assert_navigating()
    # one report (and its clearing a second after the re-alignment), not one per failure
    core_ev = [(e.sensor, e.cleared) for e in r.p.drain_events() if e.sensor == "core"]
    assert core_ev == [("core", False), ("core", True)]


def test_exception_in_a_gnss_update_is_recovered_from() -> None:
    """The shortest interval the validation boundary lets through (its 1e-5 s floor, the dt band opened up)
    and a GNSS update right after it (a denormal dt made this update raise LinAlgError): the state stays
    finite and navigation continues."""
    r = Run("python", limits=Limits(imu_dt_min_periods=1e-9))
    r.run(2.0)
    r.imu(dt=1.1e-5)  # the floor of the validation boundary: the core must cope or be recovered
    r.fix()
    r.p.flush()
    r.assert_navigating()
    assert all(state_ok(s) for s in r.states)
