"""The start-up check of the IMU against the configuration (issue 40): from the first seconds of samples, the
mounting (where the accelerometer says "down" is, against the body's z) and the noise (the measured per-sample
spread at rest against the filter's ``gyro_arw`` / ``accel_vrw``). A mismatch is a one-line warning naming the
likely fix; a noise preset far below what the IMU shows is inflated to the measured density (a filter whose
process noise is several times too small rejects good fixes and diverges), never silently used."""

from __future__ import annotations

import math

import numpy as np

from ins_hil.nav import alignment
from ins_hil.types import ImuSample

from .config import NavConfig

#: s of samples the check takes (at most; the levelling window's length when shorter)
CHECK_S = 2.0

#: rad: a resting tilt beyond this is called a mounting error (vehicles rest within ~20° of level)
MOUNT_TILT = 30.0 * math.pi / 180.0

#: the measured white noise beyond this many times the preset's is "far above" it: a process-noise variance
#: FACTOR² (9×) too small lets the state σ shrink 3× below its error, and the gates reject good measurements
NOISE_FACTOR = 3.0


class SensorCheck:
    """Accumulates the first :data:`CHECK_S` s of IMU samples; :meth:`add` returns True once it has judged.
    ``warnings`` holds the one-line findings; ``inflate`` the factors (gyro, accel) to apply to the filter's
    white-noise densities (1.0 = none)."""

    def __init__(self, cfg: NavConfig) -> None:
        self.cfg = cfg
        self.window = min(CHECK_S, max(0.5, cfg.alignment.time))
        self.n = 0
        self.t = 0.0
        self.dt = 0.0
        self.sf = np.zeros(3)
        self.sf2 = np.zeros(3)
        self.sw = np.zeros(3)
        self.sw2 = np.zeros(3)
        self.warnings: list[str] = []
        self.inflate = (1.0, 1.0)
        self.tilt = math.nan  # rad: the resting tilt found

    def add(self, imu: ImuSample) -> bool:
        """One sample (body FRD increments over ``imu.dt``); True when the window is full and judged."""
        if not imu.dt > 0.0:
            return False
        f = np.asarray(imu.dvel, dtype=np.float64) / imu.dt
        w = np.asarray(imu.dtheta, dtype=np.float64) / imu.dt
        self.sf += f
        self.sf2 += f * f
        self.sw += w
        self.sw2 += w * w
        self.n += 1
        self.t += imu.dt
        if self.t < self.window:
            return False
        self.dt = self.t / self.n
        self._judge()
        return True

    def _judge(self) -> None:
        n = self.n
        f, w = self.sf / n, self.sw / n
        sd_f = np.sqrt(np.maximum(self.sf2 / n - f * f, 0.0))
        sd_w = np.sqrt(np.maximum(self.sw2 / n - w * w, 0.0))
        a = self.cfg.alignment
        g = float(np.linalg.norm(f))
        if abs(g - 9.80665) > 1.5:  # accelerating (or a wrong unit): no resting direction to judge
            return
        roll, pitch = alignment.coarse_level(f)
        self.tilt = math.acos(max(-1.0, min(1.0, -float(f[2]) / g)))
        if self.tilt > MOUNT_TILT:
            r90 = 90 * round(math.degrees(roll) / 90) % 360
            p90 = 90 * round(math.degrees(pitch) / 90)
            fix = " and ".join(s for s in (f"roll {r90}°" if r90 else "", f"pitch {p90}°" if p90 else "") if s)
            self.warnings.append(
                f"mounting: at start the IMU rests at roll {math.degrees(roll):.0f}°, pitch {math.degrees(pitch):.0f}° "
                f"(gravity along body {np.round(-f / g, 2).tolist()}): its mounting likely misses "
                f"{fix or 'a rotation'} (sensor → body)"
            )
        at_rest = float(np.linalg.norm(w)) < a.still_gyro and float(np.max(sd_w)) < a.still_gyro and float(
            np.max(sd_f)) < a.still_accel  # fmt: skip
        fc = self.cfg.filter
        if not at_rest or fc.gyro_vib_gain > 0.0 or fc.accel_vib_gain > 0.0:
            return  # moving, or the filter grows its noise with the measured vibration already
        root_dt = math.sqrt(self.dt)
        meas_g = float(np.sqrt(np.mean(sd_w**2))) * root_dt  # rad/s/√Hz
        meas_a = float(np.sqrt(np.mean(sd_f**2))) * root_dt  # m/s²/√Hz
        kg = meas_g / fc.gyro_arw if fc.gyro_arw > 0 else 1.0
        ka = meas_a / fc.accel_vrw if fc.accel_vrw > 0 else 1.0
        if kg > NOISE_FACTOR or ka > NOISE_FACTOR:
            self.inflate = (max(1.0, kg), max(1.0, ka))
            self.warnings.append(
                f"noise: at rest the IMU shows {kg:.0f}× the configured gyro_arw and {ka:.0f}× accel_vrw (the sensor "
                "grade preset is far below this IMU): the filter uses the measured densities; set the right grade"
            )
