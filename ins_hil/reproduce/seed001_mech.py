"""Seed 001 §3.2.1–3.2.2: the i-frame and e-frame mechanizations held against the local-level (NED) one.

The three integrate the same IMU increments from one initial state (:mod:`ins_hil.nav.mechanization_ie`,
:class:`~ins_hil.nav.mechanization.StrapdownNED`); the NED state is taken to ECEF / ECI and compared every 10 s.
The seed prints no numbers (001-M). What "relative" means:

* position: for a moving vehicle |Δr(t)|/s(t), s(t) the distance travelled by then (the usual INS drift measure:
  360 km after 1 h at 100 m/s); for an Earth-fixed one |Δr|/|r|, r the ECEF radius;
* velocity: |Δv|/|vⁱ|, vⁱ the inertial velocity (the i-frame mechanization's state; ≈ 330 m/s at 45° for an
  Earth-fixed vehicle, 330–430 m/s at 100 m/s);
* attitude: the angle between the two attitudes (rad).

The moving profiles: "cruise", constant 100 m/s north-east at 45° N (:func:`cruise_profile`); "turns", 100 m/s
with sweeping coordinated turns (heading ±90°, period 180 s, bank up to 29°) and a ±5 m/s climb/descent
(:func:`turns_profile`). All three mechanizations are second order in the step, so they agree to O(Δt²): the
difference quarters when the step halves. Over 1 h the free-inertial vertical channel (time constant
√(R/2g) ≈ 570 s) amplifies it: at 100 Hz the position stays below 2e-10 of the distance and the velocity below
1.1e-7 m/s (≤ 1e-9 of |vⁱ|; 1.1e-9 of the 100 m/s ground speed in the turns); at 10 Hz the position reaches
1e-8 of the distance.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache

import numpy as np

from ins_hil.nav.mechanization import StrapdownNED, StrapdownState
from ins_hil.nav.mechanization_ie import (
    FrameState,
    StrapdownECEF,
    StrapdownECI,
    ecef_from_eci,
    ecef_from_ned,
    eci_from_ecef,
)
from ins_hil.nav.rotation import quat_angle_between
from ins_hil.sim import trajectory as tr
from ins_hil.types import Vec

from . import Row

LAT, LON, H = math.radians(45.0), math.radians(10.0), 100.0


def cruise_profile(vel_ned: tuple[float, float, float] = (60.0, 80.0, 0.0),
                   euler: tuple[float, float, float] = (0.05, 0.02, 0.9)) -> tr.Profile:  # fmt: skip
    """Constant NED velocity (m/s) and constant roll/pitch/yaw (rad)."""
    v, e = np.array(vel_ned), np.array(euler)

    def prof(t: Vec) -> tr.Kinematics:
        m = np.size(t)
        z = np.zeros((m, 3))
        return tr.Kinematics(np.tile(e, (m, 1)), z, np.tile(v, (m, 1)), z.copy())

    return prof


def turns_profile(speed: float = 100.0, turn_period: float = 180.0, climb_rate: float = 5.0) -> tr.Profile:
    """``speed`` (m/s) along the nose from t = 0, heading sweeping ±90° with period ``turn_period`` (s)
    in coordinated turns, a climb/descent of ±``climb_rate`` (m/s) over twice that period
    (:func:`ins_hil.sim.trajectory.uav_profile` already at speed)."""
    return tr.uav_profile(speed=speed, turn_period=turn_period, climb_rate=climb_rate, t_takeoff=-20.0, ramp=20.0)


PROFILES: dict[str, Callable[[], tr.Profile]] = {"cruise": cruise_profile, "turns": turns_profile}


def _diff(a: FrameState, b: FrameState, p_scale: float, v_scale: float) -> tuple[float, float, float]:
    return (float(np.linalg.norm(a.r - b.r)) / p_scale, float(np.linalg.norm(a.v - b.v)) / v_scale,
            quat_angle_between(a.q_xb, b.q_xb))  # fmt: skip


@lru_cache(maxsize=8)
def compare(profile: str, dt: float, seconds: float) -> dict[str, tuple[float, float, float]]:
    """Max over the run (checked every 10 s) of the relative (position, velocity) and attitude (rad)
    differences "e-NED", "i-NED", "i-e" (the module docstring says relative to what). ``profile``: "static"
    (45° N, roll 0.1, pitch −0.2, yaw 1.0 rad), "cruise" or "turns" (:data:`PROFILES`); ``dt`` the IMU step (s)."""
    prof = tr.static_profile(0.1, -0.2, 1.0) if profile == "static" else PROFILES[profile]()
    T = tr.generate(prof, seconds, dt, LAT, LON, H)
    speed = np.linalg.norm(T.vel_ned, axis=1)
    travelled = np.concatenate(([0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * dt)))
    s0 = StrapdownState(T.q_nb[0].copy(), T.vel_ned[0].copy(), LAT, LON, H)
    ned = StrapdownNED(s0.copy())
    e = StrapdownECEF(ecef_from_ned(s0))
    i = StrapdownECI(eci_from_ecef(ecef_from_ned(s0)))
    every = round(10.0 / dt)
    worst = {k: (0.0, 0.0, 0.0) for k in ("e-NED", "i-NED", "i-e")}
    for k in range(len(T.dtheta)):
        a, b = T.dtheta[k], T.dvel[k]
        ned.step(a, b, dt)
        e.step(a, b, dt)
        i.step(a, b, dt)
        if (k + 1) % every and k + 1 != len(T.dtheta):
            continue
        E = ecef_from_ned(ned.state)
        Ii = eci_from_ecef(E)
        ps = float(np.linalg.norm(E.r)) if profile == "static" else float(travelled[k + 1])
        vs = float(np.linalg.norm(Ii.v))
        for key, d in (("e-NED", _diff(e.state, E, ps, vs)), ("i-NED", _diff(i.state, Ii, ps, vs)),
                       ("i-e", _diff(ecef_from_eci(i.state), e.state, ps, vs))):  # fmt: skip
            worst[key] = tuple(max(x, y) for x, y in zip(worst[key], d, strict=True))  # type: ignore[assignment]
    return worst


@lru_cache(maxsize=1)
def rows() -> list[Row]:
    g = "001-M i- and e-frame mechanizations vs NED (seed 001 eqs. 45, 51; nav.mechanization_ie)"
    out: list[Row] = []
    st = compare("static", 0.01, 3600.0)
    names = ("position |Δr|/|r|", "velocity |Δv|/|vⁱ|", "attitude [rad]")
    for key, frame in (("e-NED", "e-frame"), ("i-NED", "i-frame")):
        for j, what in enumerate(names):
            out.append(Row(g, f"{frame} − NED, Earth-fixed, 1 h at 100 Hz: max {what}", None, st[key][j], 1e-9, "le",
                           1e-9, "the NED state taken to the frame"))  # fmt: skip
    moving = ("position |Δr|/distance travelled", "velocity |Δv|/|vⁱ|", "attitude [rad]")
    pairs = (("e-NED", "e-frame − NED"), ("i-NED", "i-frame − NED"), ("i-e", "i-frame − e-frame"))
    for prof, label in (("cruise", "100 m/s cruise"), ("turns", "100 m/s turns and climb")):
        w, w10 = compare(prof, 0.01, 3600.0), compare(prof, 0.1, 3600.0)
        for key, frame in pairs:
            for j, what in enumerate(moving):
                out.append(Row(g, f"{frame}, {label}, 1 h at 100 Hz: max {what}", None, w[key][j], 1e-9, "le", 1e-9,
                               f"at 10 Hz {w10[key][j]:.2g} (the O(Δt²) difference, amplified by the free-inertial "
                               "vertical channel)"))  # fmt: skip
    return out


@lru_cache(maxsize=1)
def order_rows() -> list[Row]:
    """The differences' order in the step (5 min at 10 and 20 Hz; cheap: the mutation check runs these)."""
    g = "001-M i-, e-frame and NED mechanizations: order in the step (nav.mechanization, nav.mechanization_ie)"
    why = ("second order in the step: the NED mechanization takes Earth rate, transport rate, gravity and radii at "
           "the mid-interval state (at the step start the ratio was 2)")  # fmt: skip
    out: list[Row] = []
    for prof, label in (("cruise", "100 m/s cruise"), ("turns", "100 m/s turns and climb")):
        c10, c20 = compare(prof, 0.1, 300.0), compare(prof, 0.05, 300.0)
        for key, frame in (("e-NED", "NED − e-frame"), ("i-NED", "NED − i-frame")):
            for j, what in ((0, "position"), (1, "velocity")):
                out.append(Row(g, f"{frame}, {label}, 5 min: max {what} difference at 10 Hz / at 20 Hz", None,
                               c10[key][j] / c20[key][j], 0.1, "rel", 4.0, why))  # fmt: skip
    return out
