"""Simulate a redundant inertial sensor set from a truth trajectory.

The ideal body increments of :func:`ins_hil.sim.trajectory.generate` are
projected on every sensing axis of a :class:`SensorAxes` (what the simulator reads of
the :class:`ins_hil.fdi.geometry.SensorGeometry` the caller passes in; y = A Δθ, book
eq. 5.1), then each sensor gets its own independent errors from
:func:`ins_hil.sim.sensors.corrupt_imu` (rows processed three at a time as
virtual triads; for full IMUs each triad is exactly one IMU in its own frame).
Default error models are the stochastic parts of ``mems_gyro()``/``mems_accel()``
(white noise + bias instability): turn-on bias, scale factor and misalignment
are taken as calibrated out, which is what a parity-space monitor assumes.
Units: increments in rad and m/s over ``dt`` (s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from ins_hil.sim.sensors import ImuErrorModel, corrupt_imu, mems_accel, mems_gyro
from ins_hil.sim.trajectory import TruthSeries
from ins_hil.types import ImuSample, Vec


class SensorAxes(Protocol):
    """The sensing axes of a redundant set (``ins_hil.fdi.geometry.SensorGeometry`` has them)."""

    @property
    def name(self) -> str:
        """For messages."""
        ...

    @property
    def kind(self) -> str:
        """``"array"`` (one axis per ImuSample) or ``"imus"`` (one triad per ImuSample)."""
        ...

    @property
    def gyro_axes(self) -> Vec:
        """(n, 3) unit rows, body FRD."""
        ...

    @property
    def accel_axes(self) -> Vec:
        """(n, 3) unit rows, body FRD."""
        ...

    @property
    def n(self) -> int:
        """Sensing axes (rows)."""
        ...

    @property
    def units(self) -> int:
        """ImuSamples per epoch."""
        ...


@dataclass
class RedundantSeries:
    """Outputs of a redundant set: ``gyro``/``accel`` increments (N, n), times (N,) at interval ends."""

    geometry: SensorAxes
    t: Vec
    dt: float
    gyro: Vec
    accel: Vec
    flags: Vec  # (N, units) ImuFlags bits (saturation of a unit's triad)

    def copy(self) -> RedundantSeries:
        return replace(self, gyro=self.gyro.copy(), accel=self.accel.copy(), flags=self.flags.copy())

    def epoch(self, k: int) -> list[ImuSample]:
        """The samples of epoch k, one ImuSample per unit (see ins_hil.fdi.geometry for the layout)."""
        g, a, us = self.geometry, self.gyro[k], self.accel[k]
        t = float(self.t[k])
        if g.kind == "array":
            z = np.zeros(2)
            return [
                ImuSample(
                    t=t,
                    dt=self.dt,
                    dtheta=np.concatenate(([a_i], z)),
                    dvel=np.concatenate(([u_i], z)),
                    imu_id=i,
                    seq=k & 0xFFFF,
                )
                for i, (a_i, u_i) in enumerate(zip(a, us))
            ]
        return [
            ImuSample(
                t=t,
                dt=self.dt,
                dtheta=a[3 * j : 3 * j + 3].copy(),
                dvel=us[3 * j : 3 * j + 3].copy(),
                imu_id=j,
                seq=k & 0xFFFF,
                flags=int(self.flags[k, j]),
            )
            for j in range(g.units)
        ]


def simulate(
    truth: TruthSeries,
    geometry: SensorAxes,
    gyro: ImuErrorModel | None = None,
    accel: ImuErrorModel | None = None,
    seed: int = 0,
) -> RedundantSeries:
    """Independent noisy outputs of every sensor of ``geometry`` along ``truth``."""
    gyro = gyro if gyro is not None else mems_gyro()
    accel = accel if accel is not None else mems_accel()
    rng = np.random.default_rng(seed)
    n = geometry.n
    ig = truth.dtheta @ geometry.gyro_axes.T
    ia = truth.dvel @ geometry.accel_axes.T
    nt = len(ig)
    ntri = math.ceil(n / 3)
    pad = 3 * ntri - n
    if pad:
        ig = np.hstack([ig, np.zeros((nt, pad))])
        ia = np.hstack([ia, np.zeros((nt, pad))])
    og = np.empty_like(ig)
    oa = np.empty_like(ia)
    fl = np.zeros((nt, ntri), dtype=np.int64)
    for j in range(ntri):
        tr = replace(truth, dtheta=ig[:, 3 * j : 3 * j + 3], dvel=ia[:, 3 * j : 3 * j + 3])
        s = corrupt_imu(tr, gyro, accel, rng)
        og[:, 3 * j : 3 * j + 3] = s.dtheta
        oa[:, 3 * j : 3 * j + 3] = s.dvel
        fl[:, j] = s.flags
    flags = fl if geometry.kind == "imus" else np.zeros((nt, geometry.units), dtype=np.int64)
    return RedundantSeries(geometry, truth.t[1:].copy(), truth.dt, og[:, :n], oa[:, :n], flags)
