"""`ins-hil demo`: a simulated flight through the navigation core (errors against truth), or
`ins-hil demo platform-ins`: seed 004's platform INS on its simulated test bed, with PNG plots."""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ins_hil.core import NavCore
from ins_hil.nav import earth
from ins_hil.nav.mechanization import StrapdownState
from ins_hil.nav.rotation import quat_angle_between
from ins_hil.sim.trajectory import generate, static_profile, uav_profile
from ins_hil.types import ImuSample

NAME = "demo"
HELP = "run a simulated trajectory through the navigation core (or seed 004's platform INS) against truth"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "scenario",
        nargs="?",
        choices=["flight", "platform-ins"],
        default="flight",
        help="flight: strapdown core on a simulated trajectory (default); platform-ins: seed 004's platform INS "
        "with precession-angle sensors, classical and reduced-measurement adaptive corrections, PNGs to --out",
    )
    p.add_argument("--profile", choices=["uav", "static"], default="uav", help="trajectory (default: uav)")
    p.add_argument("--duration", type=float, default=None, help="seconds of flight (default 120; platform-ins: 7200)")
    p.add_argument("--rate", type=float, default=200.0, help="IMU rate in Hz (default 200)")
    p.add_argument("--lat", type=float, default=50.45, help="start latitude, deg")
    p.add_argument("--lon", type=float, default=30.52, help="start longitude, deg")
    p.add_argument("--height", type=float, default=180.0, help="start ellipsoidal height, m")
    p.add_argument("--out", type=Path, default=Path("demo-platform-ins"), help="platform-ins: directory for the PNGs")
    p.add_argument("--constant-velocity", action="store_true", help="platform-ins: no manoeuvres")
    p.add_argument("--seed", type=int, default=4, help="platform-ins: noise seed (default 4)")


#: the longest flight demo, in IMU samples (--duration x --rate): its truth is held in memory, ~2.6 kB a sample
#: (600 s vs 300 s at 200 Hz: 351 vs 193 MB peak RSS), so 1 h at the default 200 Hz is ~1.9 GB
MAX_SAMPLES = 720_000
#: the longest platform-INS run (s; 0.1-s steps)
MAX_PLATFORM_S = 86_400.0


def _bad_arguments(args: argparse.Namespace) -> str | None:
    """Why the arguments cannot run (one line naming the flag), or None."""
    if args.duration is not None and not math.isfinite(args.duration):
        return f"--duration {args.duration}: must be a finite number of seconds"
    if not (math.isfinite(args.lat) and abs(args.lat) < 90.0):
        return f"--lat {args.lat:g}: must be within ±90° (the poles excluded)"
    if not (math.isfinite(args.lon) and abs(args.lon) <= 180.0):
        return f"--lon {args.lon:g}: must be within ±180°"
    if not math.isfinite(args.height):
        return f"--height {args.height}: must be finite"
    if args.scenario == "platform-ins":
        if args.duration is not None and args.duration > MAX_PLATFORM_S:
            return f"--duration {args.duration:g}: at most {MAX_PLATFORM_S:g} s"
        return None
    if not (math.isfinite(args.rate) and args.rate > 0):
        return f"--rate {args.rate:g}: must be a positive number of Hz"
    duration = 120.0 if args.duration is None else args.duration
    if duration <= 0:
        return "--duration and --rate must be positive"
    if duration * args.rate > MAX_SAMPLES:
        return (f"--duration {duration:g} x --rate {args.rate:g} = {duration * args.rate:.3g} IMU samples: at most "
                f"{MAX_SAMPLES:,} (the truth is held in memory, ~2.6 kB a sample)")  # fmt: skip
    if duration * args.rate < 2:
        return f"--duration {duration:g} x --rate {args.rate:g}: fewer than 2 IMU samples"
    return None


def run_platform_ins(args: argparse.Namespace) -> int:
    """Seed 004 end to end (DIGEST_001_004 §4): test bed, corrections, plots, printed summary."""
    from ins_hil.commands._outputs import out_dir
    from ins_hil.platform_ins import testbed as tb
    from ins_hil.reproduce.plots import platform_ins_figures

    out_dir(args.out, "--out")
    cfg = tb.TestbedConfig(seed=args.seed, manoeuvres=not args.constant_velocity)
    if args.duration is not None:
        if args.duration < 4 * cfg.T + cfg.settle:
            print(f"ins-hil demo: --duration {args.duration:g}: platform-ins needs at least "
                  f"{4 * cfg.T + cfg.settle:.0f} s", file=sys.stderr)  # fmt: skip
            return 2
        cfg = replace(cfg, duration=args.duration)
    t0 = time.perf_counter()
    res = tb.simulate(cfg)
    t_sim = time.perf_counter() - t0
    flight = "constant velocity" if args.constant_velocity else f"{len(cfg.pulses)} manoeuvres"
    print(
        f"ins-hil demo platform-ins: {cfg.duration:.0f} s at {cfg.v0[1]:.0f} m/s north, {flight}, "
        f"filter step T = {cfg.T:.0f} s, seed {cfg.seed} (simulated in {t_sim:.1f} s)"
    )
    true = res.truth[:, 2:5]
    for order, phi in ((1, res.phi_first), (2, res.phi_second)):
        rms = np.sqrt(np.mean((phi - true) ** 2, axis=0)) * 1e6
        print(f"platform angles, eq. {3 + order} residual RMS (E, N, up): {', '.join(f'{x:.3g}' for x in rms)} µrad")
    print(
        f"reduced measurements: cond(S) = {res.cond_S:.3g}; S⁻¹ row δv_N = {np.array2string(res.s_inv[0], precision=3)}"
    )
    print(f"{'correction':24} {'δv_N':>8} {'Φ_E':>8} {'ω_E^dr':>8}   (improvement of RMS after {cfg.settle:.0f} s)")
    for name, v in tb.improvements(res).items():
        print(f"{name:24} " + " ".join(f"{x:+7.0f}%" for x in v))
    sq, sr = res.scales["reduced adaptive"]
    print(f"adaptive KF final noise scales: Q {np.array2string(sq, precision=3)}, R {np.array2string(sr, precision=3)}")
    try:
        paths = platform_ins_figures(res, args.out)
    except OSError as e:
        print(f"ins-hil demo: cannot write {args.out}: {e}", file=sys.stderr)
        return 2
    print("plots: " + ", ".join(str(p) for p in paths))
    return 0


def run(args: argparse.Namespace) -> int:
    why = _bad_arguments(args)
    if why is not None:
        print(f"ins-hil demo: {why}", file=sys.stderr)
        return 2
    if args.scenario == "platform-ins":
        return run_platform_ins(args)
    if args.duration is None:
        args.duration = 120.0
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
