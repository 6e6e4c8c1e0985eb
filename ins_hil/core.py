"""NavCore: the one synchronous entry point the runtime and replay call.

``step(imu)`` runs mechanization (and, once the fusion filter is plugged in,
the EKF predict and FDI monitor) on every IMU sample; ``fuse(sample)`` applies
a GNSS/baro/magnetometer measurement at its time of validity. Pure and
deterministic: no I/O, no clock, no asyncio; the same input sequence gives
the same output, bit for bit.
"""

from __future__ import annotations

import numpy as np

from ins_hil.nav.mechanization import StrapdownNED, StrapdownState
from ins_hil.types import BaroSample, GnssFix, ImuSample, MagSample, NavState


class NavCore:
    """Strapdown navigation core (mechanization only until fusion lands)."""

    def __init__(self, initial: StrapdownState) -> None:
        self.ins = StrapdownNED(initial.copy())
        self._last_t: float | None = None

    def step(self, imu: ImuSample) -> NavState:
        """Propagate with one IMU interval; returns the current state."""
        self.ins.step(imu.dtheta, imu.dvel, imu.dt)
        self.ins.state.t = imu.t
        return self.state()

    def fuse(self, meas: GnssFix | BaroSample | MagSample) -> None:
        """Apply an aiding measurement (no-op until the fusion filter is wired in)."""
        return None

    def state(self) -> NavState:
        s = self.ins.state
        return NavState(
            t=s.t,
            q_nb=s.q_nb.copy(),
            vel_ned=s.vel_ned.copy(),
            lat=s.lat,
            lon=s.lon,
            h=s.h,
            accel_b=np.zeros(3),
            aligned=True,
        )
