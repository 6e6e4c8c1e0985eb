"""Change indication: the golden replays (tests/golden_replay.py) and the drive's headline figures.

A change that moves any navigation number by one bit fails here; if the change is meant to move them,
`scripts/golden` rewrites tests/golden/*.csv and the six-digit rows show in the diff how far it moved.
"""

from __future__ import annotations

import difflib
import json
import math
from pathlib import Path

import golden_replay as gr
import pytest

from ins_hil.datasets import config as dataset_config
from ins_hil.datasets import study
from ins_hil.datasets.evaluate import run_drive

REPO = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("name", list(gr.RUNS))
def test_golden_replay_is_unchanged(name: str, shared_dir: Path):
    want = (gr.GOLDEN / f"{name}.csv").read_text()
    got = gr.render(name, gr.RUNS[name]())
    if gr.differs(want, got):
        diff = "".join(list(difflib.unified_diff(want.splitlines(True), got.splitlines(True), "golden", "now"))[:40])
        pytest.fail(f"{name}: the navigation numbers changed (scripts/golden rewrites the file if intended)\n{diff}")


def test_golden_digest_sees_one_bit():
    """The full-precision digest changes when one value moves by one ulp (the six-digit rows would not show it)."""
    rows = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]
    moved = [[1.0, 2.0, 3.0], [4.0, math.nextafter(5.0, 6.0), 6.0]]
    assert moved[1][1] != 5.0
    assert gr.render("x", rows).splitlines()[2:] == gr.render("x", moved).splitlines()[2:]
    assert gr.digest(rows) != gr.digest(moved)
    assert gr.differs(gr.render("x", rows), gr.render("x", moved))


def test_golden_digest_is_compared_within_one_library_release():
    """Another numpy/scipy release may move the last bit: then only the six-digit rows are compared."""
    rows = [[1.0, 2.0, 3.0]]
    moved = [[1.0, math.nextafter(2.0, 3.0), 3.0]]
    other = gr.render("x", moved).replace(gr.libraries(), "numpy 0.0, scipy 0.0")
    assert not gr.differs(other, gr.render("x", rows))
    assert gr.differs(other.replace("2,", "2.5,"), gr.render("x", rows))


@pytest.mark.slow
def test_drive_protocol_headline_figures(shared_dir: Path):
    """The drive's outage protocol (ZUPT + NHC) against the figures in docs/accuracy/metrics.json (±2 %)."""
    doc = json.loads((REPO / "docs" / "accuracy" / "metrics.json").read_text())["drive"]["outages_aids"]
    cfg = dataset_config.load(REPO / "configs" / "datasets" / "drive0708.toml")
    _, p, outages = study.load(cfg, shared_dir / "data" / "gnss_imu_drive_0708")
    m, _, _ = run_drive(p.imu, p.gnss, [f.fix_type == 6 for f in p.gnss], p.nav, outages)
    assert m["outage_h_rms_m"] == pytest.approx(doc["outage_h_rms_m"], rel=0.02)
    assert m["outage_h_max_m"] == pytest.approx(doc["outage_h_max_m"], rel=0.02)
    assert m["outage_h_rms_m"] <= 1.5  # the protocol's RMS target
