"""`ins-hil replay`: scenario and real-drive runs, metrics/plots, gateway-log dispatch, bad input."""

from __future__ import annotations

import json
import math
import types
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ins_hil.cli import main
from ins_hil.commands import replay as rp
from ins_hil.datasets import config as dataset_config
from ins_hil.datasets import simulated, study
from ins_hil.datasets.evaluate import run_drive
from ins_hil.sim import scenarios
from ins_hil.types import BaroSample


@pytest.mark.slow
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


@pytest.mark.slow
def test_replay_monte_carlo_nees(tmp_path: Path):
    """The 9-dof NEES of the simulated UAV with only the modelled errors, averaged over 4 seeds from 60 s on,
    lies inside its two-sided 95 % χ² band, and every sensor's NIS/dof is near 1 (a filter that is over- or
    under-confident by a factor of ~1.3 in variance fails)."""
    mc = simulated.monte_carlo(lambda seed: scenarios.build("uav_modelled", seed=seed, duration=140.0),
                               "uav_modelled", runs=4)  # fmt: skip
    lo, hi = mc["anees_bounds_95"]
    assert lo <= mc["anees_mean"] <= hi, mc
    assert mc["fraction_inside"] >= 0.3, mc  # ANEES(t) is time-correlated: a loose bound on the share inside
    nis = mc["nis_mean_over_dof"]
    assert set(nis) >= {"gnss_pos", "gnss_vel", "mag", "baro"}
    assert all(0.85 <= v <= 1.15 for v in nis.values()), nis


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


REPO = Path(__file__).resolve().parent.parent


@dataclass
class _Drive:
    nav: Any
    outages: list[tuple[float, float]]
    t0: float


def _drive_head(shared_dir: Path, seconds: float) -> tuple[_Drive, list, list, list[bool]]:
    """The real drive (through configs/datasets/drive0708.toml)'s first ``seconds`` s after its first GNSS epoch:
    (drive: nav config, protocol outages, first fix time; IMU samples, fixes, RTK-fixed)."""
    cfg = dataset_config.load(REPO / "configs" / "datasets" / "drive0708.toml")
    _, p, outages = study.load(cfg, shared_dir / "data" / "gnss_imu_drive_0708")
    t0 = p.gnss[0].t
    gnss = [f for f in p.gnss if f.t < t0 + seconds]
    dr = _Drive(nav=p.nav, outages=outages, t0=t0)
    return dr, [s for s in p.imu if s.t < t0 + seconds], gnss, [f.fix_type == 6 for f in gnss]


@pytest.mark.slow
def test_drive_replay_first_outage(shared_dir: Path):
    """The first 100 s of the real drive with the protocol's first outage (40–55 s): causal replay."""
    dr, imu, gnss, rtk = _drive_head(shared_dir, 100.0)
    outs = dr.outages[:1]
    m, ser, core = run_drive(imu, gnss, rtk, dr.nav, outs)
    assert core.state().aligned
    assert 50 <= m["outage_epochs"] <= 60  # 15 s at 4 Hz, RTK-fixed epochs only
    assert m["outage_h_max_m"] < 10.0
    assert m["gnss_h_rms_post_m"] < 0.5
    assert m["nhc_updates"] > 0
    a = ser.arrays()
    assert np.all(np.isfinite(a["pos_err"]))


@pytest.mark.slow
def test_drive_replay_fuses_aux_baro_inside_outages(shared_dir: Path):
    """``run_drive(aux=...)``: baro samples are fused at their time, inside outages too. Late in the 85–100 s
    outage, a baro made from the RTK height holds the height error near zero, and one that reads 1.5 m high from
    the outage's start (3 σ: inside the gate) pulls the height up by about 1.5 m (NED down −1.5 m)."""
    dr, imu, gnss, rtk = _drive_head(shared_dir, 101.0)
    outs = dr.outages[:2]
    a, b = outs[1]  # the datum is learnt against GNSS in 55–85 s

    def late_down(step: float | None) -> tuple[float, int]:
        aux = [] if step is None else [
            BaroSample(f.t, math.nan, altitude=f.h - 1601.0 + (step if f.t >= a else 0.0)) for f in gnss
        ]  # fmt: skip
        _, ser, core = run_drive(imu, gnss, rtk, dr.nav, outs, aux=aux)
        t, e = np.array(ser.t), np.array(ser.pos_err)
        late = (t >= a + 10.0) & (t < b)
        assert late.sum() > 10
        return float(np.mean(e[late, 2])), core.stats["baro"].accepted

    no_baro, n0 = late_down(None)
    true_baro, n1 = late_down(0.0)
    high_baro, _ = late_down(1.5)
    assert n0 == 0
    assert n1 > 200  # both outages and the GNSS-present epochs after alignment
    assert abs(no_baro) > 0.5  # the height drifts without a reference ...
    assert abs(true_baro) < 0.3  # ... and the baro holds it
    assert abs(high_baro - true_baro + 1.5) < 0.5  # the step (the vertical velocity it implies overshoots a little)


@pytest.mark.slow
def test_baro_datum_is_learnt_during_the_alignment(shared_dir: Path):
    """The drive's first outage starts 0.25 s after the core enters navigation. The baro datum is learnt against
    GNSS during the 37 s rest, so a baro made from the RTK height is weighted fully inside that outage (with the
    datum taken at the first navigation sample instead, its σ would be the start's height σ and the baro weak)."""
    dr, imu, gnss, rtk = _drive_head(shared_dir, 56.0)
    t0 = dr.t0
    outs = dr.outages[:1]
    a, b = outs[0]
    h_err = {}
    for with_baro in (False, True):
        aux = [BaroSample(f.t, math.nan, altitude=f.h - 1601.0) for f in gnss] if with_baro else []
        m, ser, core = run_drive(imu, gnss, rtk, dr.nav, outs, aux=aux)
        assert a - 0.5 < m["t_aligned_s"] + t0 < a
        t, e = np.array(ser.t), np.array(ser.pos_err)
        late = (t >= a + 10.0) & (t < b)
        h_err[with_baro] = float(np.sqrt(np.mean(e[late, 2] ** 2)))
    assert core.baro.offset_var < 0.01  # learnt against the RTK height (σ floor 0.06 m), not the start σ
    # vertical RMS late in the outage: 0.27 m without a baro, 0.26 m with the datum from the first navigation
    # sample (the rule before the alignment learnt it), 0.22 m now (0.20 m before the learnt datum's error was
    # weighted as correlated over its time constant)
    assert h_err[True] < 0.85 * h_err[False]


def test_accuracy_markdown_renders_the_saved_metrics():
    """The library's renderer (``ins_hil.datasets.accuracy_md``) gives docs/accuracy.md's tables from its metrics."""
    from ins_hil.datasets.accuracy_md import render_markdown

    r = json.loads((REPO / "docs" / "accuracy" / "metrics.json").read_text())
    r["drive"].setdefault("config", "configs/datasets/drive0708.toml")
    study = dataset_config.load(REPO / "configs" / "datasets" / "drive0708.toml").study
    r["drive"].update(targets=study["targets"], upstream=study["upstream"])  # as ins_hil.datasets.study adds them
    md = render_markdown(r, {}, REPO / "docs").splitlines()
    doc = (REPO / "docs" / "accuracy.md").read_text().splitlines()
    rows = [x for x in md if x.startswith("| ")]
    assert len(rows) > 15 and all(x in doc for x in rows), [x for x in rows if x not in doc]
    assert any(x.startswith("| target | ≤ 1.5 | ≤ 6 |") for x in rows)
    assert any(x.startswith("| upstream filter, causal | 3.09 | 12.8 | 0.41 |") for x in rows)
    assert any("configs/datasets/drive0708.toml" in x for x in md)
    # the simulated car with its odometer beats the same car without it in the 30-s outages (issue 41)
    od = r["odometer"]
    assert od["runs"] == 10 and od["with"]["rms_mean_m"] < 0.6 * od["without"]["rms_mean_m"]
    assert f"| RMS over the outage, mean | {od['with']['rms_mean_m']:.2f} | {od['without']['rms_mean_m']:.2f} |" in doc


def test_flight_log_targets_are_judged_from_the_metrics():
    """docs/accuracy.md's flight-log table: each target quantity read from a replay's metrics, met or not; a log
    that failed to replay says so instead of a figure."""
    from ins_hil.datasets.accuracy_md import flight_logs_md

    att = {"roll": {"rms": 0.5}, "pitch": {"rms": 1.6}, "yaw": {"rms": 0.8}}
    quad = {"gnss": {"gnss_h_rms_prior_m": 0.148},
            "outages": {"outage_h_rms_m": 2.23, "outage_h_max_m": 8.73, "nees_2dof_mean": 0.05, "outages_scored": 4,
                        "beats_both_in_every_outage": False,
                        "windows": [{"scored": True, "beats_both": b} for b in (True, False, True, True)]},
            "rejection": {"gnss_pos": {"rate": 0.002}},
            "rotor_drag": {"ours": {"x": {"mu_per_s": 0.1876}}}}  # fmt: skip
    quad["outages"]["windows"][1].update(h_rms_m=3.73, hold_h_rms_m=1.6, cv_h_rms_m=4.02, before={
        "imu_lost_s": 2.52, "since_imu_lost_s": 4.97, "peak_rate_dps": 199.7, "since_peak_rate_s": 3.07})  # fmt: skip
    quad["outages"]["windows"][3].update(before={"imu_lost_s": 0.0, "since_imu_lost_s": None,  # as read back
                                                 "peak_rate_dps": None, "since_peak_rate_s": None})  # fmt: skip
    md = flight_logs_md({"ardupilot_copter": {"onboard": {"attitude_deg": att}}, "px4_quad": quad,
                         "px4_hover": {"error": "hover.ulg: no such file"}})  # fmt: skip
    rows = md.splitlines()
    why = "outage 2, opened 5.0 s after 2.52 s of lost IMU data, 3.1 s after a 200 °/s turn"
    assert f"| px4_quad | {why}: ours / hold / cv h RMS (m) | 3.73 / 1.60 / 4.02 | below both | falls short |" in rows
    assert sum("outage 4" in x for x in rows) == 0  # below both: not listed
    assert "| ardupilot_copter | roll vs NKF1, RMS (°) | 0.50 | ≤ 1° | met |" in rows
    assert "| ardupilot_copter | pitch vs NKF1, RMS (°) | 1.60 | ≤ 1.5° | falls short |" in rows
    assert "| px4_quad | GNSS-present h error prior, RMS (m) | 0.148 | ≤ 0.35 m | met |" in rows
    assert "| px4_quad | 10-s outages h error, worst (m) | 8.73 | ≤ 6 m | falls short |" in rows
    beats = "| px4_quad | outages below hold-last-fix and constant velocity | 3 of 4 | every outage | falls short |"
    assert beats in rows
    assert "| px4_quad | gate rejections, worst kind | 0.2% | reported | reported |" in rows
    mu = "| px4_quad | body-x specific force against our velocity: rotor drag μ (1/s) | 0.188 |"
    assert mu + " ≥ 0.1 for a real velocity | reported |" in rows
    assert "| px4_hover | yaw vs EKF2, RMS (°) | failed: hover.ulg: no such file | ≤ 5° | — |" in rows
