"""Figures of the reproduction report (matplotlib, Agg backend, PNG)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

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
