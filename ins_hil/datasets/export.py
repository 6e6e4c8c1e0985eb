"""Trajectory export (``ins-hil replay ... --export traj.csv``): the replay's navigation states as CSV.

One row per navigating IMU epoch: time (s), latitude, longitude (deg, WGS84), height (m, WGS84 ellipsoidal),
velocity NED (m/s), roll, pitch, yaw (deg, aerospace ZYX, body FRD → NED) and the filter's 1-σ of each (position
N, E, D in m; velocity m/s; attitude about the NED axes in deg, the σ of roll, pitch and yaw when level). The
numbers are written with 17 significant digits: read back they are the states bit for bit.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.datasets.run import euler_series
from ins_hil.types import NavState, Vec

COLUMNS = (
    "t_s", "lat_deg", "lon_deg", "h_m", "vn_mps", "ve_mps", "vd_mps", "roll_deg", "pitch_deg", "yaw_deg",
    "sn_m", "se_m", "sd_m", "svn_mps", "sve_mps", "svd_mps", "sroll_deg", "spitch_deg", "syaw_deg",
)  # fmt: skip


def rows(t: Vec, llh: Vec, vel: Vec, q: Vec, std_pos: Vec, std_vel: Vec, std_att: Vec) -> Vec:
    """(N, 19) rows of :data:`COLUMNS` from the arrays of a trajectory (llh: lat, lon rad, h m; σ att rad)."""
    n = len(t)
    if n == 0:
        return np.zeros((0, len(COLUMNS)))
    return np.column_stack([
        np.asarray(t, dtype=np.float64), np.degrees(llh[:, 0]), np.degrees(llh[:, 1]), llh[:, 2], vel,
        np.degrees(euler_series(np.asarray(q, dtype=np.float64))), std_pos, std_vel, np.degrees(std_att),
    ])  # fmt: skip


def rows_from_states(states: Sequence[NavState]) -> Vec:
    """The rows of a list of navigation states (a gateway log's replay, a live run)."""
    if not states:
        return np.zeros((0, len(COLUMNS)))
    a = lambda f: np.array([f(s) for s in states], dtype=np.float64)
    return rows(a(lambda s: s.t), a(lambda s: (s.lat, s.lon, s.h)), a(lambda s: s.vel_ned), a(lambda s: s.q_nb),
                a(lambda s: s.std_pos), a(lambda s: s.std_vel), a(lambda s: s.std_att))  # fmt: skip


def rows_from_run(r: Any) -> Vec:
    """The rows of a dataset replay (``ins_hil.datasets.run.RunResult``)."""
    return rows(r.t, r.llh, r.vel_ned, r.q_nb, r.std_pos, r.std_vel, r.std_att)


def write_csv(path: str | Path, data: Vec) -> Path:
    """Write ``data`` (N, 19) with a header line of :data:`COLUMNS`; returns the path."""
    p = Path(path)
    if p.parent != Path(""):
        p.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(p, data, fmt="%.17g", delimiter=",", header=",".join(COLUMNS), comments="")
    return p


def read_csv(path: str | Path) -> Vec:
    """The rows of an exported trajectory (N, 19)."""
    return np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
