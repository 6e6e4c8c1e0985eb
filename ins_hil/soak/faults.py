"""Fault-injection schedule of a soak run: parsing and the sensor names the FDI monitor reports.

Syntax (``--faults``): comma-separated ``T:GROUP:ROW:MODE:SIZE[:DURATION]`` with ``T`` the
start (s of sensor time), ``GROUP`` gyro|accel, ``ROW`` the sensor row of the redundant
geometry (0..3·imus−1; rows 3j..3j+2 are the x/y/z axes of IMU j in its own frame),
``MODE`` a :class:`~ins_hil.types.FaultMode` name (step_bias, ramp, stuck, dropout,
noise_burst, saturation, scale_factor), ``SIZE`` in rad/s or m/s² (see
:mod:`ins_hil.sim.faults`). ``auto`` = one gyro step at 40 % and one accelerometer step
at 70 % of the run (different groups, so both are isolable with two IMUs); ``none`` = no fault.
"""

from __future__ import annotations

import math

from ins_hil.fdi.geometry import SensorGeometry, dual_imu, triple_imu
from ins_hil.sim.faults import FaultSpec
from ins_hil.types import FaultMode

#: default sizes of the ``auto`` schedule: well above the MEMS noise (0.15 °/√h, 70 µg/√Hz)
AUTO_GYRO_STEP = math.radians(2.0)  # rad/s
AUTO_ACCEL_STEP = 0.5  # m/s²


def geometry_for(n_imus: int) -> SensorGeometry:
    """The redundant geometry of ``n_imus`` full IMUs: 2 = dual_imu, 3 = triple_imu (the runtime's named sets)."""
    if n_imus == 2:
        return dual_imu()
    if n_imus == 3:
        return triple_imu()
    raise ValueError(f"--imus {n_imus}: the gateway's FDI takes 2 (dual_imu) or 3 (triple_imu) redundant IMUs")


def parse_faults(text: str, duration: float, n_imus: int) -> list[FaultSpec]:
    """The schedule from its ``--faults`` text (see module doc); raises ValueError naming the bad item."""
    text = text.strip().lower()
    if text in ("", "none"):
        return []
    if n_imus < 2:
        raise ValueError(f"--faults {text!r}: fault detection needs --imus 2 or more (got {n_imus})")
    if text == "auto":
        return [
            FaultSpec(FaultMode.STEP_BIAS, 1, 0.4 * duration, AUTO_GYRO_STEP, "gyro"),
            FaultSpec(FaultMode.STEP_BIAS, 3, 0.7 * duration, AUTO_ACCEL_STEP, "accel"),
        ]
    n_rows = 3 * n_imus
    out = []
    for item in text.split(","):
        f = item.strip().split(":")
        if len(f) not in (5, 6):
            raise ValueError(f"--faults item {item!r}: expected T:GROUP:ROW:MODE:SIZE[:DURATION]")
        try:
            t, group, row, mode, size = float(f[0]), f[1], int(f[2]), f[3].upper(), float(f[4])
            dur = float(f[5]) if len(f) == 6 else math.inf
        except ValueError as e:
            raise ValueError(f"--faults item {item!r}: {e}") from None
        if mode not in FaultMode.__members__:
            raise ValueError(f"--faults item {item!r}: unknown mode {f[3]!r}")
        if not 0 <= row < n_rows:
            raise ValueError(f"--faults item {item!r}: row {row} outside 0..{n_rows - 1} for {n_imus} IMUs")
        if not 0 < t < duration:
            raise ValueError(f"--faults item {item!r}: start {t} s is not inside the run (0..{duration} s)")
        out.append(FaultSpec(FaultMode[mode], row, t, size, group, dur))
    return out


def format_faults(specs: list[FaultSpec]) -> str:
    """The ``--faults`` text of a schedule (round trip of :func:`parse_faults`)."""
    items = []
    for s in specs:
        item = f"{s.t_start:g}:{s.group}:{s.sensor}:{s.mode.name.lower()}:{s.size:.17g}"
        if math.isfinite(s.duration):
            item += f":{s.duration:g}"
        items.append(item)
    return ",".join(items) or "none"
