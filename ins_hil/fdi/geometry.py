"""Redundant inertial sensor configurations as geometry matrices.

A configuration is a set of *units*; each unit is one :class:`ins_hil.types.ImuSample`
per epoch (matched by ``imu_id`` = unit index):

* ``kind="array"``: skewed single-axis sensors. Unit i carries gyro i's delta angle
  (rad) in ``dtheta[0]`` and accelerometer i's delta velocity (m/s) in ``dvel[0]``
  (the other components are ignored). Both sense along row i of ``gyro_axes`` /
  ``accel_axes`` (unit vectors in body FRD). Sensor names ``gyro[i]``, ``accel[i]``.
* ``kind="imus"``: full three-axis IMUs, each in its own sensor frame. Unit j carries
  its triad in its own axes; ``mountings[j]`` is C_s^b (sensor→body DCM), so the rows
  of the geometry for unit j are the sensor axes in body, (C_s^b)ᵀ. Names
  ``imu{j}.gyro.x`` … ``imu{j}.accel.z``.

The geometry matrix A (n×3) gives y = A ω (+ e + w) for the stacked outputs (book eq. 5.1).
Lever arms between co-mounted units are neglected (accelerometers assumed co-located).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ins_hil.fdi.parity import BOOK_CONE_A, dodecahedron_geometry
from ins_hil.nav.rotation import dcm_from_euler
from ins_hil.types import Vec

_AX = "xyz"


@dataclass(frozen=True)
class SensorGeometry:
    """Stacked sensing axes of a redundant set (see module docstring)."""

    name: str
    kind: str  # "array" | "imus"
    gyro_axes: Vec  # (n, 3) unit rows, body FRD
    accel_axes: Vec  # (n, 3)
    mountings: tuple[Vec, ...] = field(default=())  # C_s^b per IMU (kind="imus")

    def __post_init__(self) -> None:
        if self.kind not in ("array", "imus"):
            raise ValueError(f"SensorGeometry {self.name!r}: kind must be 'array' or 'imus', got {self.kind!r}")
        for lbl, a in (("gyro_axes", self.gyro_axes), ("accel_axes", self.accel_axes)):
            if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] < 4:
                raise ValueError(f"SensorGeometry {self.name!r}: {lbl} must be n×3 with n ≥ 4, got {a.shape}")
            if np.linalg.matrix_rank(a) < 3:
                raise ValueError(f"SensorGeometry {self.name!r}: {lbl} does not span 3-D")
        if self.kind == "imus" and len(self.mountings) * 3 != self.gyro_axes.shape[0]:
            raise ValueError(f"SensorGeometry {self.name!r}: {len(self.mountings)} mountings for {self.n} rows")

    @property
    def n(self) -> int:
        """Rows per group (gyros = accelerometers)."""
        return int(self.gyro_axes.shape[0])

    @property
    def unit_size(self) -> int:
        """Rows carried by one ImuSample: 1 (array) or 3 (IMU)."""
        return 1 if self.kind == "array" else 3

    @property
    def units(self) -> int:
        return self.n // self.unit_size

    def row_name(self, group: str, row: int) -> str:
        """Sensor name of row ``row`` of group ``"gyro"``/``"accel"``."""
        if self.kind == "array":
            return f"{group}[{row}]"
        return f"imu{row // 3}.{group}.{_AX[row % 3]}"

    def unit_of(self, row: int) -> int:
        return row // self.unit_size


def book_cone5() -> SensorGeometry:
    """The book's five gyros on a cone (Ex 5.1, A printed), accelerometers on the same axes."""
    a = BOOK_CONE_A / np.linalg.norm(BOOK_CONE_A, axis=1, keepdims=True)
    return SensorGeometry("cone5", "array", a, a.copy())


def skewed6() -> SensorGeometry:
    """Six skewed gyro + accelerometer pairs normal to the faces of a dodecahedron."""
    a = dodecahedron_geometry()
    return SensorGeometry("skew6", "array", a, a.copy())


def imus(mount_rpy_deg: list[tuple[float, float, float]], name: str = "") -> SensorGeometry:
    """Full IMUs with mountings given as roll/pitch/yaw (deg) of each sensor frame in body
    (C_s^b = dcm_from_euler(roll, pitch, yaw))."""
    if len(mount_rpy_deg) < 2:
        raise ValueError("imus: at least two IMUs are needed for fault detection")
    mounts = tuple(dcm_from_euler(*(math.radians(x) for x in rpy)) for rpy in mount_rpy_deg)
    a = np.vstack([m.T for m in mounts])  # rows = sensor axes in body
    return SensorGeometry(name or f"imu{len(mounts)}", "imus", a, a.copy(), mounts)


def dual_imu() -> SensorGeometry:
    """Two IMUs; the second skewed (yaw 45°, roll 54.74°: its axes lie in the body diagonals' directions
    so no axis is collinear with one of the first IMU's and a single-axis fault can be isolated).
    With two axis-aligned IMUs a fault can be detected but not isolated (collinear axes)."""
    return imus([(0.0, 0.0, 0.0), (54.7356, 0.0, 45.0)], "dual_imu")


def triple_imu() -> SensorGeometry:
    """Three IMUs mounted as on a typical flight controller: aligned, yaw 90°, roll 180°.
    Each body axis is measured three times (collinear), so isolation is by 2-of-3 voting."""
    return imus([(0.0, 0.0, 0.0), (0.0, 0.0, 90.0), (180.0, 0.0, 0.0)], "triple_imu")


CONFIGS = {"cone5": book_cone5, "skew6": skewed6, "dual_imu": dual_imu, "triple_imu": triple_imu}


def by_name(name: str) -> SensorGeometry:
    """One of :data:`CONFIGS` by name (clear error for an unknown name)."""
    try:
        return CONFIGS[name]()
    except KeyError:
        raise ValueError(f"unknown redundant configuration {name!r}; choose from {sorted(CONFIGS)}") from None
