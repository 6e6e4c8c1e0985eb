"""Flight without absolute aiding (``NavConfig.hold.enabled``): while no GNSS position has been fused for
``hold.after`` s, a constant-position / zero-velocity pseudo-measurement every ``1 / hold.rate`` s, with the
large σ ``hold.std`` (m) and ``hold.vel_std`` (m/s), at the last fused GNSS position (or ``alignment.position``
when there has been none). It keeps the tilt observable in a hover (tilt error → horizontal acceleration →
velocity, which the zero-velocity row sees), as PX4 EKF2's fake-position fusion does; it cannot tell a
vehicle that moves, so it is for hovering and ground tests, not for a car in a tunnel (its σ bounds the pull)."""

from __future__ import annotations

import math

import numpy as np

from ins_hil.fusion import measurements as mm
from ins_hil.fusion.ekf import StateIndex
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.types import Vec

from .config import NavConfig
from .contract import Measurement


class NoAidHold:
    """When the hold is due, and its two measurements (kind ``hold``)."""

    def __init__(self, c: NavConfig) -> None:
        self.cfg = c
        self.t_gnss = -math.inf  # last fused GNSS position (s)
        self.t_hold = -math.inf  # last hold update (s)
        self.pos: tuple[float, float, float] | None = None  # where to hold (rad, rad, m)
        if c.alignment.position is not None:
            lat, lon, h = c.alignment.position
            self.pos = (math.radians(lat), math.radians(lon), float(h))

    def gnss(self, t: float, lat: float, lon: float, h: float) -> None:
        """A GNSS position was fused at ``t``: the hold waits, and would hold there."""
        self.t_gnss = t
        self.pos = (lat, lon, h)

    def due(self, t: float) -> bool:
        """Whether a hold update is due at ``t`` (s)."""
        c = self.cfg
        return self.pos is not None and t - self.t_gnss >= c.hold.after and t - self.t_hold >= 1.0 / c.hold.rate - 1e-9

    def measurements(self, t: float, s: StrapdownState, C: Vec, idx: StateIndex) -> list[Measurement]:
        """The position row (at the IMU: no lever arm) and, with ``hold.vel_std`` > 0, the zero-velocity row."""
        assert self.pos is not None
        c = self.cfg
        self.t_hold = t
        z, H = mm.gnss_position(idx, C, s.lat, s.lon, s.h, *self.pos, np.zeros(3), None)
        out = [Measurement("hold", z, H, np.full(3, c.hold.std**2), c.hold.gate)]
        if c.hold.vel_std > 0:
            zv, Hv = mm.zero_velocity(idx, s.vel_ned)
            out.append(Measurement("hold", zv, Hv, np.full(3, c.hold.vel_std**2), c.hold.gate))
        return out
