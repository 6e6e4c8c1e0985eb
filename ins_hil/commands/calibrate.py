"""`ins-hil calibrate accel|gyro|mag|allan LOG`: bench calibration from a recorded log.

Reads a log (CSV; the runtime recorder's ``.ihlog``: :mod:`ins_hil.calibration.logs`),
estimates the calibration with :mod:`ins_hil.nav.calibration` /
:mod:`ins_hil.nav.allan`, merges it into the calibration file (TOML or JSON) the
gateway loads at start, and writes a Markdown report with PNG plots.

The CSV columns are those of :mod:`ins_hil.calibration.logs` (and docs/calibration.md).

``--simulate`` first writes a simulated log with known errors to LOG (and prints
them), so the whole workflow can be tried without hardware.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from datetime import UTC, datetime
from pathlib import Path

from ins_hil.calibration.bench import bench, simulate_log
from ins_hil.calibration.files import load_calibration, save_calibration
from ins_hil.calibration.fit import allan_log, fit_mag_log, fit_triad_log
from ins_hil.calibration.logs import LOG_READERS, read_log, read_plan
from ins_hil.commands._outputs import DOCS, out_dir, out_file
from ins_hil.nav import calibration as cal
from ins_hil.types import Vec

NAME = "calibrate"
HELP = "calibrate accelerometers, gyros, magnetometer or run an Allan-variance analysis from a recorded log"
DESCRIPTION = __doc__

KINDS = ("accel", "gyro", "mag", "allan", "bench")


# ---------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "kind", choices=KINDS, help="what to calibrate ('bench': measure accuracy on simulated runs, update the docs)"
    )
    p.add_argument("log", type=Path, nargs="?", help="recorded log (.csv; .ihlog via the runtime recorder)")
    p.add_argument(
        "--docs",
        type=Path,
        default=DOCS / "calibration.md",
        help="bench: Markdown file whose generated section is rewritten (default: the checkout's docs/calibration.md)",
    )
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        default=Path("calibration.toml"),
        help="calibration file to create or update (.toml or .json; default calibration.toml)",
    )
    p.add_argument(
        "--report", type=Path, default=None, help="report directory (default: <output stem>_report beside the output)"
    )
    p.add_argument(
        "--imu-id", type=int, default=None, help="IMU the calibration applies to (default: from the log, else any)"
    )
    p.add_argument(
        "--plan",
        default="book",
        help="positions: 'book' (accel: 16 × 45° about X then Y; gyro: Table 4.1) or a CSV "
        "with columns step,ref_x,ref_y,ref_z (reference in SI, body FRD)",
    )
    p.add_argument(
        "--rates", default="3,9", help="gyro: table rates in deg/s, comma-separated (default 3,9 as the book)"
    )
    p.add_argument(
        "--lat",
        type=float,
        default=None,
        help="latitude in deg: gravity magnitude (accel) and vertical Earth rate (gyro) for the references",
    )
    p.add_argument("--height", type=float, default=0.0, help="accel: ellipsoidal height in m for normal gravity")
    p.add_argument(
        "--max-std",
        type=float,
        default=None,
        help="motion threshold: per-axis sample std within a step (m/s² accel, rad/s gyro)",
    )
    p.add_argument(
        "--max-drift", type=float, default=None, help="motion threshold: change of the step mean between halves"
    )
    p.add_argument(
        "--range",
        dest="sat_range",
        type=float,
        default=0.0,
        help="sensor full scale (SI); samples at or beyond it count as saturated (default: flags only)",
    )
    p.add_argument(
        "--field", type=float, default=None, help="mag: local field magnitude in µT (default: keep the fitted radius)"
    )
    p.add_argument("--sensor", choices=["gyro", "accel", "both"], default="both", help="allan: which triad")
    p.add_argument(
        "--simulate",
        action="store_true",
        help="first write a simulated log with known errors to LOG, then calibrate it",
    )
    p.add_argument("--seed", type=int, default=1, help="--simulate: random seed")
    p.add_argument("--force", action="store_true", help="--simulate: overwrite an existing LOG (a simulated one)")


def _plan_refs(args: argparse.Namespace, kind: str) -> Vec:
    g = 9.80665 if args.lat is None else cal.earth.normal_gravity(math.radians(args.lat), args.height)
    if args.plan == "book":
        if kind == "accel":
            return cal.accel_references(cal.BOOK_ACCEL_POSITIONS, g)
        rates = [math.radians(float(r)) for r in args.rates.split(",") if r.strip()]
        lat = None if args.lat is None else math.radians(args.lat)
        return cal.gyro_references(cal.TABLE_4_1_TILTS, rates, lat)
    return read_plan(Path(args.plan))


def _limits(args: argparse.Namespace, base: cal.StepLimits) -> cal.StepLimits:
    return cal.StepLimits(
        max_std=base.max_std if args.max_std is None else args.max_std,
        max_drift=base.max_drift if args.max_drift is None else args.max_drift,
        min_samples=base.min_samples,
        saturation=args.sat_range,
    )


# ---------------------------------------------------------------------------


def _bad_arguments(args: argparse.Namespace) -> str | None:
    """Why the arguments cannot run (one line naming the flag or the file), or None: checked before the log is
    read (a long log takes a while) and before anything is written."""
    if args.kind == "bench":
        return None
    if args.log is None:
        return "the log file argument is missing"
    if args.output.suffix not in (".toml", ".json"):
        return f"--output {args.output}: must end in .toml or .json"
    if args.force and not args.simulate:
        return "--force: only with --simulate (it lets the simulated log overwrite LOG)"
    if args.simulate and os.path.lexists(args.log) and not args.force:  # a recorded log under that name would be lost
        return (
            f"{args.log}: exists; --simulate writes a new simulated log there: give a new name, remove it or add"
            " --force"
        )
    if not args.simulate:
        if not args.log.exists():
            return f"{args.log}: no such file"
        if args.log.is_dir():
            return f"{args.log}: a folder, not a log file"
        if args.log.suffix.lower() not in LOG_READERS:
            return f"{args.log}: unknown log type {args.log.suffix!r}; known: {', '.join(sorted(LOG_READERS))}"
    numbers = (("--lat", args.lat), ("--height", args.height), ("--field", args.field), ("--max-std", args.max_std),
               ("--max-drift", args.max_drift), ("--range", args.sat_range))  # fmt: skip
    for flag, v in numbers:
        if v is not None and not math.isfinite(v):
            return f"{flag} {v}: must be a finite number"
    if args.lat is not None and abs(args.lat) > 90.0:
        return f"--lat {args.lat:g}: must be within ±90°"
    if args.kind == "gyro" and args.plan == "book" and not args.simulate:
        try:
            rates = [float(r) for r in args.rates.split(",") if r.strip()]
        except ValueError:
            return f"--rates {args.rates}: expected comma-separated numbers (deg/s), e.g. 3,9"
        if not rates or not all(math.isfinite(r) and r > 0 for r in rates):
            return f"--rates {args.rates}: table rates must be positive numbers (deg/s), e.g. 3,9"
    return None


def run(args: argparse.Namespace) -> int:
    why = _bad_arguments(args)
    if why is not None:
        print(f"ins-hil calibrate {args.kind}: {why}", file=sys.stderr)
        return 2
    try:
        return _run(args)
    except cal.CalibrationError as e:
        print(f"ins-hil calibrate {args.kind}: {e} (no calibration written)", file=sys.stderr)
        return 1


def _run(args: argparse.Namespace) -> int:
    if args.kind == "bench":
        out_file(args.docs, "--docs")
        return bench(args.docs, args.seed)
    assert args.log is not None  # _bad_arguments
    out_file(args.output, "--output")  # every file this writes: refused before the work
    rep = args.report if args.report is not None else args.output.with_name(args.output.stem + "_report")
    out_dir(rep, "--report")
    if args.simulate:
        out_file(args.log, "LOG (--simulate)")
    if args.simulate:
        print(f"writing a simulated {args.kind} log to {args.log} ...", flush=True)
        print("  " + simulate_log(args.kind, args.log, args.seed))
        if args.kind == "gyro" and args.plan == "book":
            args.rates, args.lat = "30,90", 50.45
            print("  (simulated table rates 30 and 90 °/s at latitude 50.45°: using --rates 30,90 --lat 50.45)")
        if args.kind == "accel" and args.plan == "book":
            args.lat, args.height = 50.45, 100.0
    if args.output.exists():
        load_calibration(args.output)  # refuse early (before the work) if the file to update is broken
    refs = _plan_refs(args, args.kind) if args.kind in ("accel", "gyro") else None  # --plan read before the log
    print(f"reading {args.log} ...", flush=True)
    log = read_log(args.log, args.imu_id)
    made = not rep.exists()
    rep.mkdir(parents=True, exist_ok=True)
    lines: list[str] = [
        f"# ins-hil calibrate {args.kind}",
        "",
        f"Generated {datetime.now(UTC):%Y-%m-%d %H:%M UTC}.",
        "",
    ]
    try:
        if args.kind in ("accel", "gyro"):
            base = cal.ACCEL_LIMITS if args.kind == "accel" else cal.GYRO_LIMITS
            assert refs is not None
            new = fit_triad_log(log, args.kind, refs, _limits(args, base), rep, lines, str(args.log), args.plan)
        elif args.kind == "mag":
            new = fit_mag_log(log, None if args.field is None else args.field * 1e-6, rep, lines, str(args.log))
        else:
            sensors = ["gyro", "accel"] if args.sensor == "both" else [args.sensor]
            new = allan_log(log, sensors, rep, lines, str(args.log))
    except BaseException:  # no calibration: the report folder this run made goes too if nothing is in it
        if made and not any(rep.iterdir()):
            rep.rmdir()
        raise
    new.imu_id = args.imu_id if args.imu_id is not None else log.imu_id
    new.created = f"{datetime.now(UTC):%Y-%m-%dT%H:%M:%SZ}"
    new.source = str(args.log)
    if args.output.exists():
        old = load_calibration(args.output)
        if old.imu_id is not None and new.imu_id is not None and old.imu_id != new.imu_id:
            raise cal.CalibrationError(
                f"{args.output} holds the calibration of IMU {old.imu_id}, this log is for IMU {new.imu_id}; "
                "write it to another --output file"
            )
        merged = old.merged(new)
        sec = "noise" if args.kind == "allan" else args.kind
        print(f"updating {args.output} ([{sec}] replaced, other sections kept)")
    else:
        merged = new
        print(f"writing {args.output}")
    save_calibration(merged, args.output)
    md = rep / f"{args.kind}.md"
    md.write_text("\n".join(lines) + "\n")
    print(f"report: {md}")
    return 0
