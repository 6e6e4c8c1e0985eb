"""The emergency yaw reset in navigation: a yaw that disagrees with the GNSS-velocity yaw bank
(:mod:`ins_hil.fusion.yaw_gsf`) while the vehicle moves and the GNSS velocity is rejected is reset to the bank's yaw.

The conditions are EKF2's (PX4 ``src/modules/ekf2/EKF/aid_sources/gnss/gps_control.cpp``: ``isYawFailure``,
``isYawEmergencyEstimateAvailable``, ``tryYawEmergencyReset`` and ``resetYawToEKFGSF``; the bank itself is
``src/modules/ekf2/EKF/yaw_estimator/EKFGSF_yaw.cpp``):

1. the bank is converged: its yaw variance below ``GsfConfig.converged_std``² (EKF2 ``EKFGSF_yaw_err_max``, 15°);
2. the filter's yaw is more than :data:`YAW_FAIL` (25°, EKF2's fixed threshold) from the bank's, and beyond
   :data:`YAW_GATE` of the two σ combined (a yaw the filter itself is unsure of is not a failure);
3. the filter has failed the GNSS velocity innovation test — or, on a ground vehicle, the non-holonomic
   constraint's (a wrong yaw turns an accepted GNSS velocity sideways in the body) — for :data:`RESET_DELAY` s
   (EKF2 ``EKFGSF_reset_delay``) while moving faster than ``alignment.gnss_yaw_speed`` (EKF2: in air);
4. at most one reset per :data:`MIN_INTERVAL` s, so the bank has time to improve if the last reset did not help.

A position-only receiver feeds the bank nothing: its yaw is guarded by the divergence reset (core_parts/gnss.py,
the INS velocity against the fixes' track).

The reset turns the attitude about down onto the bank's yaw with its variance, reopens the tilt, z gyro bias and
accelerometer bias σ (a yaw that ran off is a sign of a wrong z bias, and the tilt and accelerometer bias took in the
wrong yaw's innovations), and resets the velocity to the GNSS velocity and the position to the fix (EKF2's
``do_vel_pos_reset``). The bank runs from the first IMU sample, on the bias-compensated increments summed to
:data:`GSF_DT` s (the bank needs the low frequencies only; ≈ 0.3 ms per prediction in Python).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ins_hil.fusion.yaw_gsf import YawGsf
from ins_hil.nav.rotation import euler_from_quat
from ins_hil.types import GnssFix, ImuSample, Vec

if TYPE_CHECKING:
    from ins_hil.core_parts.config import NavConfig

#: rad: the smallest yaw disagreement called a failure (EKF2 ``isYawFailure``: 25°)
YAW_FAIL = math.radians(25.0)

#: the disagreement must also exceed this many σ of the filter's and the bank's yaw combined
YAW_GATE = 3.0

#: s the GNSS velocity (or position) must have been rejected for (EKF2 ``EKFGSF_reset_delay``, 1 s)
RESET_DELAY = 1.0

#: s between two resets at least
MIN_INTERVAL = 5.0

#: s: the bank's prediction interval (the IMU increments are summed to it)
GSF_DT = 0.1


class YawReset:
    """The yaw bank run alongside the filter and the reset decision (:meth:`check`)."""

    def __init__(self, cfg: NavConfig) -> None:
        self.cfg = cfg
        self.gsf = YawGsf()
        self._dth = np.zeros(3)
        self._dv = np.zeros(3)
        self._dt = 0.0
        self.rejected_since: float | None = None  # t (s) of the first GNSS rejection of the current run
        self.last_reset = -math.inf  # t (s) of the last reset
        self.speed = 0.0  # the last GNSS horizontal speed (m/s)

    def imu(self, imu: ImuSample, bg: Vec) -> None:
        """One IMU interval (body FRD increments) with the core's gyro bias estimate (rad/s)."""
        self._dth = self._dth + (imu.dtheta - bg * imu.dt)
        self._dv = self._dv + imu.dvel
        self._dt += imu.dt
        if self._dt >= GSF_DT - 1e-9:
            # a ground vehicle (NHC: its velocity is along body x) tells the bank its turns' centripetal acceleration
            self.gsf.predict(self._dth, self._dv, self._dt, self.speed if self.cfg.aids.nhc else 0.0)
            self._dth, self._dv, self._dt = np.zeros(3), np.zeros(3), 0.0

    def gnss(self, meas: GnssFix) -> None:
        """A GNSS fix: its velocity (when it has one) into the bank."""
        if meas.vel_ned is not None:
            v = np.asarray(meas.vel_ned, dtype=float)
            self.speed = math.hypot(float(v[0]), float(v[1]))
            self.gsf.fuse_velocity(v, meas.std_vel)

    def check(self, meas: GnssFix, rejected: bool, q_nb: Vec, var_yaw: float) -> float | None:
        """After a fix was fused: ``rejected`` when its velocity (or the NHC) failed the innovation test. Returns the
        yaw turn (rad) to apply when a reset is due, else None."""
        t = meas.t
        if not rejected:
            self.rejected_since = None
            return None
        if self.rejected_since is None:
            self.rejected_since = t
        gsf = self.gsf
        if meas.vel_ned is None or not gsf.converged() or t - self.last_reset < MIN_INTERVAL:
            return None
        if t - self.rejected_since < RESET_DELAY:
            return None
        v = np.asarray(meas.vel_ned, dtype=float)
        if math.hypot(float(v[0]), float(v[1])) < self.cfg.alignment.gnss_yaw_speed:
            return None
        dpsi = math.remainder(gsf.yaw - euler_from_quat(q_nb)[2], math.tau)
        if abs(dpsi) <= YAW_FAIL or dpsi * dpsi <= YAW_GATE**2 * (var_yaw + gsf.yaw_var):
            return None
        self.last_reset = t
        self.rejected_since = None
        return dpsi
