"""ins_hil.fdi: fault detection and isolation of redundant inertial sensors (book ch. 5).

* :mod:`ins_hil.fdi.parity`: parity space (SVD / QR), SVD isolation with the corrected
  eq. 5.17, the Lebedev projector form, the determinant procedure (5.32).
* :mod:`ins_hil.fdi.recursive`: recursive LS / Kalman statistic with cyclic transposition (5.18–5.23).
* :mod:`ins_hil.fdi.bias`: isolation from the estimated gyro bias (5.24–5.30) and the Ex 5.3 filter.
* :mod:`ins_hil.fdi.geometry`: redundant configurations (5-gyro cone, skewed six, 2–3 IMUs).
* :mod:`ins_hil.fdi.thresholds`: χ² thresholds from noise and a false-alarm probability.
* :mod:`ins_hil.fdi.monitor`: the runtime :class:`~ins_hil.fdi.monitor.FdiMonitor`.
* :mod:`ins_hil.fdi.aiding`: GNSS/baro drift and slow-pull detection (:class:`~ins_hil.fdi.aiding.AidingMonitor`).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ins_hil.fdi.aiding import AidingConfig, AidingMonitor
    from ins_hil.fdi.geometry import SensorGeometry, book_cone5, by_name, dual_imu, skewed6, triple_imu
    from ins_hil.fdi.monitor import FdiConfig, FdiMonitor

#: the package's names and their modules, imported on first use (PEP 562): importing ``ins_hil.fdi.aiding`` (the
#: replay's drift monitor) does not load the IMU monitor, the geometries and the parity space
_LAZY = {"AidingConfig": "aiding", "AidingMonitor": "aiding", "FdiConfig": "monitor", "FdiMonitor": "monitor",
         "SensorGeometry": "geometry", "book_cone5": "geometry", "by_name": "geometry", "dual_imu": "geometry",
         "skewed6": "geometry", "triple_imu": "geometry"}  # fmt: skip


def __getattr__(name: str) -> Any:
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'ins_hil.fdi' has no attribute {name!r}")
    return getattr(importlib.import_module(f"ins_hil.fdi.{mod}"), name)


__all__ = [
    "AidingConfig",
    "AidingMonitor",
    "FdiConfig",
    "FdiMonitor",
    "SensorGeometry",
    "book_cone5",
    "by_name",
    "dual_imu",
    "skewed6",
    "triple_imu",
]
