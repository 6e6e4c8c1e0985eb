"""Non-causal diagnostic for the drive's outage protocol: how far is the state at an outage's start from one
that would have kept the outage's error below a bound?

The core runs the README protocol (drive settings, ZUPT + NHC) up to the start of outage N (1-based). From
there the outage is replayed with four corrections of the start state: a rotation about the body y axis
(pitch, mrad), the gyro-y bias (mrad/s), the accelerometer-x bias (cm/s²) and the forward velocity
(0.1 m/s). For each bound (default 6 m and 3 m) Nelder–Mead finds the smallest correction, measured as a
Mahalanobis distance in the filter's own covariance at the start, that keeps the outage's horizontal error
(RTK-fixed epochs) under the bound. The error depends mostly on one combination of the four, so read the
distance as a 1-D normal deviate (1.83 σ: a one-sided 3 % tail): a small one means the start uncertainty alone
explains the error; a large one means the error builds up inside the outage (or the start σ is too small).

    .venv/bin/python scripts/diagnostics/outage_oracle.py 2 [bound_m ...]

Uses the future (the outage's RTK truth): a diagnostic, never an estimator. ~2–4 min per bound.
"""

from __future__ import annotations

import copy
import math
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from ins_hil.core import NavCore
from ins_hil.datasets import config as dataset_config
from ins_hil.datasets import study
from ins_hil.datasets.run import antenna_ned
from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_from_quat, quat_from_rotvec, quat_mul
from ins_hil.types import FixType

DRIVE_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "datasets" / "drive0708.toml"


def main(argv: list[str]) -> int:
    if not argv or not argv[0].isdigit():
        print(__doc__)
        return 2
    n_out = int(argv[0])
    bounds = [float(x) for x in argv[1:]] or [6.0, 3.0]
    cfg_ds = dataset_config.load(DRIVE_CONFIG)
    _, dr, outs_p = study.load(cfg_ds)  # the prepared drive (imu, gnss, nav) and its protocol
    g0 = dr.gnss[0]
    origin = (g0.lat, g0.lon, g0.h)
    outs = outs_p
    if not 1 <= n_out <= len(outs):
        print(f"outage number 1..{len(outs)}", file=sys.stderr)
        return 2
    a, b = outs[n_out - 1]
    cfg = dr.nav
    core = NavCore(None, cfg)
    j = k = 0
    while dr.imu[k].t < a - 1e-9:
        s = dr.imu[k]
        k += 1
        core.step(s)
        while j < len(dr.gnss) and dr.gnss[j].t <= s.t:
            f = dr.gnss[j]
            j += 1
            if not any(x <= f.t < y for x, y in outs):
                core.fuse(f)
    seg = [s for s in dr.imu[k:] if s.t < b + 0.02]
    fixes = [f for f in dr.gnss if a <= f.t < b and f.fix_type == FixType.RTK_FIXED]
    refs = [earth.ned_from_geodetic(f.lat, f.lon, f.h, *origin) for f in fixes]
    C0 = dcm_from_quat(core.ins.state.q_nb)
    ix = core.idx
    assert ix.bg is not None and ix.ba is not None
    # p = T x: the four corrections from the error state (δ = true − estimate; Ĉ = (I + [μ×]) C, so the
    # body-y rotation that corrects μ is −(Cᵀ μ)_y), in the units above
    T = np.zeros((4, core.kf.n))
    T[0, 6:9] = -C0.T[1, :] * 1e3
    T[1, ix.bg + 1] = 1e3
    T[2, ix.ba] = 1e2
    T[3, 3:6] = C0[:, 0] * 10.0
    cov = T @ core.kf.P @ T.T
    ci = np.linalg.inv(cov)
    print(f"outage {n_out} ({a - g0.t:.0f}–{b - g0.t:.0f} s); start-state 1-σ: pitch {math.sqrt(cov[0, 0]):.2f} mrad, "
          f"gyro-y bias {math.sqrt(cov[1, 1]):.3f} mrad/s, accel-x bias {math.sqrt(cov[2, 2]):.2f} cm/s², "
          f"forward velocity {0.1 * math.sqrt(cov[3, 3]):.3f} m/s")  # fmt: skip

    def run(p: np.ndarray) -> np.ndarray:
        c = copy.deepcopy(core)
        st = c.ins.state
        C = dcm_from_quat(st.q_nb)
        st.q_nb = quat_mul(st.q_nb, quat_from_rotvec(np.array((0.0, p[0] * 1e-3, 0.0))))
        c.bg = c.bg + np.array((0.0, p[1] * 1e-3, 0.0))
        c.ba = c.ba + np.array((p[2] * 1e-2, 0.0, 0.0))
        st.vel_ned = st.vel_ned + C[:, 0] * p[3] * 0.1
        err = []
        i = 0
        for s in seg:
            c.step(s)
            while i < len(fixes) and fixes[i].t <= s.t:
                e = antenna_ned(c.ins.state, cfg.gnss.lever_arm_b, fixes[i].t, origin) - refs[i]
                err.append(math.hypot(float(e[0]), float(e[1])))
                i += 1
        return np.array(err)

    e0 = run(np.zeros(4))
    print(f"  as run: h RMS / max {math.sqrt(float(np.mean(e0**2))):.2f} / {e0.max():.2f} m")
    for bound in bounds:
        best = None
        for x0 in (np.zeros(4), np.sqrt(np.diag(cov)) * np.array((-1.0, 1.0, -1.0, 1.0))):

            def cost(p: np.ndarray, bound: float = bound) -> float:
                return float(p @ ci @ p) + 1e3 * max(0.0, float(np.max(run(p))) - bound) ** 2

            r = minimize(cost, x0, method="Nelder-Mead", options={"maxiter": 600, "xatol": 0.01, "fatol": 0.001})
            if best is None or r.fun < best.fun:
                best = r
        assert best is not None
        e = run(best.x)
        d = math.sqrt(float(best.x @ ci @ best.x))
        print(f"  max ≤ {bound:g} m: smallest correction {d:.2f} σ (pitch {best.x[0]:.2f} mrad, gyro-y "
              f"{best.x[1]:.3f} mrad/s, accel-x {best.x[2]:.2f} cm/s², forward {0.1 * best.x[3]:.3f} m/s) → "
              f"{math.sqrt(float(np.mean(e**2))):.2f} / {e.max():.2f} m", flush=True)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
