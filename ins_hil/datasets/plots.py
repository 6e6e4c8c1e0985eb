"""PNG plots of a replay's :class:`~ins_hil.datasets.evaluate.Series`: trajectory, errors with ±3σ, biases and
innovation test ratios (matplotlib, Agg)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ins_hil.datasets.evaluate import Series

DEG = math.pi / 180.0


def _save(fig: Any, path_prefix: Path, suffix: str) -> Path:
    """Write ``fig`` as ``<path_prefix><suffix>.png`` (90 dpi) and close it; the file."""
    import matplotlib.pyplot as plt

    f = path_prefix.with_name(path_prefix.name + suffix + ".png")
    fig.tight_layout()
    fig.savefig(f, dpi=90)
    plt.close(fig)
    return f


def plot_series(
    ser: Series, title: str, path_prefix: Path, outages: list[tuple[float, float]] | None = None
) -> list[Path]:
    """Three PNGs named ``path_prefix`` + ``_trajectory``, ``_errors``, ``_biases_ratios``; ``outages`` (absolute
    s) shaded. Returns the files ([] for an empty series)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = ser.arrays()
    if len(a["t"]) == 0:
        return []
    t = a["t"] - a["t"][0]
    t_off = a["t"][0]
    files = []
    # trajectory
    fig, ax = plt.subplots(figsize=(6, 5))
    ax.plot(a["ref_ned"][:, 1], a["ref_ned"][:, 0], "k-", lw=1, label="reference")
    ax.plot(a["ned"][:, 1], a["ned"][:, 0], "r-", lw=0.8, label="filter")
    ax.set_xlabel("East (m)")
    ax.set_ylabel("North (m)")
    ax.axis("equal")
    ax.legend()
    ax.set_title(f"{title}: trajectory")
    files.append(_save(fig, path_prefix, "_trajectory"))
    # errors with 3σ
    fig, axs = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for ax, key, sk, unit, scale in (
        (axs[0], "pos_err", "std_pos", "m", 1.0),
        (axs[1], "vel_err", "std_vel", "m/s", 1.0),
        (axs[2], "att_err", "std_att", "deg", 1 / DEG),
    ):
        for i, (c, lab) in enumerate(zip("rgb", "NED" if key != "att_err" else ("roll", "pitch", "yaw"))):
            ax.plot(t, a[key][:, i] * scale, c, lw=0.7, label=lab)
            ax.plot(t, 3 * a[sk][:, i] * scale, c + ":", lw=0.6)
            ax.plot(t, -3 * a[sk][:, i] * scale, c + ":", lw=0.6)
        if outages:
            for o0, o1 in outages:
                ax.axvspan(o0 - t_off, o1 - t_off, color="0.9")
        ax.set_ylabel(f"{key.split('_')[0]} error ({unit})")
        ax.legend(loc="upper right", fontsize=7, ncol=3)
    axs[-1].set_xlabel("time (s)")
    axs[0].set_title(f"{title}: errors and ±3σ (dotted)")
    files.append(_save(fig, path_prefix, "_errors"))
    # biases and test ratios
    fig, axs = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    axs[0].plot(t, a["gyro_bias"] / DEG)
    axs[0].set_ylabel("gyro bias (°/s)")
    axs[1].plot(t, a["accel_bias"])
    axs[1].set_ylabel("accel bias (m/s²)")
    kinds = sorted({k for r in ser.ratios for k in r})
    for k in kinds:
        axs[2].semilogy(t, [max(r.get(k, np.nan), 1e-4) for r in ser.ratios], lw=0.7, label=k)
    axs[2].axhline(1.0, color="k", lw=0.8)
    axs[2].set_ylabel("test ratio")
    axs[2].legend(fontsize=7, ncol=3)
    axs[-1].set_xlabel("time (s)")
    axs[0].set_title(f"{title}: estimated biases and innovation test ratios (reject > 1)")
    files.append(_save(fig, path_prefix, "_biases_ratios"))
    return files
