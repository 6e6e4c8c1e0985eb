"""Each shipped dataset config replayed through the gateway's Pipeline (``ins_hil.datasets.run.replay``, as
``ins-hil replay`` runs it: validation, drift monitor, delayed fusion, the state published after the
mechanization and scored) on the Python core and on the C core (double): the published states agree to ≤ 1e-9
relative per state at every IMU epoch.

The fast test covers the first seconds of each log: its alignment (``ALIGN_S``, as measured: 3.5 s on the
ArduCopter and px4_hover logs, 18.8 s on px4_quad, 36.5 s on the drive) then ``NAV_S`` = 15 s of navigation with
its hold / ZUPT / NHC / magnetometer / GNSS / baro updates and roll-backs; the slow one the whole log.
Relative: |Δq| on the unit quaternion; velocity / max(1, |v|); latitude and longitude / |value|; height /
max(1, |h|); biases / max(1e-3, |b|) (rad/s, m/s²).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ins_hil.cref import CNavCore
from ins_hil.datasets import config
from ins_hil.datasets.dataset import read_dataset
from ins_hil.datasets.run import heading_only, navigating, offline_config, prepare, replay
from ins_hil.runtime.pipeline import Observer
from ins_hil.types import GnssFix, MagSample, NavState

REPO = Path(__file__).resolve().parent.parent
CONFIGS = sorted((REPO / "configs" / "datasets").glob("*.toml"))
#: the shipped configs the C core refuses, with the setting it names (tests/test_replay_core_c.py)
REFUSED: dict[str, str] = {}
#: the alignment of each log (s from its first IMU sample; measured, rounded up) and the navigation after it the
#: fast test replays (s)
ALIGN_S = {"ardupilot_copter": 4.0, "px4_hover": 4.0, "px4_quad": 19.0, "drive0708": 37.0}
NAV_S = 15.0
TOL = 1e-9


class _Published(Observer):
    """The published state at every navigating epoch: t, q, v, lat, lon, h, b_g, b_a."""

    def __init__(self) -> None:
        self.rows: list[list[float]] = []

    def epoch(self, pipe: Any, st: NavState) -> None:
        if navigating(pipe):
            self.rows.append([st.t, *st.q_nb, *st.vel_ned, st.lat, st.lon, st.h, *st.gyro_bias, *st.accel_bias])


def _run(p: Any, imu: list[Any], core: str) -> tuple[np.ndarray, dict[str, int]]:
    aids = sorted([*p.gnss, *p.aux], key=lambda m: (m.t, 0 if isinstance(m, GnssFix) else 2))
    t_end = imu[-1].t
    aids = [m for m in aids if m.t <= t_end]
    ref = p.nav.mag.ref_ned

    def heading(pipe: Any, m: Any) -> Any:
        st = pipe.last_state
        if isinstance(m, MagSample) and st is not None and navigating(pipe):
            return heading_only(m, st.q_nb, ref)
        return m

    obs = _Published()
    pipe, _ = replay(imu, aids, p.nav, [obs], on_aid=heading if p.mag_heading_only else None,
                     pipeline=offline_config(p.aiding_fdi, core))  # fmt: skip
    return np.array(obs.rows), dict(pipe.counts)


def worst_relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Worst relative difference over the epochs: [q, v, lat/lon, h, b_g, b_a]."""
    assert a.shape == b.shape and len(a) > 0
    np.testing.assert_array_equal(a[:, 0], b[:, 0])
    d = np.abs(a - b)
    q = d[:, 1:5].max()
    v = (d[:, 5:8] / np.maximum(1.0, np.abs(a[:, 5:8]))).max()
    ll = (d[:, 8:10] / np.maximum(1e-3, np.abs(a[:, 8:10]))).max()
    h = (d[:, 10] / np.maximum(1.0, np.abs(a[:, 10]))).max()
    bg = (d[:, 11:14] / np.maximum(1e-3, np.abs(a[:, 11:14]))).max()
    ba = (d[:, 14:17] / np.maximum(1e-3, np.abs(a[:, 14:17]))).max()
    return np.array([q, v, ll, h, bg, ba])


def _check(name: str, seconds: float) -> float:
    cfg = config.load(REPO / "configs" / "datasets" / f"{name}.toml")
    assert cfg.path is not None
    if name in REFUSED:
        with pytest.raises(ValueError, match=f"not supported by the C core: {REFUSED[name]}$"):
            CNavCore(None, cfg.nav_config())
        return math.inf
    p = prepare(read_dataset(cfg.path, cfg.format, cfg), cfg)
    t0 = p.imu[0].t
    imu = [s for s in p.imu if s.t <= t0 + seconds]
    a, ca = _run(p, imu, "python")
    b, cb = _run(p, imu, "c")
    assert ca == cb  # fused / excluded / rejected counts
    assert sum(v for k, v in ca.items() if k.startswith("fused_")) > 10
    w = worst_relative(a, b)
    assert np.all(w <= TOL), dict(zip(("q", "v", "latlon", "h", "bg", "ba"), w.tolist()))
    return float(a[-1, 0] - a[0, 0])


@pytest.mark.parametrize("name", [c.stem for c in CONFIGS])
def test_pipeline_prefix_on_c_matches_python(name: str) -> None:
    assert _check(name, ALIGN_S.get(name, 60.0) + NAV_S) > NAV_S - 1.0  # navigated and compared (s)


@pytest.mark.slow
@pytest.mark.parametrize("name", [c.stem for c in CONFIGS])
def test_pipeline_whole_log_on_c_matches_python(name: str) -> None:
    assert _check(name, math.inf) > 80.0
