"""`ins-hil calibrate accel|gyro|mag|allan LOG`: bench calibration from a recorded log.

Reads a log (CSV now; the runtime recorder's ``.ihlog`` through :data:`LOG_READERS`),
estimates the calibration with :mod:`ins_hil.nav.calibration` /
:mod:`ins_hil.nav.allan`, merges it into the calibration file (TOML or JSON) the
gateway loads at start, and writes a Markdown report with PNG plots.

CSV columns (header row required, SI units, body FRD; see docs/calibration.md):

* IMU logs: ``t`` (s, end of interval) and either increments
  ``dtheta_x,dtheta_y,dtheta_z`` (rad), ``dvel_x,dvel_y,dvel_z`` (m/s) with ``dt`` (s)
  — the :class:`~ins_hil.types.ImuSample` form — or rates ``gyro_x..z`` (rad/s) and
  ``accel_x..z`` (m/s²). Optional ``step`` (int: position/rate step, −1 = transit;
  without it quiet segments are detected), ``flags`` (ImuFlags bits; saturation
  bits are checked), ``imu_id``.
* Magnetometer logs: ``t``, ``mag_x,mag_y,mag_z`` (T).

``--simulate`` first writes a simulated log with known errors to LOG (and prints
them), so the whole workflow can be tried without hardware.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from ins_hil.machine import summary
from ins_hil.nav import allan as av
from ins_hil.nav import calibration as cal
from ins_hil.types import ImuFlags, ImuSample, MagSample, Vec

NAME = "calibrate"
HELP = "calibrate accelerometers, gyros, magnetometer or run an Allan-variance analysis from a recorded log"
DESCRIPTION = __doc__

KINDS = ("accel", "gyro", "mag", "allan", "bench")


@dataclass
class LogData:
    """What the calibration needs from a log (arrays over N samples; None when absent)."""

    t: Vec
    dt: float
    gyro: Vec | None = None  # (N, 3) rad/s
    accel: Vec | None = None  # (N, 3) m/s²
    dtheta: Vec | None = None  # (N, 3) rad
    dvel: Vec | None = None  # (N, 3) m/s
    mag: Vec | None = None  # (N, 3) T
    step: Vec | None = None  # (N,) int
    flags: Vec | None = None  # (N,) int
    imu_id: int | None = None


def read_csv_log(path: Path, imu_id: int | None = None) -> LogData:
    """Read a calibration CSV (columns in the module doc); CalibrationError names missing columns.

    With an ``imu_id`` column, ``imu_id`` selects the rows of one IMU (required when there are several).
    """
    try:
        with path.open(newline="") as f:
            header = next(csv.reader(f), None)
    except (OSError, UnicodeDecodeError) as e:
        raise cal.CalibrationError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from e
    if not header:
        raise cal.CalibrationError(f"{path}: empty file; a header row with column names is required")
    cols = [h.strip() for h in header]
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except ValueError as e:
        raise cal.CalibrationError(f"{path}: not a numeric CSV after the header ({e})") from e
    if data.shape[0] == 0:
        raise cal.CalibrationError(f"{path}: no data rows")
    if data.shape[1] != len(cols):
        raise cal.CalibrationError(f"{path}: {data.shape[1]} values per row but {len(cols)} header names")
    ix = {c: i for i, c in enumerate(cols)}
    if "imu_id" in ix:
        ids = sorted(int(i) for i in np.unique(data[:, ix["imu_id"]]))
        if imu_id is not None:
            data = data[data[:, ix["imu_id"]] == imu_id]
            if len(data) == 0:
                raise cal.CalibrationError(f"{path}: no samples of IMU {imu_id}; the log has IMUs {ids}")
        elif len(ids) > 1:
            raise cal.CalibrationError(f"{path}: samples of IMUs {ids}; choose one with --imu-id")

    def get3(prefix: str) -> Vec | None:
        names = [f"{prefix}_{a}" for a in "xyz"]
        have = [n in ix for n in names]
        if any(have) and not all(have):
            raise cal.CalibrationError(f"{path}: column(s) {[n for n in names if n not in ix]} missing")
        return data[:, [ix[n] for n in names]] if all(have) else None

    if "t" not in ix:
        raise cal.CalibrationError(f"{path}: column 't' (time, s) missing; columns are {cols}")
    vec = {p: get3(p) for p in ("dtheta", "dvel", "mag", "gyro", "accel")}
    t = data[:, ix["t"]]
    if len(t) > 1 and np.any(np.diff(t) <= 0):
        raise cal.CalibrationError(f"{path}: column 't' must increase strictly (row {int(np.argmin(np.diff(t))) + 2})")
    if "dt" in ix:
        dts = data[:, ix["dt"]]
        dt = float(np.median(dts))
    elif len(t) > 1:
        dts = np.diff(t, prepend=t[0] - (t[1] - t[0]))
        dt = float(np.median(np.diff(t)))
    else:
        raise cal.CalibrationError(f"{path}: one row and no 'dt' column")
    log = LogData(t=t, dt=dt, dtheta=vec["dtheta"], dvel=vec["dvel"], mag=vec["mag"])
    log.gyro = vec["gyro"]
    log.accel = vec["accel"]
    if log.dtheta is not None and log.gyro is None:
        log.gyro = log.dtheta / dts[:, None]
    if log.dvel is not None and log.accel is None:
        log.accel = log.dvel / dts[:, None]
    if log.gyro is not None and log.dtheta is None:
        log.dtheta = log.gyro * dts[:, None]
    if log.accel is not None and log.dvel is None:
        log.dvel = log.accel * dts[:, None]
    if "step" in ix:
        log.step = data[:, ix["step"]].astype(np.int64)
    if "flags" in ix:
        log.flags = data[:, ix["flags"]].astype(np.int64)
    if "imu_id" in ix:
        log.imu_id = int(data[0, ix["imu_id"]])
    return log


def log_from_records(records: Iterable[object], imu_id: int | None = None, where: str = "log") -> LogData:
    """LogData from recorded samples (``ImuSample``/``MagSample``; other records are skipped).

    This is how ``.ihlog`` files of the runtime recorder are read: no step labels (the quiet
    segments are detected), flags and imu_id from the samples.
    """
    imu: list[ImuSample] = []
    mag: list[MagSample] = []
    for r in records:
        if isinstance(r, ImuSample):
            imu.append(r)
        elif isinstance(r, MagSample):
            mag.append(r)
    ids = sorted({s.imu_id for s in imu})
    if imu_id is not None:
        imu = [s for s in imu if s.imu_id == imu_id]
        if not imu and ids:
            raise cal.CalibrationError(f"{where}: no samples of IMU {imu_id}; the log has IMUs {ids}")
    elif len(ids) > 1:
        raise cal.CalibrationError(f"{where}: samples of IMUs {ids}; choose one with --imu-id")
    mag_arr = np.array([m.field_b for m in mag], dtype=np.float64).reshape(-1, 3) if mag else None
    if imu:
        t = np.array([s.t for s in imu])
        dts = np.array([s.dt for s in imu])
        dth = np.array([s.dtheta for s in imu], dtype=np.float64)
        dv = np.array([s.dvel for s in imu], dtype=np.float64)
        return LogData(
            t=t,
            dt=float(np.median(dts)),
            gyro=dth / dts[:, None],
            accel=dv / dts[:, None],
            dtheta=dth,
            dvel=dv,
            mag=mag_arr,
            flags=np.array([s.flags for s in imu], dtype=np.int64),
            imu_id=imu[0].imu_id,
        )
    if mag_arr is not None:
        t = np.array([m.t for m in mag])
        return LogData(t=t, dt=float(np.median(np.diff(t))) if len(t) > 1 else 0.0, mag=mag_arr)
    raise cal.CalibrationError(f"{where}: no IMU or magnetometer samples")


def _read_ihlog(path: Path, imu_id: int | None = None) -> LogData:
    """The runtime recorder's ``.ihlog`` (``ins_hil.runtime.recorder.read_records``, all parts)."""
    try:
        from ins_hil.runtime import recorder  # type: ignore[attr-defined,unused-ignore]
    except ImportError as e:
        raise cal.CalibrationError(
            f"{path}: .ihlog logs need ins_hil.runtime.recorder (not in this build); "
            "export the log to CSV (columns: docs/calibration.md)"
        ) from e
    try:
        records = list(recorder.read_records(path))
    except (OSError, ValueError) as e:
        raise cal.CalibrationError(f"{path}: cannot read the recording ({e})") from e
    return log_from_records(records, imu_id, str(path))


#: log readers by file suffix: (path, imu_id or None) → LogData
LOG_READERS: dict[str, Callable[[Path, int | None], LogData]] = {".csv": read_csv_log, ".ihlog": _read_ihlog}


def read_log(path: Path, imu_id: int | None = None) -> LogData:
    reader = LOG_READERS.get(path.suffix.lower())
    if reader is None:
        raise cal.CalibrationError(f"{path}: unknown log type {path.suffix!r}; known: {sorted(LOG_READERS)}")
    return reader(path, imu_id)


def write_csv_log(path: Path, t: Vec, dt: float, columns: dict[str, Vec]) -> None:
    """Write a CSV log with ``t``, ``dt`` and named (N,) or (N, 3) columns (…_x/_y/_z)."""
    names = ["t", "dt"]
    cols = [t, np.full(len(t), dt)]
    for k, v in columns.items():
        v = np.asarray(v)
        if v.ndim == 2:
            names += [f"{k}_{a}" for a in "xyz"]
            cols += [v[:, 0], v[:, 1], v[:, 2]]
        else:
            names.append(k)
            cols.append(v)
    fmt = ["%.6f", "%.6g"] + ["%d" if k in ("step", "flags", "imu_id") else "%.10e" for k in names[2:]]
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=",".join(names), comments="", fmt=fmt)


# ---------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "kind", choices=KINDS, help="what to calibrate ('bench': measure accuracy on simulated runs, update the docs)"
    )
    p.add_argument("log", type=Path, nargs="?", help="recorded log (.csv; .ihlog via the runtime recorder)")
    p.add_argument(
        "--docs",
        type=Path,
        default=Path("docs/calibration.md"),
        help="bench: Markdown file whose generated section is rewritten (default docs/calibration.md)",
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


def _plan_refs(args: argparse.Namespace, kind: str) -> Vec:
    g = 9.80665 if args.lat is None else cal.earth.normal_gravity(math.radians(args.lat), args.height)
    if args.plan == "book":
        if kind == "accel":
            return cal.accel_references(cal.BOOK_ACCEL_POSITIONS, g)
        rates = [math.radians(float(r)) for r in args.rates.split(",") if r.strip()]
        lat = None if args.lat is None else math.radians(args.lat)
        return cal.gyro_references(cal.TABLE_4_1_TILTS, rates, lat)
    path = Path(args.plan)
    try:
        d = np.genfromtxt(path, delimiter=",", names=True)
    except OSError as e:
        raise cal.CalibrationError(f"--plan {path}: cannot read ({e})") from e
    need = ("step", "ref_x", "ref_y", "ref_z")
    if d.dtype.names is None or any(n not in d.dtype.names for n in need):
        raise cal.CalibrationError(f"--plan {path}: needs columns {list(need)}, has {d.dtype.names}")
    d = np.atleast_1d(d)
    order = np.argsort(d["step"])
    refs = np.column_stack([d["ref_x"][order], d["ref_y"][order], d["ref_z"][order]])
    if not np.all(np.isfinite(refs)) or not np.all(np.isfinite(d["step"])):
        raise cal.CalibrationError(f"--plan {path}: every row needs numeric step, ref_x, ref_y, ref_z")
    if np.any(np.diff(d["step"][order]) == 0):
        raise cal.CalibrationError(f"--plan {path}: a step number appears twice")
    return refs


def _limits(args: argparse.Namespace, base: cal.StepLimits) -> cal.StepLimits:
    return cal.StepLimits(
        max_std=base.max_std if args.max_std is None else args.max_std,
        max_drift=base.max_drift if args.max_drift is None else args.max_drift,
        min_samples=base.min_samples,
        saturation=args.sat_range,
    )


def _labels(log: LogData, signal: Vec, kind: str) -> Vec:
    if log.step is not None:
        return log.step
    print(f"  no 'step' column: detecting quiet segments of the {kind} signal")
    max_std = 0.05 if kind == "accel" else 0.01
    return cal.detect_steps(signal, log.dt, window=1.0, max_std=max_std, min_duration=5.0)


def _fmt_mat(m: Vec, digits: int = 6) -> str:
    return "\n".join("| " + " | ".join(f"{v: .{digits}f}" for v in row) + " |" for row in m)


def _triad_report(fit: cal.TriadFit, unit: str, refs: Vec, means: Vec) -> list[str]:
    d = fit.decomposition
    resid = means - (refs @ fit.matrix.T + fit.bias)
    lines = [
        f"* equations: {fit.n_equations} (12 unknowns); cond(R0) = {fit.cond:.3f} (eq. 4.16)",
        f"* deviation dev = ‖z2‖/‖z1‖ = **{fit.dev_percent:.4f} %** (eq. 4.17; 0 % is ideal, the book had 3–4 % "
        "(accel) and 0.82 % (gyro))",
        f"* residual rms per equation: {fit.residual_rms:.3e} {unit}",
        "",
        "A (m = A x + b, eq. 4.11/4.23):",
        "",
        "| | x | y | z |\n|---|---|---|---|",
        "\n".join(f"| {a} | " + " | ".join(f"{v: .6f}" for v in row) + " |" for a, row in zip("xyz", fit.matrix)),
        "",
        f"b = {np.array2string(fit.bias, precision=6)} {unit}; "
        f"b_book = S⁻¹b = {np.array2string(fit.bias_book, precision=6)}",
        "",
        f"Scale factors S = diag(A) = {np.array2string(d.scale, precision=6)} "
        f"(s = {np.array2string((d.scale - 1) * 1e6, precision=1)} ppm)",
        "",
        "Misalignment A_ε = S⁻¹A (book §4.2.1):\n",
        "|||| \n|---|---|---|\n" + _fmt_mat(d.misalignment),
        "",
        "Sensitivity I + εB_sym (eq. 4.20):\n",
        "|||| \n|---|---|---|\n" + _fmt_mat(d.sym),
        "",
        "Rotation I + εB_skew (eq. 4.21):\n",
        "|||| \n|---|---|---|\n" + _fmt_mat(d.skew),
        "",
        f"μ = {np.array2string(np.degrees(d.mu), precision=4)} deg (triad vs. table, eq. 4.21)",
        "",
        "Per-step residuals (measured mean − model):\n",
        "| step | ref x | ref y | ref z | res x | res y | res z |\n|---|---|---|---|---|---|---|",
    ]
    for k, (r, e) in enumerate(zip(refs, resid)):
        lines.append(f"| {k} | " + " | ".join(f"{v:.4f}" for v in r) + " | " + " | ".join(f"{v:.2e}" for v in e) + " |")
    return lines


def _plot_steps(
    path: Path, log: LogData, signal: Vec, labels: Vec, refs: Vec, fit: cal.TriadFit, unit: str, title: str
) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labs = sorted(int(u) for u in np.unique(labels) if u >= 0)
    means = np.array([signal[labels == k].mean(axis=0) for k in labs])
    resid = means - (refs @ fit.matrix.T + fit.bias)
    fig, ax = plt.subplots(2, 1, figsize=(9, 6.5))
    stride = max(1, len(log.t) // 20000)
    for i, c in enumerate("xyz"):
        ax[0].plot(log.t[::stride], signal[::stride, i], lw=0.6, label=c)
    for k in labs:
        tt = log.t[labels == k]
        ax[0].axvspan(tt[0], tt[-1], color="0.9", zorder=0)
    ax[0].set(xlabel="t [s]", ylabel=unit, title=f"{title}: log (steps shaded)")
    ax[0].legend(loc="upper right")
    w = 0.27
    for i, c in enumerate("xyz"):
        ax[1].bar(np.arange(len(labs)) + (i - 1) * w, resid[:, i], w, label=c)
    ax[1].set(
        xlabel="step", ylabel=f"residual [{unit}]", title=f"residual after calibration (dev {fit.dev_percent:.3f} %)"
    )
    ax[1].legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _do_triad(args: argparse.Namespace, log: LogData, kind: str, rep: Path, lines: list[str]) -> cal.SensorCalibration:
    signal = log.accel if kind == "accel" else log.gyro
    if signal is None:
        need = "accel_x..z or dvel_x..z" if kind == "accel" else "gyro_x..z or dtheta_x..z"
        raise cal.CalibrationError(f"{args.log}: no {kind} columns ({need})")
    refs = _plan_refs(args, kind)
    labels = _labels(log, signal, kind)
    if kind == "accel":
        fit = cal.calibrate_accel(signal, labels, refs, _limits(args, cal.ACCEL_LIMITS), log.flags)
        unit, title = "m/s²", "Accelerometer calibration (book §4.2.1)"
    else:
        fit = cal.calibrate_gyro(signal, labels, refs, _limits(args, cal.GYRO_LIMITS), log.flags)
        unit, title = "rad/s", "Rate-gyro calibration (book §4.2.2)"
    labs = sorted(int(u) for u in np.unique(labels) if u >= 0)
    means = np.array([signal[labels == k].mean(axis=0) for k in labs])
    png = rep / f"{kind}_steps.png"
    _plot_steps(png, log, signal, labels, refs, fit, unit, title)
    lines += [f"## {title}", "", f"Log `{args.log}`, plan `{args.plan}`, {len(labs)} steps.", ""]
    lines += _triad_report(fit, unit, refs, means)
    lines += ["", f"![steps and residuals]({png.name})", ""]
    print(f"  {kind}: {fit.n_equations} equations, dev {fit.dev_percent:.4f} %, cond(R0) {fit.cond:.2f}")
    print(
        f"  scale factors {np.array2string(np.diag(fit.matrix), precision=6)}, "
        f"bias {np.array2string(fit.bias, precision=6)} {unit}"
    )
    out = cal.SensorCalibration()
    setattr(out, kind, cal.TriadCalibration.from_fit(fit, cal.UNITS[kind]))
    return out


def _do_mag(args: argparse.Namespace, log: LogData, rep: Path, lines: list[str]) -> cal.SensorCalibration:
    if log.mag is None:
        raise cal.CalibrationError(f"{args.log}: no magnetometer columns mag_x, mag_y, mag_z")
    fit = cal.fit_ellipsoid(log.mag, None if args.field is None else args.field * 1e-6)
    corr = cal.TriadCalibration.from_fit(fit, "T").correct(log.mag)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(11, 3.8))
    for i, (a, b) in enumerate([(0, 1), (0, 2), (1, 2)]):
        ax[i].plot(log.mag[:, a] * 1e6, log.mag[:, b] * 1e6, ".", ms=1.5, label="raw")
        ax[i].plot(corr[:, a] * 1e6, corr[:, b] * 1e6, ".", ms=1.5, label="corrected")
        ax[i].set(xlabel=f"{'xyz'[a]} [µT]", ylabel=f"{'xyz'[b]} [µT]", aspect="equal")
    ax[0].legend(loc="upper right", markerscale=5)
    fig.suptitle(f"Magnetometer hard/soft iron: |m| rms error {fit.residual_rms * 1e9:.1f} nT after correction")
    fig.tight_layout()
    png = rep / "mag_ellipsoid.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    raw_n = np.linalg.norm(log.mag, axis=1)
    lines += [
        "## Magnetometer hard/soft-iron calibration (ellipsoid fit)",
        "",
        f"Log `{args.log}`, {len(log.mag)} samples; sphere coverage {fit.coverage:.3f} (1/3 = full sphere).",
        "",
        f"* hard iron b = {np.array2string(fit.bias * 1e6, precision=3)} µT",
        f"* field magnitude after correction {fit.radius * 1e6:.3f} µT; |m| rms error {fit.residual_rms * 1e9:.2f} nT "
        f"(raw |m| spread {np.std(raw_n) * 1e9:.1f} nT)",
        "",
        "Soft iron A (m = A x + b, symmetric):\n",
        "|||| \n|---|---|---|\n" + _fmt_mat(fit.matrix),
        "",
        f"![raw and corrected field]({png.name})",
        "",
    ]
    print(
        f"  mag: hard iron {np.array2string(fit.bias * 1e6, precision=3)} µT, "
        f"|m| rms error {fit.residual_rms * 1e9:.2f} nT"
    )
    return cal.SensorCalibration(mag=cal.TriadCalibration.from_fit(fit, "T"))


def _do_allan(args: argparse.Namespace, log: LogData, rep: Path, lines: list[str]) -> cal.SensorCalibration:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = cal.SensorCalibration()
    which = ["gyro", "accel"] if args.sensor == "both" else [args.sensor]
    lines += [
        "## Allan variance (overlapping, IEEE 952)",
        "",
        f"Log `{args.log}`, {len(log.t)} samples, {len(log.t) * log.dt:.0f} s at dt = {log.dt:g} s.",
        "",
    ]
    for s in which:
        inc = log.dtheta if s == "gyro" else log.dvel
        if inc is None:
            raise cal.CalibrationError(f"{args.log}: allan --sensor {s} needs the {s} columns")
        if log.flags is not None:
            bit = int(ImuFlags.GYRO_SATURATED if s == "gyro" else ImuFlags.ACCEL_SATURATED)
            ns = int(np.count_nonzero(log.flags & bit))
            if ns:
                raise cal.CalibrationError(
                    f"{args.log}: {ns} {s} samples flagged saturated; a static record must not saturate"
                )
        print(f"  allan {s}: {len(inc)} samples ...", flush=True)
        res = av.allan_deviation(inc, log.dt)
        u, ru, wu = ("rad/s", "rad/s/√Hz", "rad/s/√s") if s == "gyro" else ("m/s²", "m/s²/√Hz", "m/s²/√s")
        fig, ax = plt.subplots(figsize=(7.5, 5.5))
        lines += [
            f"### {s}",
            "",
            "| axis | N (white) | B (bias instability) | K (rate random walk) | N read-off | "
            "B read-off | K read-off | τ at minimum |",
            "|---|---|---|---|---|---|---|---|",
        ]
        params = []
        for i, c in enumerate("xyz"):
            p = av.noise_parameters(res, i)
            params.append(p)
            lines.append(
                f"| {c} | {p.random_walk:.3e} | {p.bias_instability:.3e} | {p.rate_random_walk:.3e} | "
                f"{p.random_walk_readoff:.3e} | {p.bias_instability_readoff:.3e} | {p.rate_random_walk_readoff:.3e} | "
                f"{p.tau_min:.1f} s |"
            )
            ax.loglog(res.tau, res.adev[:, i], "o-", ms=3, lw=1, label=f"{c}")
            ax.loglog(res.tau, av.model_adev(res.tau, p), "--", lw=0.8, color=ax.lines[-1].get_color())
        p0 = params[0]
        ax.loglog(res.tau, p0.random_walk / np.sqrt(res.tau), ":", color="0.4", label="slope −½ (N)")
        if p0.rate_random_walk > 0:
            ax.loglog(res.tau, p0.rate_random_walk * np.sqrt(res.tau / 3), "-.", color="0.4", label="slope +½ (K)")
        ax.axhline(p0.bias_instability * av.B_FACTOR, color="0.6", lw=0.8, label="0.664 B")
        ax.set(xlabel="τ [s]", ylabel=f"Allan deviation [{u}]", title=f"{s}: overlapping Allan deviation (dashed: fit)")
        ax.grid(True, which="major", alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        png = rep / f"allan_{s}.png"
        fig.savefig(png, dpi=110)
        plt.close(fig)
        lines += [
            "",
            f"Units: N {ru}, B {u}, K {wu}; "
            "fit = weighted least squares of σ² = N²/τ + 0.44 B² + K²τ/3; read-off = slope lines / flat floor.",
            "",
            f"![Allan deviation]({png.name})",
            "",
        ]
        out.noise[s] = {
            "random_walk": float(np.mean([p.random_walk for p in params])),
            "bias_instability": float(np.mean([p.bias_instability for p in params])),
            "rate_random_walk": float(np.mean([p.rate_random_walk for p in params])),
            "tau_min": float(np.mean([p.tau_min for p in params])),
        }
        print(
            f"  allan {s}: N {out.noise[s]['random_walk']:.3e} {ru}, B {out.noise[s]['bias_instability']:.3e} {u}, "
            f"K {out.noise[s]['rate_random_walk']:.3e} {wu}"
        )
    return out


# ---------------------------------------------------------------------------


def simulate_log(kind: str, path: Path, seed: int) -> str:
    """Write a simulated log for ``kind`` with known errors; returns a description of the truth."""
    from ins_hil.sim import calibration as simcal
    from ins_hil.sim.sensors import mems_accel, mems_gyro

    rng = np.random.default_rng(seed)
    g, a = mems_gyro(rng), mems_accel(rng)
    if kind in ("accel", "gyro"):
        if kind == "accel":
            run = simcal.accel_static_run(g, a, dt=0.02, step_time=20.0, seed=seed)
            m = a
        else:
            # 30 and 90 °/s: whole revolutions in 12 s, so the horizontal Earth rate averages out
            run = simcal.rate_table_run(
                g, a, rates=(math.radians(30), math.radians(90)), step_time=12.0, dt=0.02, seed=seed
            )
            m = g
        write_csv_log(
            path,
            run.imu.t,
            run.imu.dt,
            {"dtheta": run.imu.dtheta, "dvel": run.imu.dvel, "step": run.labels, "flags": run.imu.flags},
        )
        return (
            f"simulated {kind}: A = {np.array2string(m.matrix(), precision=6)}, "
            f"b = {np.array2string(m.bias, precision=6)}; lat 50.45°"
        )
    if kind == "mag":
        hi = np.array([20e-6, -12e-6, 7e-6])
        si = np.array([[1.08, 0.04, -0.02], [0.04, 0.95, 0.03], [-0.02, 0.03, 1.02]])
        t, mag = simcal.mag_rotation_run(hard_iron=hi, soft_iron=si, seed=seed)
        write_csv_log(path, t, float(t[1] - t[0]), {"mag": mag})
        return f"simulated mag: hard iron {hi * 1e6} µT, soft iron {si.tolist()}, |F| = 50 µT"
    dt = 0.05
    gy = simcal.static_noise_record(20000, dt, 3e-5, 1e-4, 3e-5, bias=g.bias, seed=seed)
    ac = simcal.static_noise_record(20000, dt, 6.9e-4, 1e-3, 1e-4, bias=np.array([0.0, 0.0, -9.8]), seed=seed + 1)
    write_csv_log(path, dt * np.arange(1, len(gy) + 1), dt, {"dtheta": gy, "dvel": ac})
    return (
        "simulated static record 20000 s at 20 Hz: gyro N 3e-5 rad/s/√Hz, B 1e-4 rad/s, K 3e-5 rad/s/√s; "
        "accel N 6.9e-4 m/s²/√Hz, B 1e-3 m/s², K 1e-4 m/s²/√s"
    )


BENCH_BEGIN = "<!-- calibrate bench: begin (generated by `ins-hil calibrate bench`, do not edit) -->"
BENCH_END = "<!-- calibrate bench: end -->"


def bench(docs: Path, seed: int) -> int:
    """Recover known errors from simulated runs (several seeds), time the pieces, update ``docs``."""
    import time

    from ins_hil.sim import calibration as simcal
    from ins_hil.sim.sensors import mems_accel, mems_gyro

    rows: list[str] = []
    seeds = [seed + k for k in range(3)]
    print(f"calibrate bench: seeds {seeds}", flush=True)

    def triad_rows(kind: str) -> None:
        e_s, e_m, e_b, devs, t_fit = [], [], [], [], []
        for sd in seeds:
            rng = np.random.default_rng(100 + sd)
            g, a = mems_gyro(rng), mems_accel(rng)
            if kind == "accel":
                run = simcal.accel_static_run(g, a, dt=0.02, step_time=20.0, seed=sd)
                t0 = time.perf_counter()
                fit = cal.calibrate_accel(run.accel, run.labels, run.references)
                m, tb = a, run.imu.accel_bias[run.labels >= 0].mean(axis=0)
            else:
                rates = (math.radians(30.0), math.radians(90.0))
                run = simcal.rate_table_run(g, a, rates=rates, step_time=12.0, dt=0.02, seed=sd)
                t0 = time.perf_counter()
                fit = cal.calibrate_gyro(run.gyro, run.labels, run.references)
                m, tb = g, run.imu.gyro_bias[run.labels >= 0].mean(axis=0)
            t_fit.append(time.perf_counter() - t0)
            st = np.diag(m.matrix())
            e_s.append(np.abs(np.diag(fit.matrix) - st).max())
            mis = fit.decomposition.misalignment - (m.matrix() / st[:, None])
            np.fill_diagonal(mis, 0.0)
            e_m.append(math.degrees(np.abs(mis).max()))
            e_b.append(100 * np.max(np.abs(fit.bias - tb) / np.abs(tb)))
            devs.append(fit.dev_percent)
        unit = "m/s²" if kind == "accel" else "rad/s"
        rows.append(
            f"| {kind} ({'16 positions, 20 s' if kind == 'accel' else 'Table 4.1 × ±ω × 30, 90 °/s, 12 s'}) | "
            f"{max(e_s):.1e} | {max(e_m):.4f}° | {max(e_b):.2f} % | {max(devs):.4f} % | {1e3 * np.mean(t_fit):.1f} ms |"
        )
        print(f"  {kind}: worst scale {max(e_s):.1e}, misalignment {max(e_m):.4f} deg, bias {max(e_b):.2f} % ({unit})")

    triad_rows("accel")
    triad_rows("gyro")
    hi = np.array([20e-6, -12e-6, 7e-6])
    si = np.array([[1.08, 0.04, -0.02], [0.04, 0.95, 0.03], [-0.02, 0.03, 1.02]])
    mag_err = []
    for sd in seeds:
        _, mm = simcal.mag_rotation_run(duration=60.0, rate=20.0, hard_iron=hi, soft_iron=si, seed=sd)
        t0 = time.perf_counter()
        mf = cal.fit_ellipsoid(mm, field_norm=50e-6)
        dtm = time.perf_counter() - t0
        mag_err.append((np.abs(mf.bias - hi).max() * 1e9, np.abs(mf.matrix - si).max(), mf.residual_rms * 1e9, dtm))
    me = np.array(mag_err)
    print(f"  mag: worst hard iron {me[:, 0].max():.1f} nT, soft iron {me[:, 1].max():.1e}")
    truth = {"random_walk": 3e-5, "bias_instability": 1e-4, "rate_random_walk": 3e-5}
    worst = dict.fromkeys(truth, 0.0)
    worst_ro = dict.fromkeys(truth, 0.0)
    t_av = []
    for sd in seeds:
        inc = simcal.static_noise_record(20000.0, 0.05, 3e-5, 1e-4, 3e-5, seed=sd)
        t0 = time.perf_counter()
        res = av.allan_deviation(inc, 0.05)
        t_av.append(time.perf_counter() - t0)
        for ax in range(3):
            p = av.noise_parameters(res, ax).as_dict()
            for k, v in truth.items():
                worst[k] = max(worst[k], abs(p[k] / v - 1) * 100)
                worst_ro[k] = max(worst_ro[k], abs(p[k + "_readoff"] / v - 1) * 100)
    print(
        f"  allan: worst fit error N {worst['random_walk']:.1f} %, B {worst['bias_instability']:.1f} %, "
        f"K {worst['rate_random_walk']:.1f} %"
    )
    c = cal.SensorCalibration(
        accel=cal.TriadCalibration(np.eye(3) * 1.001, np.array([0.1, 0.2, 0.3])),
        gyro=cal.TriadCalibration(np.eye(3) * 1.001, np.array([1e-3, 2e-3, 3e-3])),
    )
    smp = ImuSample(t=0.0, dt=0.005, dtheta=np.array([1e-3, 2e-3, 3e-3]), dvel=np.array([0.0, 0.0, -0.049]))
    n_ap = 20000
    t0 = time.perf_counter()
    for _ in range(n_ap):
        c.apply(smp)
    t_apply = (time.perf_counter() - t0) / n_ap * 1e6
    print(f"  apply(): {t_apply:.1f} µs per IMU sample")
    text = [
        BENCH_BEGIN,
        "",
        f"Measured by `ins-hil calibrate bench` on {datetime.now(UTC):%Y-%m-%d %H:%M UTC}; machine: {summary()}.",
        f"Worst case over seeds {seeds} (mems_accel/mems_gyro error draws incl. white noise and bias instability;",
        "bias error relative to the mean true bias during the steps).",
        "",
        "| run | scale-factor error | misalignment error | bias error | dev (eq. 4.17) | LS time |",
        "|---|---|---|---|---|---|",
        *rows,
        "",
        f"Magnetometer (60 s tumble at 20 Hz, 0.1 µT noise, |F| = 50 µT given): hard iron within "
        f"{me[:, 0].max():.1f} nT, soft-iron matrix within {me[:, 1].max():.1e}, |m| rms after correction "
        f"{me[:, 2].max():.0f} nT, fit {1e3 * me[:, 3].mean():.1f} ms.",
        "",
        "Allan variance (20000 s at 20 Hz, 4·10⁵ samples × 3 axes; N = 3e-5 rad/s/√Hz, B = 1e-4 rad/s, "
        "K = 3e-5 rad/s/√s):",
        "",
        "| term | worst fit error | worst read-off error |",
        "|---|---|---|",
        *[f"| {k} | {worst[k]:.1f} % | {worst_ro[k]:.1f} % |" for k in truth],
        "",
        f"`allan_deviation` on 4·10⁵ × 3 samples: {1e3 * np.mean(t_av):.0f} ms. The read-off B and N are biased "
        "high here because the regimes overlap (crossovers at 0.2 s and 15 s); the joint fit is what the command "
        "writes to the file.",
        "",
        f"`SensorCalibration.apply` (accel + gyro): {t_apply:.1f} µs per IMU sample.",
        "",
        BENCH_END,
    ]
    old = docs.read_text() if docs.exists() else "# Calibration\n\n"
    if BENCH_BEGIN in old and BENCH_END in old:
        head, rest = old.split(BENCH_BEGIN, 1)
        new = head + "\n".join(text) + rest.split(BENCH_END, 1)[1]
    else:
        new = old.rstrip("\n") + "\n\n## Measured accuracy\n\n" + "\n".join(text) + "\n"
    docs.parent.mkdir(parents=True, exist_ok=True)
    docs.write_text(new)
    print(f"updated {docs}")
    return 0


def run(args: argparse.Namespace) -> int:
    try:
        return _run(args)
    except cal.CalibrationError as e:
        print(f"ins-hil calibrate {args.kind}: {e}", file=sys.stderr)
        print("no calibration written", file=sys.stderr)
        return 1


def _run(args: argparse.Namespace) -> int:
    if args.kind == "bench":
        return bench(args.docs, args.seed)
    if args.log is None:
        raise cal.CalibrationError(f"calibrate {args.kind}: the log file argument is missing")
    if args.output.suffix not in (".toml", ".json"):
        raise cal.CalibrationError(f"--output {args.output}: must end in .toml or .json")
    if args.simulate:
        print(f"writing a simulated {args.kind} log to {args.log} ...", flush=True)
        print("  " + simulate_log(args.kind, args.log, args.seed))
        if args.kind == "gyro" and args.plan == "book":
            args.rates, args.lat = "30,90", 50.45
            print("  (simulated table rates 30 and 90 °/s at latitude 50.45°: using --rates 30,90 --lat 50.45)")
        if args.kind == "accel" and args.plan == "book":
            args.lat, args.height = 50.45, 100.0
    print(f"reading {args.log} ...", flush=True)
    log = read_log(args.log, args.imu_id)
    if args.output.exists():
        cal.load_calibration(args.output)  # refuse early (before the work) if the file to update is broken
    rep = args.report if args.report is not None else args.output.with_name(args.output.stem + "_report")
    rep.mkdir(parents=True, exist_ok=True)
    lines: list[str] = [
        f"# ins-hil calibrate {args.kind}",
        "",
        f"Generated {datetime.now(UTC):%Y-%m-%d %H:%M UTC}.",
        "",
    ]
    if args.kind in ("accel", "gyro"):
        new = _do_triad(args, log, args.kind, rep, lines)
    elif args.kind == "mag":
        new = _do_mag(args, log, rep, lines)
    else:
        new = _do_allan(args, log, rep, lines)
    new.imu_id = args.imu_id if args.imu_id is not None else log.imu_id
    new.created = f"{datetime.now(UTC):%Y-%m-%dT%H:%M:%SZ}"
    new.source = str(args.log)
    if args.output.exists():
        old = cal.load_calibration(args.output)
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
    merged.save(args.output)
    md = rep / f"{args.kind}.md"
    md.write_text("\n".join(lines) + "\n")
    print(f"report: {md}")
    return 0
