"""A GNSS the drift monitor excluded because the INS disagreed with it, while the GNSS stayed consistent with itself
and the INS drifted away, is re-admitted (``AidingConfig.diverged_speed``): the core then sees its rejections and
resets. The ArduCopter flight with ``grade = "tactical"`` (a preset far below its vibrating MEMS IMU): the
INS-innovation CUSUM excluded the GNSS for good 25 s into navigation and the replay ended 3.9 km off with no
divergence reported; now each divergence is detected and reset."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ins_hil.datasets import config as dcfg
from ins_hil.datasets.dataset import read_dataset
from ins_hil.datasets.run import prepare, run_dataset


def test_a_diverged_ins_does_not_keep_a_good_gnss_out(shared_dir: Path) -> None:
    cfg_path = Path(__file__).resolve().parents[1] / "configs/datasets/ardupilot_copter.toml"
    c = dcfg.load(cfg_path, overrides={"sensor": {"grade": "tactical"}})
    ds = read_dataset(shared_dir / "data/uav/ardupilot_copter_150s/flight.bin", cfg=c)
    r = run_dataset(prepare(ds, c))
    assert r.divergences, "the divergence was not detected"
    assert any("re-admitted: the INS is" in e.detail for e in r.events)
    h = np.hypot(r.gnss_err[:, 0], r.gnss_err[:, 1])
    assert float(np.max(h)) < 100.0, float(np.max(h))  # was 3,851 m
    assert r.counts.get("excluded_GnssFix", 0) < 0.4 * r.counts["fused_GnssFix"], r.counts
