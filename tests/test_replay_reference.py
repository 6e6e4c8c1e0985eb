"""Scoring against a reference (issue 40 item 5): outages scored against a log's reference trajectory with its
lever arm, the onboard-estimator comparison on one datum and trimmed to its valid part."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_datasets_boundary import LAT, LON, H, _cfg, _ds, _rest

from ins_hil.datasets import compare as cmp
from ins_hil.datasets import report
from ins_hil.datasets.config import OutageProtocol
from ins_hil.datasets.dataset import Dataset, Trajectory
from ins_hil.geoid import msl_height

#: the reference point: 1.5 m ahead of the IMU (body FRD), the vehicle at rest heading north
LEVER = np.array((1.5, 0.0, 0.0))


def _with_reference(ds: Dataset) -> Dataset:
    t = np.arange(0.1, 30.0, 0.1)
    pos = np.tile(LEVER, (len(t), 1))  # NED from the fixes' point (the IMU): the lever arm, heading north
    ds.reference = Trajectory("reference", t_pos=t, pos_ned=pos, origin=(LAT, LON, H))
    return ds


def _scored(lever: np.ndarray) -> dict:
    cfg = dataclasses.replace(_cfg(), reference_lever_arm=lever,
                              outages=OutageProtocol("start", 15.0, 5.0, 3.0, None, 0.0))  # fmt: skip
    m, _ = report.replay(_with_reference(_ds(_rest())), cfg)
    return m


def test_outages_are_scored_against_the_reference_with_its_lever_arm():
    with_lever, without = _scored(LEVER), _scored(np.zeros(3))
    o = with_lever["outages"]["reference"]
    assert o["outages_scored"] >= 2 and o["samples"] > 50
    assert o["h_rms_m"] < 0.3 and o["lever_arm_m"] == LEVER.tolist()
    assert without["outages"]["reference"]["h_rms_m"] > 1.2  # the 1.5-m lever arm not applied
    # the GNSS-present comparison with the reference applies it too
    assert with_lever["reference"]["position_m"]["horizontal"]["rms"] < 0.3
    assert without["reference"]["position_m"]["horizontal"]["rms"] > 1.2
    text = report.format_table(report.summary(with_lever))
    assert "vs reference (" in text


def test_onboard_comparison_is_on_one_datum_and_trimmed_to_its_valid_part():
    """An onboard estimate whose origin height is MSL (converted with the EGM96 undulation: ~48 m here) and one
    bad sample after landing: neither shows in the comparison."""
    m, runs = report.replay(_ds(_rest()), _cfg())
    r = runs["gnss"]
    t = r.t[::20]
    pos = r.ned[::20].copy()
    pos[-3] += (0.0, 508.0, 0.0)  # one bad sample after landing
    origin_msl = (LAT, LON, msl_height(LAT, LON, H))
    ob = Trajectory("EKF2", t_pos=t, pos_ned=pos, origin=origin_msl, origin_datum="msl")
    landing = float(t[-5])
    a, b, why = cmp.valid_span(ob, r.t_nav, r.t[-1], takeoff=float(t[10]), landing=landing)
    assert (a, b) == (float(t[10]), landing) and why == "from take-off, to landing"
    c = cmp.compare(r, ob, a, b)["position_m"]
    assert c["east"]["max"] < 1e-6 and abs(c["down"]["mean"]) < 1e-6
    wgs = cmp.compare(r, dataclasses.replace(ob, origin_datum="wgs84"), a, b)["position_m"]
    assert wgs["down"]["mean"] == pytest.approx(origin_msl[2] - H, abs=1e-6)  # the datum error it removes
    assert abs(H - origin_msl[2]) > 40.0
    untrimmed = cmp.compare(r, ob, a, float(r.t[-1]))["position_m"]
    assert untrimmed["east"]["max"] > 500.0
    # the estimator's own status ends its valid part
    _, b2, why2 = cmp.valid_span(dataclasses.replace(ob, t_valid_end=float(t[30])), r.t_nav, r.t[-1])
    assert b2 == float(t[30]) and "status says invalid" in why2
    assert math.isfinite(m["t_nav_s"])


def test_an_empty_compared_span_is_not_printed():
    """A core that never navigated before landing has nothing to compare: no 'compared 92.5–90.7 s' row (the span
    backwards), as `ins-hil replay hover.ulg` without a config printed it."""
    c = {"against": "EKF2", "from_s": 1092.5, "to_s": 1090.7, "trimmed": "to landing"}
    m = {
        "format": "px4-ulog",
        "duration_s": 92.5,
        "t_nav_s": None,
        "t0_s": 1000.0,
        "onboard": c,
        "realtime_factor": 150.0,
    }
    assert not any("compared" in row[0] for row in report.summary(m))
    ok = dict(m, t_nav_s=3.5, onboard=dict(c, from_s=1003.5))
    assert ("vs EKF2: compared", "3.5–90.7 s", "to landing") in report.summary(ok)
