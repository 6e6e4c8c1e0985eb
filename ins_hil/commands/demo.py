"""`ins-hil demo`: run a simulated flight through the navigation core and print errors against truth."""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from ins_hil.core import NavCore
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import quat_angle_between
from ins_hil.sim.trajectory import generate, static_profile, uav_profile
from ins_hil.types import ImuSample

NAME = "demo"
HELP = "run a simulated trajectory through the navigation core and print errors against truth"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--profile", choices=["uav", "static"], default="uav", help="trajectory (default: uav)")
    p.add_argument("--duration", type=float, default=120.0, help="seconds of flight (default 120)")
    p.add_argument("--rate", type=float, default=200.0, help="IMU rate in Hz (default 200)")
    p.add_argument("--lat", type=float, default=50.45, help="start latitude, deg")
    p.add_argument("--lon", type=float, default=30.52, help="start longitude, deg")
    p.add_argument("--height", type=float, default=180.0, help="start ellipsoidal height, m")


def run(args: argparse.Namespace) -> int:
    if args.duration <= 0 or args.rate <= 0:
        raise SystemExit("ins-hil demo: --duration and --rate must be positive")
    dt = 1.0 / args.rate
    prof = uav_profile() if args.profile == "uav" else static_profile(yaw=0.3)
    lat0, lon0 = math.radians(args.lat), math.radians(args.lon)
    t_gen = time.perf_counter()
    truth = generate(prof, args.duration, dt, lat0, lon0, args.height)
    t_gen = time.perf_counter() - t_gen
    core = NavCore(StrapdownState(truth.q_nb[0].copy(), truth.vel_ned[0].copy(), lat0, lon0, args.height, truth.t[0]))
    print(
        f"ins-hil demo: {args.profile} profile, {args.duration:.0f} s at {args.rate:.0f} Hz, "
        f"error-free IMU (truth generated in {t_gen:.1f} s)"
    )
    print(f"{'t [s]':>8} {'att err [deg]':>14} {'vel err [m/s]':>14} {'pos err N/E/D [m]':>28}")
    n = len(truth.dtheta)
    report_every = max(1, n // 8)
    t_run = time.perf_counter()
    worst = np.zeros(3)
    for k in range(n):
        st = core.step(ImuSample(t=float(truth.t[k + 1]), dt=dt, dtheta=truth.dtheta[k], dvel=truth.dvel[k]))
        if (k + 1) % report_every == 0 or k == n - 1:
            att = math.degrees(quat_angle_between(st.q_nb, truth.q_nb[k + 1]))
            verr = float(np.linalg.norm(st.vel_ned - truth.vel_ned[k + 1]))
            perr = earth.ned_from_geodetic(st.lat, st.lon, st.h, truth.lat[k + 1], truth.lon[k + 1], truth.h[k + 1])
            worst = np.maximum(worst, [att, verr, float(np.linalg.norm(perr))])
            print(f"{st.t:8.1f} {att:14.2e} {verr:14.2e}   {perr[0]:8.3f} {perr[1]:8.3f} {perr[2]:8.3f}")
    t_run = time.perf_counter() - t_run
    print(
        f"worst: attitude {worst[0]:.2e} deg, velocity {worst[1]:.2e} m/s, position {worst[2]:.3f} m; "
        f"core {1e6 * t_run / n:.1f} µs/step"
    )
    return 0
