"""The cost of an offline replay (:func:`ins_hil.datasets.run.run_dataset`) with fast GNSS and delayed fusion.

A simulated UAV mission (MEMS IMU at ``imu_hz``, RTK-grade GNSS) is replayed causally through ``NavCore`` with
the dataset defaults (``mems`` grade), for each GNSS rate and velocity delay; the figure is IMU samples per
second of process time and the real-time factor. With a GNSS velocity delay every fix is fused at its time of
validity by a roll-back and replay of the IMU steps since then (``NavConfig.gnss.vel_delay``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

#: (GNSS rate Hz, velocity delay s) of each row
CASES = ((5.0, 0.0), (20.0, 0.0), (20.0, 0.1))


def replay_cost(seconds: float = 120.0, imu_hz: float = 200.0, seed: int = 1,
                say: Callable[[str], None] | None = None) -> list[dict[str, Any]]:  # fmt: skip
    """One row per case of :data:`CASES`: IMU samples/s, real-time factor, roll-backs per fix."""
    from ins_hil.datasets import config as dcfg
    from ins_hil.datasets.dataset import Dataset
    from ins_hil.datasets.run import prepare, run_dataset
    from ins_hil.sim import sensors as se
    from ins_hil.sim import trajectory as tr

    rng = np.random.default_rng(seed)
    truth = tr.generate(tr.mission_profile(), seconds, 1.0 / imu_hz, math.radians(45.0), math.radians(7.0), 100.0)
    imu = se.corrupt_imu(truth, se.mems_gyro(rng), se.mems_accel(rng), seed=rng).samples()
    rows = []
    for rate, delay in CASES:
        fixes = list(se.gnss_fixes(truth, se.GnssModel(rate=rate, std_ne=0.02, std_d=0.04, std_vel=0.02), seed=seed))
        if delay > 0:  # the receiver's velocity is valid `delay` s before its position (what the config says)
            fixes = [dataclasses.replace(f, vel_ned=_vel_at(truth, f.t - delay)) for f in fixes]
        # the drift monitor off: this times the core's delayed fusion alone (on, it flags none of these fixes:
        # tests/test_aiding_vel_delay.py)
        c = dcfg.from_dict({"dataset": {"name": "replay-cost"}, "nav": {"gnss": {"vel_delay": delay}},
                            "fdi": {"aiding": False}})  # fmt: skip
        c.use_mag = c.use_baro = False
        p = prepare(Dataset(imu, fixes), c)
        t0 = time.process_time()
        r = run_dataset(p)
        cpu = time.process_time() - t0
        row = {"gnss_hz": rate, "vel_delay_s": delay, "imu_hz": imu_hz, "imu_samples": len(p.imu),
               "samples_per_s": len(p.imu) / cpu, "realtime": seconds / cpu,
               "h_rms_prior_m": float(np.sqrt(np.mean(r.gnss_err[:, 0] ** 2 + r.gnss_err[:, 1] ** 2)))}  # fmt: skip
        rows.append(row)
        if say:
            say(
                f"  GNSS {rate:4.0f} Hz, velocity delay {delay:.2f} s: {row['samples_per_s']:7.0f} IMU samples/s "
                f"= {row['realtime']:5.1f}x real time at {imu_hz:.0f} Hz (h prior {row['h_rms_prior_m']:.3f} m)"
            )
    return rows


def _vel_at(truth: Any, t: float) -> np.ndarray:
    return np.array([np.interp(t, truth.t, truth.vel_ned[:, k]) for k in range(3)])
