"""Outages scored against a log's separate reference trajectory (``ref`` records of the generic CSV, a simulated
gateway log's truth), besides the withheld GNSS fixes.

:class:`ReferenceScore` observes the replay (:func:`ins_hil.datasets.run.replay`): each reference position inside
an outage window is compared, at the first IMU epoch at or after its time, with the point of the body it refers to:
our IMU position plus the body lever arm ``reference_lever_arm_m`` (``[mounting]``, IMU → reference point, body
FRD) turned by our attitude, moved on with our velocity to the reference time. :func:`outage_scores` gives the
horizontal RMS / max per window and over all, the vertical RMS and the 2-dof NEES with our σ. The reference's
positions are taken to our origin through their own (``Trajectory.origin``); one without an origin cannot be
scored absolutely (None).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ins_hil.datasets.dataset import Trajectory
from ins_hil.datasets.run import antenna_ned, navigating, states_at
from ins_hil.nav import earth
from ins_hil.runtime.pipeline import Observer, Pipeline
from ins_hil.types import NavState, Vec


class ReferenceScore(Observer):
    """The error of the reference point against a reference trajectory inside ``windows`` (s, absolute)."""

    def __init__(self, tr: Trajectory, origin: tuple[float, float, float], lever_b: Vec,
                 windows: Sequence[tuple[float, float]]) -> None:  # fmt: skip
        self.lever = np.asarray(lever_b, dtype=np.float64)
        self.origin = origin
        self._o = earth.ned_ref(*origin)  # the origin's ECEF point and C_e^n, once
        self.windows = list(windows)
        t, p = tr.t_pos, tr.pos_ned
        if t is None or p is None or tr.origin is None or not len(t):
            self.t, self.ref = np.zeros(0), np.zeros((0, 3))
        else:
            shift = earth.ned_from_geodetic(*tr.origin, *origin)  # the reference's origin from ours
            inside = np.array([any(a <= x < b for a, b in self.windows) for x in t], dtype=bool)
            ok = inside & np.all(np.isfinite(p), axis=1)
            self.t, self.ref = np.asarray(t)[ok], np.asarray(p)[ok] + shift
        self._t: list[float] = self.t.tolist()
        self._k = 0
        self.rows: list[tuple[float, Vec, Vec]] = []  # (t s, error NED m, our σ NED m)

    def epoch(self, pipe: Pipeline, st: NavState) -> None:
        t = self.t
        k = self._k
        if k >= len(t) or t[k] > st.t:
            return
        nav = navigating(pipe)
        while k < len(t) and t[k] <= st.t:
            if nav:
                self._row(k, st)
            k += 1
        self._k = k

    def epochs(self, pipe: Pipeline, states: Sequence[NavState]) -> None:
        k = self._k
        at, self._k = states_at(self._t, k, states)  # each reference point at the first state at or after its time
        if at and navigating(pipe):
            for j, i in enumerate(at, k):
                self._row(j, states[i])

    def _row(self, k: int, st: NavState) -> None:
        """Reference point ``k`` scored against ``st`` (the first state at or after its time), the lever arm turned
        with our attitude and our position carried to the point's time with our velocity."""
        t = float(self.t[k])
        ours = antenna_ned(st, self.lever, t, self.origin, self._o)
        self.rows.append((t, ours - self.ref[k], np.asarray(st.std_pos)))


def outage_scores(sc: ReferenceScore, t_nav: float) -> dict[str, Any] | None:
    """Per window opened while navigating (``t_nav`` s): the horizontal RMS / max (m) of the error against the
    reference, and over all windows also the vertical RMS (m) and the mean 2-dof NEES; None when the reference
    has no position inside any window (or no origin)."""
    if not len(sc.t):
        return None
    rows = []
    allh: list[Vec] = []
    alld: list[Vec] = []
    nees: list[Vec] = []
    for a, b in sc.windows:
        sel = [(e, s) for t, e, s in sc.rows if a <= t < b]
        if not sel or not (t_nav <= a):
            rows.append({"window_s": [a, b], "scored": False})
            continue
        e = np.array([x for x, _ in sel])
        s = np.array([y for _, y in sel])
        h = np.hypot(e[:, 0], e[:, 1])
        rows.append({"window_s": [a, b], "scored": True, "samples": len(e), "h_rms_m": float(np.sqrt(np.mean(h**2))),
                     "h_max_m": float(h.max())})  # fmt: skip
        allh.append(h)
        alld.append(e[:, 2])
        nees.append((e[:, 0] / s[:, 0]) ** 2 + (e[:, 1] / s[:, 1]) ** 2)
    if not allh:
        return {"windows": rows, "outages_scored": 0, "h_rms_m": math.nan, "h_max_m": math.nan,
                "v_rms_m": math.nan, "nees_2dof_mean": math.nan, "lever_arm_m": sc.lever.tolist()}  # fmt: skip
    H, D = np.concatenate(allh), np.concatenate(alld)
    return {"windows": rows, "outages_scored": len(allh), "samples": len(H), "h_rms_m": float(np.sqrt(np.mean(H**2))),
            "h_max_m": float(H.max()), "v_rms_m": float(np.sqrt(np.mean(D**2))),
            "nees_2dof_mean": float(np.mean(np.concatenate(nees))), "lever_arm_m": sc.lever.tolist()}  # fmt: skip


def lever_of(tr: Trajectory, configured: Vec) -> Vec:
    """The reference point's lever arm (body FRD, m, from the IMU): the config's ``reference_lever_arm_m`` when it
    sets one, else the reader's (``Trajectory.lever_b``)."""
    c = np.asarray(configured, dtype=np.float64)
    return c if np.any(c != 0.0) else np.asarray(tr.lever_b, dtype=np.float64)
