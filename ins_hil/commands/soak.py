"""`ins-hil soak`: sensors, gateway and ground station on 2 pinned CPUs for hours; a report with plots."""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

from ins_hil.soak.orchestrate import GCS_RATE

NAME = "soak"
HELP = "soak test: simulated sensors + gateway + ground station on 2 pinned CPUs; latency, loss, memory report"
DESCRIPTION = (
    "Run the gateway against simulated sensors over real transports (serial IMU frames over ptys, GNSS/baro "
    "MAVLink over UDP) with a pymavlink ground-station client, the sensors and client pinned to one CPU and the "
    "gateway to the other. Measures end-to-end latency per published state (sensor emission → received), loop "
    "latency and jitter, late samples, frame loss by reason, queue depth, CPU, RSS and fds per process, "
    "navigation error against truth and fault detection. Writes metrics.json, report.md and PNG plots into "
    "--out; exits 1 when a target is missed (with --interleave: e2e p99 ≤ 1.2 × and p99.9 ≤ 1.5 × the null "
    "relay's in the same run; steal-free e2e p99.9 ≤ 2 ms and loop p99.9 ≤ 1 ms; no lost frame; RSS growth < 1 "
    "MiB/h; horizontal error inside 3σ in ≥ 99 % of epochs, RMS ≤ 0.3 m; faults isolated without false alarm)."
    " --gateway relay puts the null "
    "relay in the gateway's place (no navigation: the end-to-end latency floor of the transport and wake-up "
    "chain); --relay-duration S runs it right after the main run, back to back with the gateway."
)


def _floats(text: str, what: str) -> list[float]:
    try:
        v = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what}: expected comma-separated numbers, got {text!r}") from None
    if any(not (x > 0 and math.isfinite(x)) for x in v):
        raise argparse.ArgumentTypeError(f"{what}: rates must be positive, got {text!r}")
    return v


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duration", type=float, default=1800.0, metavar="S", help="main run length (default 1800 s)")
    p.add_argument("--rate", type=float, default=1000.0, metavar="HZ", help="IMU rate (default 1000 Hz)")
    p.add_argument("--imus", type=int, default=1, metavar="N", help="IMUs: 1, or 2/3 redundant with FDI (default 1)")
    p.add_argument(
        "--faults",
        default="auto",
        metavar="SPEC",
        help="fault schedule with --imus ≥ 2: auto (gyro step at 40 %%, accel step at 70 %%), none, or "
        "T:GROUP:ROW:MODE:SIZE[:DURATION],... (see ins_hil/soak/faults.py)",
    )
    p.add_argument("--core", choices=["python", "c"], default="python", help="navigation core (default python)")
    p.add_argument(
        "--gateway",
        choices=["ins-hil", "relay"],
        default="ins-hil",
        help="what runs on the gateway CPU: ins-hil (the real gateway, default) or relay (the null relay: same "
        "CPU, priority, ptys and UDP ports, decodes the IMU frames and sends ODOMETRY at the gateway's rate, no "
        "navigation; its end-to-end latency is the platform floor of the transport and wake-up chain)",
    )
    p.add_argument("--load", type=int, default=0, metavar="N", help="busy-loop background processes (2 = both CPUs)")
    p.add_argument(
        "--transports",
        default="serial,udp",
        help="serial,udp (IMU serial frames on a pty) or can,udp (each IMU a DroneCAN node, RawIMU at the IMU rate "
        "+ NodeStatus, as slcan lines on one pty read by python-can's slcan interface: no kernel CAN needed)",
    )
    p.add_argument(
        "--imu-links",
        choices=["shared", "separate"],
        default="shared",
        help="redundant IMUs' frames on one pty (interleaved by imu_id, default) or one pty per IMU",
    )
    p.add_argument(
        "--gcs-rate",
        type=float,
        default=GCS_RATE,
        metavar="HZ",
        help=f"ODOMETRY rate to the ground station (default {GCS_RATE:g}: a period that sweeps every phase of "
        "the IMU and GNSS schedules)",
    )
    p.add_argument("--no-record", action="store_true", help="do not run the gateway's recorder")
    p.add_argument(
        "--no-rt",
        action="store_true",
        help="run every process time-shared (default: SCHED_FIFO for the sensors, gateway and client when "
        "permitted, like a deployed gateway with gateway.rt_priority)",
    )
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--out", default="soak-out", metavar="DIR", help="output directory (default soak-out)")
    p.add_argument("--sweep", default="", metavar="HZ,...", help="also run these IMU rates (highest passing rate)")
    p.add_argument("--sweep-cores", default="python,c", metavar="CORES", help="cores of the sweep (default python,c)")
    p.add_argument("--sweep-duration", type=float, default=60.0, metavar="S", help="length of each sweep run")
    p.add_argument("--loaded-duration", type=float, default=0.0, metavar="S", help="also run under load on both CPUs")
    p.add_argument(
        "--relay-duration",
        type=float,
        default=0.0,
        metavar="S",
        help="right after the main run, also run the null relay (--gateway relay) for S s with the same settings: "
        "the platform floor, measured back to back with the gateway (report section 'Platform floor: null relay')",
    )
    p.add_argument(
        "--interleave",
        type=float,
        default=0.0,
        metavar="BLOCK_S",
        help="alternate the gateway and the null relay in blocks of BLOCK_S s (ABBA order, --duration s per "
        "side, same CPUs, priorities, ptys, UDP path and client): the tail judged as a ratio against the floor "
        "measured in the same run; the sweep is interleaved too",
    )
    p.add_argument(
        "--continuous",
        type=float,
        default=0.0,
        metavar="S",
        help="with --interleave: also one continuous gateway run of S s after the blocks (memory trend, one long "
        "flight; its targets count)",
    )
    p.add_argument(
        "--profile-duration",
        type=float,
        default=0.0,
        metavar="S",
        help="also one gateway run of S s under cProfile: the loop's cost by stage (not used for timing)",
    )
    p.add_argument(
        "--can-duration",
        type=float,
        default=0.0,
        metavar="S",
        help="with --interleave: also the CAN path, S s per side (one DroneCAN IMU over slcan on a pty, "
        "interleaved against the null relay decoding the same frames; targets 0 lost, p99 ≤ 1.2 × floor)",
    )
    p.add_argument("--docs", metavar="MD", help="also write the report here (e.g. docs/soak.md), plots beside it")
    p.add_argument(
        "--baseline",
        type=float,
        default=30.0,
        metavar="S",
        help="first measure the platform's own wake-up latency with cyclictest (rt-tests) for S s (0 = skip)",
    )
    p.add_argument("--note", default="", help="a note printed at the top of the report (e.g. the machine's state)")
    p.add_argument("--report-only", action="store_true", help="exit 0 even when a target is missed")
    p.add_argument(
        "--rerender",
        metavar="DIR",
        help="no new run: analyse the raw files of an earlier --out DIR again and rewrite its report (and --docs)",
    )


def run(args: argparse.Namespace) -> int:
    from ins_hil.soak.faults import parse_faults
    from ins_hil.soak.orchestrate import SoakOptions
    from ins_hil.soak.suite import campaign

    def bad(msg: str) -> int:
        print(f"ins-hil soak: {msg}", file=sys.stderr)
        return 2

    from ins_hil.commands._outputs import out_dir, out_file

    if args.docs:
        out_file(args.docs, "--docs")
    if args.rerender:
        from ins_hil.soak.suite import rerender

        try:
            top = rerender(args.rerender, args.docs)
        except (RuntimeError, OSError, ValueError, KeyError) as e:
            return bad(str(e))
        print(f"[soak] report: {args.rerender}/report.md" + (f" and {args.docs}" if args.docs else ""))
        return 0 if top["pass"] or args.report_only else 1

    numbers = ("duration", "rate", "gcs_rate", "sweep_duration", "loaded_duration", "relay_duration", "interleave",
               "continuous", "profile_duration", "can_duration", "baseline")  # fmt: skip
    for key in numbers:
        if not math.isfinite(getattr(args, key)):
            return bad(f"--{key.replace('_', '-')} {getattr(args, key)}: must be a finite number")
    if args.duration <= 0 or args.rate <= 0:
        return bad("--duration and --rate must be positive")
    if args.gcs_rate <= 0 or args.sweep_duration <= 0:
        return bad("--gcs-rate and --sweep-duration must be positive")
    if not 1 <= args.imus <= 3:
        return bad(f"--imus {args.imus}: 1, 2 (dual_imu) or 3 (triple_imu)")
    if args.load < 0:
        return bad(f"--load {args.load}: must be ≥ 0")
    if args.relay_duration < 0:
        return bad(f"--relay-duration {args.relay_duration}: must be ≥ 0")
    if args.interleave < 0 or args.continuous < 0 or args.profile_duration < 0:
        return bad("--interleave, --continuous and --profile-duration must be ≥ 0")
    if args.interleave > 0 and (args.gateway == "relay" or args.relay_duration > 0):
        return bad("--interleave runs the null relay in its own blocks: no --gateway relay / --relay-duration")
    if args.continuous > 0 and args.interleave == 0:
        return bad("--continuous: only with --interleave (without it the main run is continuous)")
    if args.can_duration < 0 or (args.can_duration > 0 and args.interleave == 0):
        return bad("--can-duration: a positive length, with --interleave")
    if args.relay_duration > 0 and args.gateway == "relay":
        return bad("--relay-duration: the main run is the null relay already (--gateway relay)")
    if args.imus == 1 and args.faults.strip().lower() not in ("auto", "none"):
        return bad(f"--faults {args.faults!r}: fault detection needs --imus 2 or 3")
    faults = args.faults if args.imus > 1 else "none"
    out_dir(args.out, "--out")
    try:
        parse_faults(faults, args.duration, args.imus)
        rates = _floats(args.sweep, "--sweep") if args.sweep else []
        if rates:
            parse_faults(faults, args.sweep_duration, args.imus)
    except (ValueError, argparse.ArgumentTypeError) as e:
        return bad(str(e))
    cores = [c.strip() for c in args.sweep_cores.split(",") if c.strip()]
    for c in cores:
        if c not in ("python", "c"):
            return bad(f"--sweep-cores: unknown core {c!r} (python, c)")
    opt = SoakOptions(
        duration=args.duration,
        rate=args.rate,
        imus=args.imus,
        links=args.imu_links,
        faults=faults,
        core=args.core,
        load=args.load,
        transports=args.transports,
        gcs_rate=args.gcs_rate,
        record=not args.no_record,
        rt=not args.no_rt,
        gateway=args.gateway,
        seed=args.seed,
        out=args.out,
    )
    tty = sys.stderr.isatty()

    def progress(line: str) -> None:
        if tty:
            print("\r" + line[:160].ljust(160), end="", file=sys.stderr, flush=True)
        else:
            print(line, file=sys.stderr, flush=True)

    try:
        top = campaign(
            opt, rates, cores if rates else [], args.sweep_duration, args.loaded_duration, args.note, args.docs,
            progress, baseline_s=max(0.0, args.baseline), relay_duration=args.relay_duration,
            interleave=args.interleave, continuous=args.continuous, profile_duration=args.profile_duration,
            can_duration=args.can_duration,
        )  # fmt: skip
    except (RuntimeError, OSError, ValueError) as e:
        print(f"\nins-hil soak: {e}", file=sys.stderr)
        return 3
    if tty:
        print(file=sys.stderr)
    inter = top.get("interleave")
    if inter is not None:
        a, c = inter["summary"]["all"], inter["checks"]
        missed = [k for k, v in c.items() if v["ok"] is False]
        print(
            f"[soak] interleaved: gateway e2e p99 {a['gateway']['p99_us']:.0f} µs p99.9 {a['gateway']['p999_us']:.0f} "
            f"µs, floor p99 {a['floor']['p99_us']:.0f} µs p99.9 {a['floor']['p999_us']:.0f} µs, ratios "
            f"{a['ratio']['p99_us']:.2f} / {a['ratio']['p999_us']:.2f}{_intervals(c)}, "
            f"lost {c['lost_frames']['value']}, "
            + ("PASS" if inter["pass"] else "targets missed: " + ", ".join(missed))
        )
    if top.get("can") is not None:
        a, c = top["can"]["summary"]["all"], top["can"]["checks"]
        print(
            f"[soak] DroneCAN over slcan: gateway e2e p99 {a['gateway']['p99_us']:.0f} µs, floor p99 "
            f"{a['floor']['p99_us']:.0f} µs, ratio {a['ratio']['p99_us']:.2f}, lost {c['lost_frames']['value']}, "
            + ("PASS" if top["can"]["pass"] else "FAIL")
        )
    if "main" not in top["runs"]:
        print(f"[soak] report: {args.out}/report.md" + (f" and {args.docs}" if args.docs else ""))
        return 0 if top["pass"] or args.report_only else 1
    main = top["runs"]["main"]
    lat = main["latency"]["end_to_end"]
    missed = [k for k, c in main["checks"].items() if c["ok"] is False]
    print(
        f"[soak] main run{' (null relay)' if args.gateway == 'relay' else ''}: e2e p50 {lat['p50_us']:.0f} µs "
        f"p99 {lat['p99_us']:.0f} µs p99.9 {lat['p999_us']:.0f} µs max {lat['max_us']:.0f} µs, "
        f"lost {main['frames']['lost']}, RSS growth {main['checks']['rss_growth']['value_mib_per_h']:.2f} MiB/h, "
        + ("PASS" if top["pass"] else "targets missed: " + ", ".join(missed))
    )
    if "relay" in top["runs"]:
        r = top["runs"]["relay"]["latency"]["end_to_end"]
        print(
            f"[soak] platform floor (null relay): e2e p50 {r['p50_us']:.0f} µs p99 {r['p99_us']:.0f} µs "
            f"p99.9 {r['p999_us']:.0f} µs max {r['max_us']:.0f} µs, lost {top['runs']['relay']['frames']['lost']}"
        )
    print(f"[soak] report: {args.out}/report.md" + (f" and {args.docs}" if args.docs else ""))
    return 0 if top["pass"] or args.report_only else 1


def _intervals(checks: dict[str, Any]) -> str:
    """The ratio checks' intervals of an interleaved run for its summary line (e.g. `` (95 % intervals 1.15–1.37 /
    0.29–1.07, p99 not resolved)``), or "" when it has none."""
    p99, p999 = checks["ratio_p99"], checks["ratio_p999"]
    if "interval" not in p99:
        return ""
    unres = [k for k, c in (("p99", p99), ("p99.9", p999)) if not c["resolved"]]
    return (f" ({100 * p99['level']:.0f} % intervals {p99['interval'][0]:.2f}–{p99['interval'][1]:.2f} / "
            f"{p999['interval'][0]:.2f}–{p999['interval'][1]:.2f}"
            + (f", {' and '.join(unres)} not resolved)" if unres else ", resolved)"))  # fmt: skip
