"""ins_hil: hardware-in-the-loop navigation gateway (strapdown INS, EKF, FDI, MAVLink/MQTT).

The public API for using the navigation core in your own code::

    from ins_hil import NavCore, NavConfig, ImuSample, GnssFix, BaroSample, MagSample, NavState
    from ins_hil import GnssConfig, AidsConfig  # NavConfig's sections: NavConfig(gnss=GnssConfig(gate=10.0))

``NavCore`` is the one synchronous entry point (``step`` on every IMU sample, ``fuse`` for every aiding
measurement, ``state()``); the names are imported on first use, so ``import ins_hil`` stays cheap.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

_PUBLIC = {
    "NavCore": "ins_hil.core",
    "NavConfig": "ins_hil.core",
    "FilterConfig": "ins_hil.fusion.ekf",
    **{
        c: "ins_hil.core_parts.config"
        for c in ("GnssConfig", "BaroConfig", "MagConfig", "AidsConfig", "HoldConfig", "AlignmentConfig", "DelayConfig")
    },  # NavConfig's sections
    "StrapdownState": "ins_hil.nav.mechanization",
    "ImuSample": "ins_hil.types",
    "GnssFix": "ins_hil.types",
    "BaroSample": "ins_hil.types",
    "MagSample": "ins_hil.types",
    "NavState": "ins_hil.types",
    "FaultEvent": "ins_hil.types",
    "FixType": "ins_hil.types",
}
__all__ = [
    "AidsConfig", "AlignmentConfig", "BaroConfig", "BaroSample", "DelayConfig", "FaultEvent", "FilterConfig",
    "FixType", "GnssConfig", "GnssFix", "HoldConfig", "ImuSample", "MagConfig", "MagSample", "NavConfig", "NavCore",
    "NavState", "StrapdownState", "__version__",
]  # fmt: skip

if TYPE_CHECKING:
    from ins_hil.core import NavConfig, NavCore
    from ins_hil.core_parts.config import (
        AidsConfig,
        AlignmentConfig,
        BaroConfig,
        DelayConfig,
        GnssConfig,
        HoldConfig,
        MagConfig,
    )
    from ins_hil.fusion.ekf import FilterConfig
    from ins_hil.nav.mechanization import StrapdownState
    from ins_hil.types import BaroSample, FaultEvent, FixType, GnssFix, ImuSample, MagSample, NavState


def __getattr__(name: str) -> Any:
    mod = _PUBLIC.get(name)
    if mod is None:
        raise AttributeError(f"module 'ins_hil' has no attribute {name!r}")
    value = getattr(importlib.import_module(mod), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
