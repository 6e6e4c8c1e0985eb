"""The gateway's own recordings (``*.ihlog``, :mod:`ins_hil.runtime.recorder`) as a :class:`Dataset`.

The recorder stores every input in the order the pipeline consumed it (IMU increments in body FRD stamped at the
interval end, GNSS at its time of validity, baro, magnetometer in tesla); the reader sorts each stream by time and
keeps the lowest ``imu_id`` (a redundant-IMU run: the primary unit). ``ins-hil replay LOG.ihlog`` without
``--dataset`` is the exact pipeline replay (``ins_hil.evaluation.sim_flight.replay_log``); with a dataset config
the log is replayed like any other data set. Where the run was simulated (``[sim]`` enabled in the header's
config), the simulator's truth is regenerated from the header (seeded, deterministic:
``ins_hil.evaluation.sim_flight.sim_truth``, installed with :func:`set_truth_source`) and becomes the reference
trajectory (position and velocity at 10 Hz; the truth holds no attitude).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from ins_hil.datasets.dataset import Dataset, DatasetError, Reader, Trajectory
from ins_hil.nav import earth
from ins_hil.types import ImuSample, SimConfig

if TYPE_CHECKING:
    from ins_hil.runtime.replay import SimTruth

# ``ins_hil.runtime.recorder`` / ``ins_hil.runtime.replay`` are imported where a gateway log is read: a replay that
# only installs the truth source (every ``ins-hil replay --dataset``) does not load them

#: reference rate (Hz) of a simulated run's regenerated truth
REFERENCE_HZ = 10.0

#: regenerates a simulated run's truth, (SimConfig, duration s) -> SimTruth; installed by the evaluation layer
#: (:func:`set_truth_source` with ``ins_hil.evaluation.sim_flight.sim_truth``): ``datasets`` may not import
#: the simulator. None: a simulated log is replayed without a reference (its notes say so).
TruthSource = Callable[[SimConfig, float], "SimTruth"]
_truth_source: TruthSource | None = None


def set_truth_source(fn: TruthSource | None) -> None:
    """Install the function that regenerates a simulated run's truth (None: none)."""
    global _truth_source
    _truth_source = fn


def _is_ihlog(path: Path) -> bool:
    if not path.is_file():
        return False
    from ins_hil.runtime import recorder

    with path.open("rb") as f:
        head = f.read(len(recorder.MAGIC))
    return head in (recorder.MAGIC, recorder.MAGIC_V1)


def is_simulated(header: dict[str, Any]) -> bool:
    """Whether the recording's header says the run was simulated (``[sim]`` enabled)."""
    from ins_hil.runtime.replay import sim_config_from_header

    return sim_config_from_header(header) is not None


def sim_reference(header: dict[str, Any], duration: float) -> Trajectory | None:
    """The simulator's truth of a simulated run (header ``[sim]``) as a reference trajectory; None for a real
    run or when no truth source is installed."""
    from ins_hil.runtime.replay import sim_config_from_header

    sim = sim_config_from_header(header)
    if sim is None or _truth_source is None:
        return None
    tr = _truth_source(sim, duration)
    step = max(1, round(tr.rate / REFERENCE_HZ))
    k = np.arange(0, len(tr.t), step)
    origin = (float(tr.lat[0]), float(tr.lon[0]), float(tr.h[0]))
    pos = np.array([earth.ned_from_geodetic(float(tr.lat[i]), float(tr.lon[i]), float(tr.h[i]), *origin) for i in k])
    return Trajectory("simulator truth", t_vel=tr.t[k], vel_ned=tr.vel_ned[k], t_pos=tr.t[k], pos_ned=pos,
                      origin=origin)  # fmt: skip


def read_ihlog(path: Path) -> Dataset:
    """Read a gateway recording (all its parts); DatasetError (one line) for a damaged or foreign file."""
    from ins_hil.runtime import recorder

    try:
        header = recorder.read_header(path)
        records = list(recorder.read_records(path))
    except (ValueError, OSError) as e:
        raise DatasetError(f"{path}: not a readable gateway log ({e})") from None
    imu_all = [cast(ImuSample, r) for r in records if r.kind == "imu"]
    if not imu_all:
        raise DatasetError(f"{path}: no IMU records in the gateway log")
    primary = min(s.imu_id for s in imu_all)
    imu = sorted((s for s in imu_all if s.imu_id == primary), key=lambda s: s.t)
    ds = Dataset.of_samples(imu, [r for r in records if r.kind != "imu"])
    notes = []
    if len({s.imu_id for s in imu_all}) > 1:
        notes.append(f"redundant IMUs in the log: imu_id {primary} replayed")
    ds.reference = sim_reference(header, imu[-1].t + 1.0)
    if ds.reference is not None:
        notes.append("simulated run: the simulator's truth (regenerated from the header's [sim]) is the reference")
    elif is_simulated(header):
        notes.append("simulated run, replayed without its truth (no truth source installed)")
    ds.meta = {"source": str(path), "format": "ihlog", "vehicle": "", "notes": notes,
               "session": header.get("session")}  # fmt: skip
    return ds


READER = Reader(
    "ihlog", "a gateway recording (*.ihlog, IHLOG1/IHLOG2 magic)", _is_ihlog, read_ihlog, suffixes=(".ihlog",)
)
