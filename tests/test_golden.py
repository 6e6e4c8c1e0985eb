"""Change indication: the golden replays (tests/golden_replay.py) and the drive's headline figures.

A change that moves a navigation number by more than its column's tolerance (tests/golden/tolerances.toml:
1000-10000 times the last-bit spread between hosts) fails here; if the change is meant to move them,
`scripts/golden` rewrites tests/golden/*.csv.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import golden_replay as gr
import numpy as np
import pytest

from ins_hil.datasets import config as dataset_config
from ins_hil.datasets import study
from ins_hil.datasets.evaluate import run_drive

REPO = Path(__file__).resolve().parent.parent


def _rows(name: str, **kw) -> np.ndarray:
    return np.array(gr.RUNS[name](**kw), dtype=float).reshape(-1, len(gr.COLUMNS))


@pytest.mark.parametrize("name", list(gr.RUNS))
def test_golden_replay_matches(name: str, shared_dir: Path):
    bad = gr.compare(gr.load(name), _rows(name), gr.tolerances())
    assert not bad, (
        f"{name}: the navigation numbers changed beyond tests/golden/tolerances.toml "
        "(scripts/golden rewrites the file if intended):\n" + "\n".join(bad)
    )


def test_golden_replay_is_bit_identical_within_one_process():
    """The one bit-exact guarantee: the same replay twice in one process gives the same bits."""
    assert gr.digest(gr.RUNS["sim_uav_c_60s"]()) == gr.digest(gr.RUNS["sim_uav_c_60s"]())


def _gyro_arw_moved(cfg):
    return dataclasses.replace(cfg, filter=dataclasses.replace(cfg.filter, gyro_arw=cfg.filter.gyro_arw * (1 + 1e-6)))


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n.startswith("drive") else n for n in gr.RUNS]
)
def test_golden_sees_a_filter_constant_moved_by_1e_6(name: str, shared_dir: Path):
    """The tolerances are tight enough for a real change: the gyro's noise density 1e-6 larger (relative) fails."""
    bad = gr.compare(gr.load(name), _rows(name, tweak=_gyro_arw_moved), gr.tolerances())
    assert len(bad) >= 5, bad


def test_golden_tolerance_passes_last_bits_and_fails_a_moved_value():
    want = gr.load("sim_uav_c_60s")
    tol = gr.tolerances()
    ulps = want.copy()
    for _ in range(8):  # every value 8 ulps away: what another libm or BLAS kernel does
        ulps = np.nextafter(ulps, np.inf)
    assert not gr.compare(want, ulps, tol)
    moved = want.copy()
    moved[30, gr.COLUMNS.index("vd_mps")] *= 1 + 1e-6
    assert [m.split(":")[0] for m in gr.compare(want, moved, tol)] == ["vd_mps"]
    assert gr.compare(want, want[:-1], tol) == [f"{len(want) - 1} rows instead of {len(want)}"]
    nan = want.copy()
    nan[3, gr.COLUMNS.index("n_m")] = math.nan
    assert [m.split(":")[0] for m in gr.compare(want, nan, tol)] == ["n_m"]


def test_golden_heading_is_compared_modulo_360():
    want = gr.load("sim_uav_c_60s")[:2].copy()
    got = want.copy()
    j = gr.COLUMNS.index("yaw_deg")
    want[:, j], got[:, j] = 180.0, math.nextafter(-180.0, 0.0)
    assert not gr.compare(want, got, gr.tolerances())
    got[:, j] = -179.0
    assert gr.compare(want, got, gr.tolerances())


def test_golden_file_round_trips_every_bit():
    rows = [[v * math.pi for v in range(len(gr.COLUMNS))], [math.nextafter(1.0, 2.0)] * len(gr.COLUMNS)]
    assert gr.parse(gr.render("x", rows)).tolist() == rows
    with pytest.raises(ValueError, match="header"):
        gr.parse("a,b\n1,2\n")


def test_golden_tolerances_cover_every_column_above_the_measured_spread():
    """Every column has a tolerance with its reason, at least 1000 times the spread measured between hosts."""
    tol = gr.tolerances()
    assert set(tol) == set(gr.COLUMNS)
    for c, t in tol.items():
        assert t.reason and t.abs > 0
        assert t.abs >= 1000 * t.spread, c


@pytest.mark.slow
def test_drive_protocol_headline_figures(shared_dir: Path):
    """The drive's outage protocol (ZUPT + NHC) against the figures in docs/accuracy/metrics.json (±2 %)."""
    doc = json.loads((REPO / "docs" / "accuracy" / "metrics.json").read_text())["drive"]["outages_aids"]
    cfg = dataset_config.load(REPO / "configs" / "datasets" / "drive0708.toml")
    _, p, outages = study.load(cfg, shared_dir / "data" / "gnss_imu_drive_0708")
    m, _, _ = run_drive(p.imu, p.gnss, [f.fix_type == 6 for f in p.gnss], p.nav, outages, aiding_fdi=cfg.aiding_fdi)
    assert m["outage_h_rms_m"] == pytest.approx(doc["outage_h_rms_m"], rel=0.02)
    assert m["outage_h_max_m"] == pytest.approx(doc["outage_h_max_m"], rel=0.02)
    assert m["outage_h_rms_m"] <= 1.5  # the protocol's RMS target
