"""The core's own input contract (ins_hil.core_parts.contract): NavCore.step / fuse refuse what they cannot
integrate or fuse with a one-line ValueError and leave the core as it was, even though the runtime's
validation boundary (ins_hil.validation) filters every sample before it. Before, a NaN increment gave a NaN
state, dt = 0 a ZeroDivisionError, an infinite fix a math-domain ValueError deep in the filter."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from ins_hil.core import NavCore
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.types import BaroSample, GnssFix, ImuSample, MagSample

G = 9.80665
DT = 0.01
NAN, INF = math.nan, math.inf


def _core(n: int = 20) -> NavCore:
    """A core at rest after ``n`` good steps (time n·DT)."""
    c = NavCore(StrapdownState(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), math.radians(50.0), 0.5, 100.0, 0.0))
    for k in range(n):
        c.step(_imu((k + 1) * DT))
    return c


def _imu(t: float, dt: float = DT, a: Any = (0.0, 0.0, 0.0), v: Any = None) -> ImuSample:
    v = (0.0, 0.0, -G * DT) if v is None else v
    return ImuSample(t=t, dt=dt, dtheta=np.array(a, dtype=float), dvel=np.array(v, dtype=float))


def _same(a: NavCore, b: NavCore) -> bool:
    sa, sb = a.state(), b.state()
    return bool(
        sa.t == sb.t and np.array_equal(sa.q_nb, sb.q_nb) and np.array_equal(sa.vel_ned, sb.vel_ned)
        and (sa.lat, sa.lon, sa.h) == (sb.lat, sb.lon, sb.h) and np.array_equal(a.kf.P, b.kf.P)
    )  # fmt: skip


BAD_IMU = {
    "dtheta NaN": (_imu(0.21, a=(0.0, NAN, 0.0)), "imu.dtheta"),
    "dvel inf": (_imu(0.21, v=(0.0, 0.0, INF)), "imu.dvel"),
    "dt 0": (_imu(0.21, dt=0.0), "imu.dt"),
    "dt negative": (_imu(0.21, dt=-DT), "imu.dt"),
    "dt NaN": (_imu(0.21, dt=NAN), "imu.dt"),
    "dt inf": (_imu(0.21, dt=INF), "imu.dt"),
    "t NaN": (_imu(NAN), "imu.t"),
    "t inf": (_imu(INF), "imu.t"),
    "dtheta 2 numbers": (ImuSample(t=0.21, dt=DT, dtheta=np.zeros(2), dvel=np.zeros(3)), "imu.dtheta"),
    "dvel list with None": (ImuSample(t=0.21, dt=DT, dtheta=np.zeros(3), dvel=[0.0, None, 0.0]), "imu.dvel"),  # type: ignore[arg-type]
}


@pytest.mark.parametrize("case", list(BAD_IMU))
@pytest.mark.parametrize("entry", ["step", "step_begin"])
def test_step_refuses_what_it_cannot_integrate_in_one_line_and_changes_nothing(case: str, entry: str) -> None:
    s, what = BAD_IMU[case]
    c, ref = _core(), _core()
    with pytest.raises(ValueError, match=f"NavCore.step: {what}") as e:
        getattr(c, entry)(s)
    assert "\n" not in str(e.value)
    assert _same(c, ref)
    st = c.step(_imu(0.21))  # and the core goes on
    assert st.t == pytest.approx(0.21) and np.all(np.isfinite(st.q_nb)) and math.isfinite(st.lat)


def _fix(**kw: Any) -> GnssFix:
    a: dict[str, Any] = dict(t=0.2, lat=math.radians(50.0), lon=0.5, h=100.0, vel_ned=np.zeros(3))
    a.update(kw)
    return GnssFix(**a)


BAD_AID = {
    "fix t NaN": (_fix(t=NAN), "GnssFix.t"),
    "fix lat inf": (_fix(lat=INF), "GnssFix.lat"),
    "fix lon NaN": (_fix(lon=NAN), "GnssFix.lon"),
    "fix h NaN": (_fix(h=NAN), "GnssFix.h"),
    "fix std_ne NaN": (_fix(std_ne=NAN), "GnssFix.std_ne"),
    "fix std_d negative": (_fix(std_d=-1.0), "GnssFix.std_d"),
    "fix std_vel inf": (_fix(std_vel=INF), "GnssFix.std_vel"),
    "fix vel NaN": (_fix(vel_ned=np.array((0.0, NAN, 0.0))), "GnssFix.vel_ned"),
    "baro inf": (BaroSample(t=0.2, pressure=INF), "BaroSample pressure"),
    "baro nothing carried": (BaroSample(t=0.2, pressure=NAN), "BaroSample pressure"),
    "baro altitude -inf": (BaroSample(t=0.2, pressure=NAN, altitude=-INF), "BaroSample pressure"),
    "mag NaN": (MagSample(t=0.2, field_b=np.array((2e-5, NAN, 4e-5))), "MagSample.field_b"),
    "mag t inf": (MagSample(t=INF, field_b=np.array((2e-5, 0.0, 4e-5))), "MagSample.t"),
}


@pytest.mark.parametrize("case", list(BAD_AID))
def test_fuse_refuses_what_it_cannot_fuse_in_one_line_and_changes_nothing(case: str) -> None:
    m, what = BAD_AID[case]
    c, ref = _core(), _core()
    with pytest.raises(ValueError, match=f"NavCore.fuse: {what}") as e:
        c.fuse(m)
    assert "\n" not in str(e.value)
    assert _same(c, ref)
    c.fuse(_fix())  # a good fix is still fused
    assert math.isfinite(c.state().lat) and c.stats["gnss_pos"].last_nis >= 0


def test_good_inputs_still_pass_the_contract() -> None:
    """Lists for vectors, a baro carrying only an altitude, a fix without velocity, σ = 0 (floored by the core),
    a velocity-only GNSS record (lat = NaN; lon and h unused)."""
    c = _core()
    c.step(ImuSample(t=0.21, dt=DT, dtheta=[0.0, 0.0, 0.0], dvel=[0.0, 0.0, -G * DT]))  # type: ignore[arg-type]
    c.fuse(BaroSample(t=0.21, pressure=NAN, altitude=1.0))
    c.fuse(_fix(t=0.21, vel_ned=None, std_vel=0.0))
    c.fuse(MagSample(t=0.21, field_b=[2e-5, 0.0, 4e-5]))  # type: ignore[arg-type]
    c.fuse(_fix(t=0.21, lat=NAN, lon=NAN, h=NAN))
    st = c.state()
    assert np.all(np.isfinite(st.q_nb)) and math.isfinite(st.h)
