"""`ins-hil replay`: scenario and real-drive runs, metrics/plots, gateway-log dispatch, bad input."""

from __future__ import annotations

import json
import math
import types
from pathlib import Path

import numpy as np

from ins_hil.cli import main
from ins_hil.commands import replay as rp
from ins_hil.datasets import drive0708 as dd
from ins_hil.datasets.evaluate import run_drive


def test_replay_scenario_writes_metrics_and_plots(tmp_path: Path, capsys):
    rc = main(["replay", "uav", "--duration", "20", "--out", str(tmp_path), "--quiet"])
    assert rc == 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    s = m["scenario"]
    assert s["scenario"] == "uav" and s["aligned"]
    assert len(s["pos_rms_m"]) == 3 and max(s["pos_rms_m"]) < 3.0
    assert s["counters"]["gnss_pos"]["accepted"] > 90
    for p in m["plots"]:
        assert Path(p).stat().st_size > 5000
    out = capsys.readouterr().out
    assert "att_rms_deg" in out and "realtime factor" in out


def test_replay_monte_carlo_nees(tmp_path: Path):
    mc = rp.monte_carlo("example32_gnss", runs=2, duration=120.0, quiet=True)
    lo, hi = mc["anees_bounds_95"]
    assert lo < 9.0 < hi
    assert 0.0 <= mc["fraction_inside"] <= 1.0 and math.isfinite(mc["anees_mean"])
    assert set(mc["nis_mean_over_dof"]) >= {"gnss_pos", "gnss_vel", "mag", "baro"}


def test_replay_bad_source_and_gateway_log_dispatch(tmp_path: Path, monkeypatch, capsys):
    assert main(["replay", "no_such_thing", "--out", str(tmp_path), "--quiet"]) == 2
    assert "unknown source 'no_such_thing'" in capsys.readouterr().err
    log = tmp_path / "flight.ihlog"
    log.write_bytes(b"")
    calls = []
    stub = types.SimpleNamespace(replay_log=lambda path, args: calls.append(path) or 0)
    monkeypatch.setattr(rp, "_runtime_replay", lambda: stub)
    assert main(["replay", str(log), "--out", str(tmp_path)]) == 0
    assert calls == [log]

    def missing():
        raise ImportError("ins_hil.runtime.replay")

    monkeypatch.setattr(rp, "_runtime_replay", missing)
    assert main(["replay", str(log), "--out", str(tmp_path)]) == 2
    assert "ins_hil.runtime.replay" in capsys.readouterr().err


def test_drive_replay_first_outage(shared_dir: Path):
    """The first 100 s of the real drive with the protocol's first outage (40–55 s): causal replay."""
    dr = dd.load_drive(shared_dir / "data" / "gnss_imu_drive_0708")
    t0 = dr.pos.t[0]
    imu = [s for s in dr.imu if s.t < t0 + 100.0]
    gnss = [f for f in dr.gnss if f.t < t0 + 100.0]
    outs = dd.outage_windows(dr.pos.t)[:1]
    m, ser, core = run_drive(imu, gnss, [f.fix_type == 6 for f in gnss], rp.drive_config(True), outs)
    assert core.state().aligned
    assert 50 <= m["outage_epochs"] <= 60  # 15 s at 4 Hz, RTK-fixed epochs only
    assert m["outage_h_max_m"] < 10.0
    assert m["gnss_h_rms_post_m"] < 0.5
    assert m["nhc_updates"] > 0
    a = ser.arrays()
    assert np.all(np.isfinite(a["pos_err"]))
