"""Figures of the reproduction report (matplotlib, Agg backend, PNG)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ins_hil.platform_ins.testbed import TestbedResult

from . import seed001, seed002

MU_GRID = (1.0, 0.5, 0.2, 0.1, 0.05, 0.02, 0.01)
_LAWS = {  # seed 002's printed drift laws
    "revers1h": (0.042, 2, "Revers1h"),
    "rk21": (0.083, 2, "RK21"),
    "picard_literal": (0.0021, 2, "Picard (literal eq. 6)"),
    "exprvrs1h": (7.3e-3, 4, "ExpRvrs1h (new)"),
}


def coning_figure(path: Path) -> Path:
    """Dimensionless coning drift δ(μ) of the seed-002 algorithms (ours: markers; printed laws: lines)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5))
    mu_line = np.logspace(-2, 0, 50)
    for i, (kind, (coef, power, label)) in enumerate(_LAWS.items()):
        color = f"C{i}"
        d = [abs(seed002.coning_drift(kind, mu)) for mu in MU_GRID]
        ax.loglog(MU_GRID, d, "o", color=color, label=f"{label}: ours")
        ax.loglog(mu_line, coef * mu_line**power, "--", color=color, lw=1, label=f"{label}: {coef:g} μ^{power} (paper)")
    ax.set_xlabel("μ = ω h")
    ax.set_ylabel("δ = |dψ/dt| / (ω a²)")
    ax.set_title("Seed 002 coning test (a = 0.1 rad, ω = 1 rad/s, ε = 90°)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def schuler_figure(path: Path) -> Path:
    """North velocity and position error of the free-inertial Schuler run with the eq. 105 solution."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run = seed001.schuler_run()
    w0 = 2 * np.pi / run.period_theory
    tm = run.t / 60.0
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    a1.plot(tm, run.dv_north, label="INS − truth")
    a1.plot(tm, np.cos(w0 * run.t), "--", label="δv cos ω₀t")
    a1.set_ylabel("δv_N [m/s]")
    a1.legend(fontsize=8)
    a2.plot(tm, run.dr_north, label="INS − truth")
    a2.plot(tm, np.sin(w0 * run.t) / w0, "--", label="δv sin(ω₀t)/ω₀ (seed 001 eq. 105)")
    a2.set_ylabel("δr_N [m]")
    a2.set_xlabel(f"time [min]  (Schuler period {run.period_theory / 60:.2f} min)")
    a2.legend(fontsize=8)
    for a in (a1, a2):
        a.grid(alpha=0.3)
    fig.suptitle("Seed 001: Schuler oscillation, stationary INS, δv_N(0) = 1 m/s")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_figures(directory: Path) -> list[Path]:
    directory.mkdir(parents=True, exist_ok=True)
    return [
        coning_figure(directory / "reproduction_coning.png"),
        schuler_figure(directory / "reproduction_schuler.png"),
        seed004_figure(directory / "reproduction_seed004.png"),
    ]


def seed004_figure(path: Path) -> Path:
    """Seed-004 test bed (manoeuvres): true north-channel errors and the corrections' estimates."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from . import seed004

    res, _ = seed004.testbed()
    tm = res.t_k / 60.0
    scale = (1.0, 1e6, 180.0 / np.pi * 3600.0)
    labels = ("δv_N [m/s]", "Φ_E [µrad]", "ω_E^dr [°/h]")
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    for i, ax in enumerate(axes):
        ax.plot(tm, res.x_true[:, i] * scale[i], "k", lw=1.5, label="true error (uncorrected output)")
        for name, style in (("classical", "C0-"), ("reduced adaptive", "C3-"), ("reduced non-adaptive", "C2:")):
            ax.plot(tm, res.est[name][:, i] * scale[i], style, lw=1, label=f"estimate: {name}")
        ax.set_ylabel(labels[i])
        ax.grid(alpha=0.3)
    for t0, d, _, _ in res.cfg.pulses:
        for ax in axes:
            ax.axvspan(t0 / 60, (t0 + 2 * d) / 60, color="0.85", lw=0)
    axes[0].legend(fontsize=7, loc="upper left")
    axes[-1].set_xlabel("time [min] (grey: manoeuvres)")
    fig.suptitle("Seed 004: platform-INS north channel, simulated test bed")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def platform_ins_figures(res: TestbedResult, directory: Path) -> list[Path]:
    """`ins-hil demo platform-ins`: four PNGs of one seed-004 test-bed run (DIGEST_001_004 §4).

    platform_angles: Φ_E, Φ_N, Φ_up true vs reconstructed from the precession angles (eqs. 4, 5) and the
    residuals; level_flight: the classical measurement a_y^p (eq. 8) beside Φ_E g and the classical estimates;
    reduced: the reduced measurements S⁻¹z* (eq. 21) against the true north-channel state, cond(S) in the
    title; adaptive: the adaptive filter's Sage–Husa Q and R scales over time.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ins_hil.platform_ins import model as pim

    directory.mkdir(parents=True, exist_ok=True)
    out: list[Path] = []
    tm, tk = res.t / 60.0, res.t_k / 60.0
    urad = 1e6
    dph = 180.0 / np.pi * 3600.0  # rad/s → °/h

    fig, axes = plt.subplots(3, 2, figsize=(11, 7), sharex="col")
    zoom = res.t <= 60.0  # the first minute: the test bed's 5-s oscillation (eq. 22) resolved
    for i, name in enumerate(("Φ_E", "Φ_N", "Φ_up")):
        true = res.truth[:, 2 + i]
        axes[i, 0].plot(res.t[zoom], res.phi_second[zoom, i] * urad, "C3", lw=2.5, alpha=0.6, label="eq. 5")
        axes[i, 0].plot(res.t[zoom], res.phi_first[zoom, i] * urad, "C0", lw=1.0, label="eq. 4")
        axes[i, 0].plot(res.t[zoom], true[zoom] * urad, "k", lw=0.8, label="true")
        axes[i, 0].set_ylabel(f"{name} [µrad]")
        for arr, lab, st in ((res.phi_first, "eq. 4 − true", "C0"), (res.phi_second, "eq. 5 − true", "C3")):
            axes[i, 1].plot(tm, (arr[:, i] - true) * urad, st, lw=0.5, label=lab)
        axes[i, 1].set_ylabel("residual [µrad]")
    axes[0, 0].legend(fontsize=7)
    axes[0, 1].legend(fontsize=7)
    axes[-1, 0].set_xlabel("time [s] (first minute)")
    axes[-1, 1].set_xlabel("time [min]")
    fig.suptitle("Platform angles reconstructed from the precession-angle sensors")
    fig.tight_layout()
    out.append(directory / "platform_angles.png")
    fig.savefig(out[-1], dpi=100)
    plt.close(fig)

    scale = (1.0, urad, dph)
    labels = ("δv_N [m/s]", "Φ_E [µrad]", "ω_E^dr [°/h]")
    fig, axes = plt.subplots(4, 1, figsize=(9, 9), sharex=True)
    axes[0].plot(tk, res.z_acc * 1e3, "C0", lw=0.8, label="a_y^p smoothed (eq. 8)")
    axes[0].plot(tk, (res.x_true[:, 1] * pim.G + res.cfg.bias[1]) * 1e3, "k", lw=0.8, label="Φ_E g + B_N (true)")
    lim = 3.0 * float(np.max(np.abs(res.x_true[:, 1] * pim.G + res.cfg.bias[1]))) * 1e3
    axes[0].set_ylim(-lim, lim)  # the manoeuvres' accelerations (up to 1.5 m/s²) run off the scale
    axes[0].set_ylabel("[mm/s²]")
    axes[0].legend(fontsize=7)
    for i in range(3):
        ax = axes[i + 1]
        ax.plot(tk, res.x_true[:, i] * scale[i], "k", lw=1.2, label="true error")
        ax.plot(tk, res.est["classical"][:, i] * scale[i], "C0", lw=0.9, label="estimate: classical")
        ax.set_ylabel(labels[i])
    axes[1].legend(fontsize=7)
    for ax in axes:
        for k in np.flatnonzero(res.gated):
            ax.axvspan(tk[k] - res.cfg.T / 120, tk[k] + res.cfg.T / 120, color="0.88", lw=0)
    axes[-1].set_xlabel("time [min] (grey: measurement skipped, INS indicates horizontal acceleration)")
    fig.suptitle("Classical level-flight correction (eqs. 6–10)")
    fig.tight_layout()
    out.append(directory / "level_flight.png")
    fig.savefig(out[-1], dpi=100)
    plt.close(fig)

    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    m = len(res.reduced)
    for i in range(3):
        axes[i].plot(tk[:m], res.reduced[:, i] * scale[i], "C2.", ms=2, label="reduced measurement S⁻¹z*")
        axes[i].plot(tk, res.x_true[:, i] * scale[i], "k", lw=1.2, label="true")
        axes[i].plot(tk, res.est["reduced adaptive"][:, i] * scale[i], "C3", lw=0.9, label="adaptive KF")
        axes[i].set_ylabel(labels[i])
    axes[0].legend(fontsize=7)
    axes[-1].set_xlabel("time [min]")
    fig.suptitle(f"Reduced measurements (eqs. 14–21), T = {res.cfg.T:.0f} s: cond(S) = {res.cond_S:.3g}")
    fig.tight_layout()
    out.append(directory / "reduced.png")
    fig.savefig(out[-1], dpi=100)
    plt.close(fig)

    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    hq, hr = res.scale_hist["reduced adaptive"]
    for i in range(3):
        axes[0].semilogy(tk, hq[:, i], lw=1, label=f"Q scale, {labels[i].split(' ')[0]}")
        axes[1].semilogy(tk, hr[:, i], lw=1, label=f"R scale, y_{i + 1}")
    for ax, what in zip(axes, ("process (input) noise", "measurement noise"), strict=True):
        ax.axhline(1.0, color="k", lw=0.5)
        ax.set_ylabel(f"{what}\nestimated / nominal")
        ax.legend(fontsize=7)
    axes[-1].set_xlabel("time [min]")
    fig.suptitle("Adaptive KF: Sage–Husa noise estimates (bounded 1e-3…1e3)")
    fig.tight_layout()
    out.append(directory / "adaptive.png")
    fig.savefig(out[-1], dpi=100)
    plt.close(fig)
    return out
