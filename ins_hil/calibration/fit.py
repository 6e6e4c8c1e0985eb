"""Calibration of a recorded log: the fits of :mod:`ins_hil.nav.calibration` / :mod:`ins_hil.nav.allan`
on a :class:`~ins_hil.calibration.logs.LogData`, with the Markdown report section and PNG plots
(``ins-hil calibrate accel|gyro|mag|allan``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ins_hil.calibration.logs import LogData
from ins_hil.nav import allan as av
from ins_hil.nav import calibration as cal
from ins_hil.types import ImuFlags, Vec

#: where progress lines go (stdout by default)
Echo = Callable[[str], None]


def _echo(line: str) -> None:
    print(line, flush=True)


def step_labels(log: LogData, signal: Vec, kind: str, echo: Echo = _echo) -> Vec:
    """Step labels of the log (its ``step`` column, else the quiet segments detected in ``signal``)."""
    if log.step is not None:
        return log.step
    echo(f"  no 'step' column: detecting quiet segments of the {kind} signal")
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


def fit_triad_log(
    log: LogData,
    kind: str,
    refs: Vec,
    limits: cal.StepLimits,
    rep: Path,
    lines: list[str],
    where: str,
    plan: str,
    echo: Echo = _echo,
) -> cal.SensorCalibration:
    """Fit the accelerometer (``kind`` "accel") or gyro triad of ``log`` against the plan's references
    ``refs`` (SI, body FRD); appends the report section to ``lines`` and its plot to ``rep``."""
    signal = log.accel if kind == "accel" else log.gyro
    if signal is None:
        need = "accel_x..z or dvel_x..z" if kind == "accel" else "gyro_x..z or dtheta_x..z"
        raise cal.CalibrationError(f"{where}: no {kind} columns ({need})")
    labels = step_labels(log, signal, kind, echo)
    if kind == "accel":
        fit = cal.calibrate_accel(signal, labels, refs, limits, log.flags)
        unit, title = "m/s²", "Accelerometer calibration (book §4.2.1)"
    else:
        fit = cal.calibrate_gyro(signal, labels, refs, limits, log.flags)
        unit, title = "rad/s", "Rate-gyro calibration (book §4.2.2)"
    labs = sorted(int(u) for u in np.unique(labels) if u >= 0)
    means = np.array([signal[labels == k].mean(axis=0) for k in labs])
    png = rep / f"{kind}_steps.png"
    _plot_steps(png, log, signal, labels, refs, fit, unit, title)
    lines += [f"## {title}", "", f"Log `{where}`, plan `{plan}`, {len(labs)} steps.", ""]
    lines += _triad_report(fit, unit, refs, means)
    lines += ["", f"![steps and residuals]({png.name})", ""]
    echo(f"  {kind}: {fit.n_equations} equations, dev {fit.dev_percent:.4f} %, cond(R0) {fit.cond:.2f}")
    echo(
        f"  scale factors {np.array2string(np.diag(fit.matrix), precision=6)}, "
        f"bias {np.array2string(fit.bias, precision=6)} {unit}"
    )
    out = cal.SensorCalibration()
    setattr(out, kind, cal.TriadCalibration.from_fit(fit, cal.UNITS[kind]))
    return out


def fit_mag_log(
    log: LogData, field_norm: float | None, rep: Path, lines: list[str], where: str, echo: Echo = _echo
) -> cal.SensorCalibration:
    """Hard/soft-iron ellipsoid fit of the magnetometer samples of ``log`` (``field_norm`` in T, None = keep
    the fitted radius); appends the report section to ``lines`` and its plot to ``rep``."""
    if log.mag is None:
        raise cal.CalibrationError(f"{where}: no magnetometer columns mag_x, mag_y, mag_z")
    fit = cal.fit_ellipsoid(log.mag, field_norm)
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
        f"Log `{where}`, {len(log.mag)} samples; sphere coverage {fit.coverage:.3f} (1/3 = full sphere).",
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
    echo(
        f"  mag: hard iron {np.array2string(fit.bias * 1e6, precision=3)} µT, "
        f"|m| rms error {fit.residual_rms * 1e9:.2f} nT"
    )
    return cal.SensorCalibration(mag=cal.TriadCalibration.from_fit(fit, "T"))


def allan_log(
    log: LogData, sensors: list[str], rep: Path, lines: list[str], where: str, echo: Echo = _echo
) -> cal.SensorCalibration:
    """Allan-variance noise figures (N, B, K per axis, book/IEEE 952) of the ``sensors`` ("gyro", "accel")
    of a static ``log``; appends the report section to ``lines`` and its plots to ``rep``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = cal.SensorCalibration()
    lines += [
        "## Allan variance (overlapping, IEEE 952)",
        "",
        f"Log `{where}`, {len(log.t)} samples, {len(log.t) * log.dt:.0f} s at dt = {log.dt:g} s.",
        "",
    ]
    for s in sensors:
        inc = log.dtheta if s == "gyro" else log.dvel
        if inc is None:
            raise cal.CalibrationError(f"{where}: allan --sensor {s} needs the {s} columns")
        if log.flags is not None:
            bit = int(ImuFlags.GYRO_SATURATED if s == "gyro" else ImuFlags.ACCEL_SATURATED)
            ns = int(np.count_nonzero(log.flags & bit))
            if ns:
                raise cal.CalibrationError(
                    f"{where}: {ns} {s} samples flagged saturated; a static record must not saturate"
                )
        echo(f"  allan {s}: {len(inc)} samples ...")
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
        echo(
            f"  allan {s}: N {out.noise[s]['random_walk']:.3e} {ru}, B {out.noise[s]['bias_instability']:.3e} {u}, "
            f"K {out.noise[s]['rate_random_walk']:.3e} {wu}"
        )
    return out
