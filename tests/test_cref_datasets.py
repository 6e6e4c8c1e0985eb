"""Each shipped flight-log config (configs/datasets/*.toml) on the C core, held against NavCore over the whole log.

The log is prepared as ``ins-hil replay`` prepares it (``ins_hil.datasets.run.prepare``: mounting, time offsets,
screening, the magnetometer reference, the hold, the yaw bank) and fed to both cores as ``run_dataset`` feeds
them (every aid after its IMU step, in time order; the magnetometer as a heading with each core's own attitude).
The C core (double) agrees with NavCore to ≤ 1e-9 relative in attitude, velocity and position at every 0.5 s of
the log, and its gate counts are NavCore's. drive0708 (its scale-factor states: 21 states on both) is held the
same way through the Pipeline by tests/test_cref_pipeline.py.

NavCore's delayed-fusion log order is patched as in tests/test_cref_parity.py (a roll-back that reaches into an
earlier one's span: the measurements of a step before its IMU sample).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ins_hil.core import NavCore
from ins_hil.cref import CNavCore
from ins_hil.datasets import config
from ins_hil.datasets.dataset import read_dataset
from ins_hil.datasets.run import heading_only, prepare
from ins_hil.types import MagSample

REPO = Path(__file__).resolve().parent.parent
CONFIGS = REPO / "configs" / "datasets"
KINDS = ("gnss_pos", "gnss_vel", "baro", "nhc", "zupt", "mag", "hold")


def _prepared(name: str) -> Any:
    cfg = config.load(CONFIGS / f"{name}.toml")
    assert cfg.path is not None
    return prepare(read_dataset(cfg.path, cfg.format, cfg), cfg)


def replay_both(p: Any) -> tuple[np.ndarray, NavCore, CNavCore, int]:
    """NavCore and CNavCore over a prepared log; worst [|Δq|, rel v, rel lat/lon, rel h] and the samples compared."""
    py = NavCore(None, p.nav)
    c = CNavCore(None, p.nav, fixed_step=False)
    meas = sorted([(f.t, 0, f) for f in p.gnss] + [(m.t, 2, m) for m in p.aux], key=lambda x: (x[0], x[1]))
    worst = np.zeros(4)
    j = 0
    n = 0
    t_next = -math.inf
    for s in p.imu:
        py.step(s)
        c.step(s)
        while j < len(meas) and meas[j][0] <= s.t:
            m = meas[j][2]
            j += 1
            if isinstance(m, MagSample) and p.mag_heading_only:
                mp = heading_only(m, py.ins.state.q_nb, p.nav.mag.ref_ned) if py.phase == "nav" else m
                mc = heading_only(m, c.state().q_nb, p.nav.mag.ref_ned) if c.phase == "nav" else m
                py.fuse(mp)
                c.fuse(mc)
            else:
                py.fuse(m)
                c.fuse(m)
        assert py.phase == c.phase
        if py.phase == "nav" and s.t >= t_next:
            t_next = s.t + 0.5
            a, b = py.state(), c.state()
            n += 1
            worst = np.maximum(worst, [
                float(np.max(np.abs(a.q_nb - b.q_nb))),
                float(np.max(np.abs(a.vel_ned - b.vel_ned)) / max(1.0, float(np.max(np.abs(a.vel_ned))))),
                max(abs(a.lat - b.lat) / max(abs(a.lat), 1e-3), abs(a.lon - b.lon) / max(abs(a.lon), 1e-3)),
                abs(a.h - b.h) / max(1.0, abs(a.h)),
            ])  # fmt: skip
    return worst, py, c, n


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ardupilot_copter", "px4_hover", "px4_quad"])
def test_flight_log_config_on_c_matches_python(name: str) -> None:
    p = _prepared(name)
    worst, py, c, n = replay_both(p)
    assert n > 100  # navigated over the log
    e = c._core.ekf
    for i, k in enumerate(KINDS):
        if k in py.stats:
            assert (py.stats[k].accepted, py.stats[k].rejected) == (int(e.accepted[i]), int(e.rejected[i])), k
    assert sum(int(e.accepted[i]) for i in range(len(KINDS))) > 100
    assert np.all(worst <= 1e-9), worst


def test_a_config_with_a_python_only_state_is_refused_by_name() -> None:
    cfg = config.load(CONFIGS / "drive0708.toml")
    nav = cfg.nav_config()
    nav = dataclasses.replace(nav, filter=dataclasses.replace(nav.filter, mag_bias=True))
    with pytest.raises(ValueError, match=r"not supported by the C core: filter\.mag_bias$"):
        CNavCore(None, nav)
