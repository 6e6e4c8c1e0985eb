"""Dataset config (TOML) and `ins-hil replay FILE|DIR [--dataset CONFIG]`: validation, mounting, the
causal replay with GNSS, outages, trivial predictors and the onboard comparison, on a CSV the test writes
and on the shipped PX4 hover."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ins_hil.cli import main
from ins_hil.datasets import config as dcfg
from ins_hil.datasets import generic_csv
from ins_hil.datasets.dataset import Dataset
from ins_hil.datasets.run import prepare
from ins_hil.nav import earth
from ins_hil.nav.rotation import dcm_from_euler
from ins_hil.types import ImuSample

REPO = Path(__file__).resolve().parents[1]
LAT, LON, H = 45.0, 7.0, 300.0
M_NED_UT = (20.0, 1.0, 40.0)


def _static_csv(path: Path, yaw_deg: float = 30.0, seconds: float = 60.0, lost: tuple[int, int] = (0, 0)) -> None:
    """A vehicle at rest, level, heading ``yaw_deg``: IMU 100 Hz, GNSS 5 Hz, magnetometer 10 Hz, and an
    'onboard' estimate that is the truth. The IMU samples numbered in [lost[0], lost[1]) are left out."""
    C = dcm_from_euler(0.0, 0.0, math.radians(yaw_deg))  # body → NED
    g = earth.normal_gravity(math.radians(LAT), H)
    f_b = C.T @ np.array((0.0, 0.0, -g))
    lat = math.radians(LAT)
    w_b = C.T @ np.array((earth.OMEGA_E * math.cos(lat), 0.0, -earth.OMEGA_E * math.sin(lat)))
    m_b = C.T @ np.array(M_NED_UT)
    rows = [generic_csv.MAGIC, "# a static test vehicle"]
    n = int(seconds * 100)
    for k in range(1, n + 1):
        if lost[0] <= k < lost[1]:
            continue
        rows.append(f"imu,{k / 100:.2f},0.01," + ",".join(f"{x:.9g}" for x in (*w_b, *f_b)))
    for k in range(int(seconds * 5)):
        rows.append(f"gnss,{k / 5:.2f},{LAT},{LON},{H},0,0,0,0.5,1.0,0.1,3")
    for k in range(int(seconds * 10)):
        rows.append(f"mag,{k / 10:.2f}," + ",".join(f"{x:.5f}" for x in m_b))
        rows.append(f"onboard,{k / 10:.2f},{LAT},{LON},{H},0,0,0,0,0,{yaw_deg}")
    path.write_text("\n".join(rows) + "\n")


def _toml(path: Path, body: str) -> Path:
    path.write_text(body)
    return path


GOOD = f"""
[dataset]
name = "static_test"
[sensor]
grade = "mems"
[aiding]
mag_reference = [{M_NED_UT[0]}, {M_NED_UT[1]}, {M_NED_UT[2]}]
[outages]
relative_to = "start"
start_s = 20.0
on_s = 10.0
off_s = 10.0
[score]
against = ["gnss", "onboard", "reference"]
"""


def test_config_loads_shipped_and_validates(tmp_path: Path):
    for p in sorted((REPO / "configs" / "datasets").glob("*.toml")):
        c = dcfg.load(p)
        assert c.path is not None and c.path.exists(), p
        assert c.nav_config().alignment.mode == "static"
    bad = {
        "[dataset]\nname='x'\n[mounting]\nimu_to_body=[0,0,0]\n": "unknown key mounting.imu_to_body",
        "[dataset]\nformat='px4-ulog'\n": "missing key dataset.name",
        "[dataset]\nname='x'\n[sensor]\ngrade='navigation'\n": "sensor.grade = 'navigation': expected one of",
        "[dataset]\nname='x'\n[nav]\nwarp=1\n": "unknown key nav.warp",
        "[dataset]\nname='x'\n[nav.filter]\ngyro_noise=1\n": "unknown key 'nav.filter.gyro_noise' (did you mean",
        "[dataset]\nname='x'\n[mounting]\ngnss_lever_arm_m=[0,1]\n": "gnss_lever_arm_m = [0, 1]: expected 3",
        "[dataset]\nname='x'\n[outages]\nrelative_to='landing'\n": "outages.relative_to = 'landing'",
        "[dataset]\nname='x'\n[gnss]\nuse=true\n": "unknown table [gnss]",
        "[dataset]\nname='x'\nformat='rosbag'\n": "dataset.format = 'rosbag': expected one of",
        "[dataset]\nname='x'\n[mounting]\nimu_time_offset_s='fast'\n": "imu_time_offset_s = 'fast': wrong type",
    }
    for text, msg in bad.items():
        with pytest.raises(dcfg.DatasetConfigError, match=msg.replace("[", r"\[").replace("(", r"\(")) as e:
            dcfg.load(_toml(tmp_path / "bad.toml", text))
        assert "\n" not in str(e.value) and str(tmp_path / "bad.toml") in str(e.value)


def test_dataset_nav_sections_and_a_flat_key(tmp_path: Path):
    """[nav] takes the NavConfig sections; a key of the flat layout is one line naming its new place."""
    head = "[dataset]\nname='x'\n"
    p = _toml(tmp_path / "old.toml", head + "[nav]\ngate_gnss = 10.0\nnhc = true\n")
    with pytest.raises(dcfg.DatasetConfigError) as e:
        dcfg.load(p)
    assert str(e.value) == f"{p}: [nav] gate_gnss moved to [nav.gnss] gate"
    c = dcfg.load(_toml(tmp_path / "new.toml", head + "[nav.gnss]\ngate = 10.0\n[nav.aids]\nnhc = true\n"
                        "[nav.mag]\nstd = 0.2\n[mounting]\ngnss_lever_arm_m = [0, 0.5, 0]\n"))  # fmt: skip
    n = c.nav_config()
    assert n.gnss.gate == 10.0 and n.aids.nhc and n.mag.std == 0.2  # over the mems grade's 0.15
    assert n.gnss.lever_arm_b.tolist() == [0.0, 0.5, 0.0] and n.alignment.mode == "static"  # the defaults kept
    with pytest.raises(dcfg.DatasetConfigError, match=r"unknown key 'nav\.gnss\.gaet' \(did you mean 'gate'\?\)$"):
        dcfg.load(_toml(tmp_path / "bad.toml", head + "[nav.gnss]\ngaet = 1.0\n"))


def test_outage_windows_and_mounting():
    o = dcfg.OutageProtocol("takeoff", 20.0, 10.0, 20.0)
    assert o.windows(100.0, 185.0) == [(120.0, 130.0), (150.0, 160.0)]
    c = dcfg.from_dict({"dataset": {"name": "m"}, "aiding": {"mag": False},
                        "mounting": {"imu_to_body_deg": [0, 0, 90], "imu_time_offset_s": 0.02}})  # fmt: skip
    ds = Dataset([ImuSample(1.0, 0.01, np.array((0.01, 0.0, 0.0)), np.array((0.0, 0.0, -0.098)))])
    p = prepare(ds, c)
    # IMU x axis = body y (yaw 90°): a rate about the IMU's x is a rate about the body's y
    np.testing.assert_allclose(p.imu[0].dtheta, (0.0, 0.01, 0.0), atol=1e-12)
    assert p.imu[0].t == pytest.approx(1.02)


def test_replay_csv_with_dataset_config(tmp_path: Path, capsys):
    data = tmp_path / "static.csv"
    _static_csv(data)
    cfgp = _toml(tmp_path / "static.toml", GOOD)
    out = tmp_path / "out"
    rc = main(["replay", str(data), "--dataset", str(cfgp), "--out", str(out), "--quiet"])
    text = capsys.readouterr().out
    assert rc == 0, text
    m = json.loads((out / "metrics.json").read_text())
    assert m["format"] == "csv" and m["t_nav_s"] is not None and m["t_nav_s"] < 5.0
    assert m["gnss"]["gnss_h_rms_prior_m"] < 0.2
    assert m["reference"] == "no reference" and "no reference" in text
    att = m["onboard"]["attitude_deg"]
    for ax in ("roll", "pitch", "yaw"):
        assert att[ax]["rms"] < 1.0, (ax, att)
    o = m["outages"]
    t0 = m["t0_s"]
    assert o["outages_scored"] == 2
    np.testing.assert_allclose([w["window_s"] for w in o["windows"]], np.array([[20, 30], [40, 50]]) + t0)
    # at rest the trivial predictors are exact; the filter drifts a little in the outage
    assert o["hold_h_rms_m"] == pytest.approx(0.0, abs=1e-6) and o["outage_h_rms_m"] < 1.0
    # what the drift is made of, fitted per outage: small, and the fit explains it
    for w in o["windows"]:
        assert w["start_vel_err_mps"] < 0.01 and w["sf_err_mps2"] < 0.005 and w["growth_fit_rms_m"] < 0.01, w
    assert o["sf_err_max_mps2"] == max(w["sf_err_mps2"] for w in o["windows"])
    assert "fitted: specific-force error" in text
    # beside it the filter's own tilt σ when each window opened (measured 1.3° / 1.2°): it covers the drift's tilt
    sd = [w["start_tilt_std_deg"] for w in o["windows"]]
    assert all(0.0 < x < 3.0 for x in sd) and o["start_tilt_std_max_deg"] == max(sd), sd
    assert all(w["sf_err_tilt_deg"] < w["start_tilt_std_deg"] for w in o["windows"])
    assert "filter's tilt σ at the starts" in text
    assert "gnss_pos" in m["rejection"] and (out / "attitude.png").is_file() and (out / "outages.png").is_file()
    assert "below both predictors in every outage" in text and "vs onboard: attitude yaw" in text


def test_replay_unsupported_file_is_one_line_error(tmp_path: Path, capsys):
    p = tmp_path / "flight.txt"
    p.write_text("not a log\n")
    assert main(["replay", str(p), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "not a supported dataset (expected" in err
    for src, said in ((tmp_path, "not a supported dataset (expected"), (tmp_path / "missing.bin", "no such file")):
        assert main(["replay", str(src), "--out", str(tmp_path / "o")]) == 2  # a folder; a path that is not there
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and said in err, err
    bad = _toml(tmp_path / "b.toml", "[dataset]\nname='x'\n[aiding]\nmag_ref='wmm'\n")
    assert main(["replay", str(p), "--dataset", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "unknown key aiding.mag_ref" in capsys.readouterr().err


@pytest.mark.slow
def test_replay_px4_hover_against_ekf2(tmp_path: Path, capsys):
    cfgp = REPO / "configs" / "datasets" / "px4_hover.toml"
    out = tmp_path / "hover"
    assert main(["replay", "--dataset", str(cfgp), "--out", str(out), "--quiet", "--no-plots"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    ob = m["onboard"]
    assert m["t_nav_s"] < 6.0 and ob["against"] == "EKF2"
    assert ob["position_m"]["down"]["rms"] < 0.6  # height vs EKF2 (mean datum removed)
    # no divergence without GNSS (the hold fixes); docs/datasets.md gives the figures against the targets
    assert ob["attitude_deg"]["roll"]["rms"] < 5.0 and ob["attitude_deg"]["pitch"]["rms"] < 5.0
    assert "hold" in capsys.readouterr().out


def test_heading_only_magnetometer_keeps_the_tilt():
    from ins_hil.datasets.run import heading_only
    from ins_hil.nav.rotation import quat_from_euler
    from ins_hil.types import MagSample

    ref = np.array((20.0, 1.0, 40.0))
    q = quat_from_euler(math.radians(5.0), math.radians(-3.0), math.radians(40.0))
    C = dcm_from_euler(math.radians(5.0), math.radians(-3.0), math.radians(40.0))
    # a reading whose dip is 6° off the reference and whose heading is 2° off the estimate
    bad = dcm_from_euler(0.0, math.radians(6.0), math.radians(2.0)) @ ref
    m = heading_only(MagSample(0.0, C.T @ bad), q, ref)
    mn = C @ m.field_b
    assert np.linalg.norm(mn) == pytest.approx(np.linalg.norm(ref))
    assert mn[2] == pytest.approx(ref[2])  # the dip is the reference's: no tilt information
    yaw = math.degrees(math.atan2(mn[1], mn[0]) - math.atan2(ref[1], ref[0]))
    assert yaw == pytest.approx(math.degrees(math.atan2(bad[1], bad[0]) - math.atan2(ref[1], ref[0])))


@pytest.mark.slow
def test_replay_ardupilot_against_nkf1_to_the_crash(tmp_path: Path):
    out = tmp_path / "ardu"
    cfgp = REPO / "configs" / "datasets" / "ardupilot_copter.toml"
    assert main(["replay", "--dataset", str(cfgp), "--out", str(out), "--quiet", "--no-plots"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert "loss of control" in m["end_of_valid_data"] and m["t1_s"] < 370.2
    assert m["mag_reference"].startswith("WMM WMM_2015v2")
    att = m["onboard"]["attitude_deg"]
    # the targets against NKF1 with the field from the magnetic model
    assert att["roll"]["rms"] <= 1.0 and att["pitch"]["rms"] <= 1.5 and att["yaw"]["rms"] <= 2.0, att
    assert all(v["rate"] < 0.03 for v in m["rejection"].values())
    # the replay runs the gateway's drift monitor: its baro−GNSS height slope test, with the baro's time-correlated
    # errors modelled, flags nothing (it flagged the baro at 37.6 s, 171 of 1445 samples excluded, with a
    # white-noise slope variance): no warning
    assert m["warnings"] == [], m["warnings"]


def test_replay_reports_lost_imu_data(tmp_path: Path, capsys):
    """1.5 s of IMU rows missing from a CSV: the replay says how many gaps the core coasted across, and how long;
    a log without gaps has no such row."""
    cfgp = _toml(
        tmp_path / "static.toml", GOOD.replace('against = ["gnss", "onboard", "reference"]', 'against = ["gnss"]')
    )
    for name, lost in (("gap", (3001, 3151)), ("nogap", (0, 0))):
        data = tmp_path / f"{name}.csv"
        _static_csv(data, lost=lost)
        out = tmp_path / name
        assert main(["replay", str(data), "--dataset", str(cfgp), "--out", str(out), "--quiet", "--no-plots"]) == 0
        text = capsys.readouterr().out
        m = json.loads((out / "metrics.json").read_text())
        w = [x for x in m["outages"]["windows"] if x["scored"]]
        assert [x["window_s"][0] for x in w] == pytest.approx([20.01, 40.01])  # the data start at 0.01 s
        if name == "gap":
            assert m["imu_lost"]["gaps"] == 1 and m["imu_lost"]["s"] == pytest.approx(1.5, abs=1e-6)
            assert "IMU data lost (coasted)" in text and "1 gaps, 1.50 s" in text
            assert m["gnss"]["gnss_h_rms_prior_m"] < 0.2  # at rest, coasted at zero velocity: no jump
            # the outage at 40.01 s opened 8.51 s after the gap (30.0-31.5 s) ended; the one at 20 s saw none
            assert w[1]["before"]["imu_lost_s"] == pytest.approx(1.5, abs=1e-6)
            assert w[1]["before"]["since_imu_lost_s"] == pytest.approx(8.51, abs=1e-6)
            assert w[0]["before"]["imu_lost_s"] == 0.0 and w[0]["before"]["since_imu_lost_s"] is None
        else:
            assert m["imu_lost"] == {"gaps": 0, "s": 0.0} and "IMU data lost" not in text
            assert all(x["before"]["imu_lost_s"] == 0.0 for x in w)
        assert all(x["before"]["peak_rate_dps"] < 0.01 for x in w)  # at rest: the Earth's rate only
        assert all(x["before"]["sf_corr_mps2"] < 0.01 for x in w)  # a level vehicle at rest: nothing to correct
        # at rest, holding the last fix is exact: each outage that loses to it is listed with what preceded it
        for k, x in enumerate(w, 1):
            line = [ln for ln in text.splitlines() if ln.strip().startswith(f"outage {k}: ours / hold / cv (m)")]
            assert len(line) == (0 if x["beats_both"] else 1)
            if line and name == "gap" and k == 2:
                assert "opened 8.5 s after 1.50 s of lost IMU data" in line[0]


def test_autocorrelation_of_white_ma1_ar1_series_and_no_pair_across_a_gap():
    from ins_hil.datasets.run import autocorrelation

    rng = np.random.default_rng(7)
    n = 4000
    t = np.arange(n) * 0.2
    e = rng.standard_normal(n + 1)
    white = autocorrelation(t, e[1:])
    assert all(abs(a) < 1.96 / math.sqrt(n) * 1.5 for a in white), white
    ma1 = autocorrelation(t, e[1:] - e[:-1])  # a differenced white sequence: ρ1 = −1/2, ρ2 = 0
    assert ma1[0] == pytest.approx(-0.5, abs=0.04) and abs(ma1[1]) < 0.05
    ar = np.zeros(n)
    for k in range(1, n):
        ar[k] = 0.8 * ar[k - 1] + e[k]
    assert autocorrelation(t, ar)[:2] == pytest.approx([0.8, 0.64], abs=0.04)
    # a gap of 10 s in the middle: the pair across it is left out
    tg = np.concatenate([t[:200], t[200:400] + 10.0])
    x = np.concatenate([np.ones(200), -np.ones(200)]) + 0.01 * e[:400]
    d = x - x.mean()
    keep = np.ones(399, dtype=bool)
    keep[199] = False
    want = float(np.mean((d[1:] * d[:-1])[keep]) / np.mean(d * d))
    assert autocorrelation(tg, x, lags=1)[0] == pytest.approx(want)
    assert math.isnan(autocorrelation(t[:8], e[:8], lags=1)[0])  # fewer than 10 pairs


def test_velocity_innovations_are_white_for_white_gnss_errors_and_not_for_correlated_ones(tmp_path: Path):
    """A vehicle at rest whose GNSS velocity carries noise of the σ it reports (0.1 m/s): white noise gives near
    white innovations; the same σ correlated from fix to fix (AR(1), ρ = 0.9, as a receiver's own smoothing
    makes it) gives innovations that keep their sign over several fixes (a positive lag 1)."""
    from ins_hil.datasets import report

    lag1 = {}
    for rho in (0.0, 0.9):
        data = tmp_path / f"noisy{rho}.csv"
        _static_csv(data, seconds=150.0)
        rng = np.random.default_rng(3)
        err = np.zeros(3)
        rows = []
        for line in data.read_text().splitlines():
            if line.startswith("gnss,"):
                err = rho * err + math.sqrt(1.0 - rho**2) * rng.normal(0.0, 0.1, 3)  # stationary σ 0.1 m/s
                c = line.split(",")
                c[5:8] = [f"{x:.4f}" for x in err]
                line = ",".join(c)
            rows.append(line)
        data.write_text("\n".join(rows) + "\n")
        cfg = dcfg.from_dict(tomllib_loads(GOOD), "noisy")
        m, _ = report.replay(report.load(data, cfg), cfg)
        w = m["gnss"]["vel_innovation"]
        assert w["n"] > 400 and w["white_band"] == pytest.approx(1.96 / math.sqrt(w["n"]))
        assert 0.03 < min(w["rms_mps"]) and max(w["rms_mps"]) < 0.2, w
        lag1[rho] = float(np.mean(w["lag1"]))
    assert abs(lag1[0.0]) < 0.15 and lag1[0.9] > 0.5, lag1
    text = report.format_table(report.summary(m))
    assert "lag-1 autocorrelation N / E" in text and "white: ±" in text


def tomllib_loads(text: str) -> dict:
    import tomllib

    return tomllib.loads(text)


def test_error_growth_recovers_the_start_velocity_and_specific_force_errors():
    from ins_hil.datasets.run import error_growth

    rng = np.random.default_rng(5)
    tau = np.arange(0.2, 10.0, 0.2)
    v0, acc = np.array([0.18, -0.04]), np.array([0.115, 0.083])
    e = np.outer(tau, v0) + 0.5 * np.outer(tau**2, acc) + rng.normal(0.0, 0.02, (len(tau), 2))
    g = error_growth(tau, e)
    assert g is not None
    np.testing.assert_allclose(g[0], v0, atol=0.02)
    np.testing.assert_allclose(g[1], acc, atol=0.005)
    assert 0.01 < g[2] < 0.04  # the residual is the noise
    assert error_growth(tau[:5], e[:5]) is None


def test_what_preceded_an_outage_lost_imu_data_and_a_fast_turn():
    """``preceded_by``: the IMU data lost in the 10 s before an outage and the peak turn rate (0.25-s means of the
    body rate, so vibration averages out), each with the time since; nothing before the look-back counts; the
    fixes' specific-force corrections of the last 5 s summed (a settled filter's cancel out)."""
    from types import SimpleNamespace

    from ins_hil.datasets.run import corrections, preceded_by, rate_bins, typical_corrections

    rng = np.random.default_rng(3)
    imu = []
    for k in range(1, 1001):  # 10 s at 100 Hz: a 90 °/s yaw over [5, 6) s, 0.2 rad/s vibration on every axis
        t = k / 100
        w = rng.normal(0.0, 0.2, 3) + (np.array((0.0, 0.0, math.radians(90.0))) if 5.0 < t <= 6.0 else 0.0)
        imu.append(ImuSample(t=t, dt=0.01, dtheta=w * 0.01, dvel=np.zeros(3)))
    rb = rate_bins(imu)
    assert rb.shape == (40, 2) and rb[0, 0] == pytest.approx(0.01)
    # 60 s of fixes at 5 Hz: a settled filter's corrections alternate in sign; over [6, 8) s they all push north
    tf = np.arange(0.0, 60.0, 0.2)
    sf = np.column_stack([tf, np.where((tf >= 6.0) & (tf < 8.0), 0.05, 0.01 * (-1.0) ** np.round(tf * 5)), 0 * tf])
    r = SimpleNamespace(imu_gaps=np.array([[2.0, 0.7], [3.0, 0.3]]), rate_bins=rb, sf_corr=sf)
    b = preceded_by(r, 8.0)
    assert b["sf_corr_mps2"] == pytest.approx(0.5, abs=0.011)  # 10 fixes × 0.05 (+ at most one settled fix)
    assert typical_corrections(r) < 0.03 and corrections(r, 0.0, 5.0) < 0.011
    assert b["imu_lost_s"] == pytest.approx(1.0) and b["since_imu_lost_s"] == pytest.approx(5.0)
    assert 85.0 < b["peak_rate_dps"] < 100.0 and 1.9 < b["since_peak_rate_s"] < 2.8  # since its 0.25-s bin ended
    late = preceded_by(r, 13.5)  # the gaps are more than 10 s back; the turn is still inside
    assert late["imu_lost_s"] == 0.0 and math.isnan(late["since_imu_lost_s"]) and late["peak_rate_dps"] > 85.0
    quiet = preceded_by(SimpleNamespace(imu_gaps=np.zeros((0, 2)), rate_bins=rb, sf_corr=np.zeros((0, 3))), 4.0)
    assert quiet["sf_corr_mps2"] == 0.0
    assert quiet["peak_rate_dps"] < 10.0  # the vibration alone: 0.2 rad/s per sample, 0.25-s means of 25 samples
