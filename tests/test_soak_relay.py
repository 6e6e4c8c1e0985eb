"""The soak's null relay (platform floor): the gateway's ODOMETRY encoding and due rule, epoch assembly, and a
real relay soak over the ptys and UDP whose measurement is checked (correctness, never a timing assertion)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import machine_alone
from pymavlink.dialects.v20 import common as mavlink2
from runtime_helpers import BufferSink

from ins_hil.cli import main as cli_main
from ins_hil.runtime import mavlink_out
from ins_hil.runtime.mavlink_out import GCS_RATES, EndpointConfig, MavlinkEndpoint
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.soak.analysis import analyse
from ins_hil.soak.orchestrate import RELAY_LABEL, SoakOptions, run_soak
from ins_hil.soak.relay import Epochs, Schedule, odometry_message
from ins_hil.soak.report import floor_comparison, run_section
from ins_hil.soak.suite import RELAY_TITLE, note_command, relay_summary
from ins_hil.types import ImuSample, NavState

DURATION = 4.0
GCS_RATE = 47.0


def _odometry_endpoint() -> tuple[MavlinkEndpoint, BufferSink]:
    """A gateway ground-station endpoint that sends ODOMETRY alone, at the soak's rate."""
    rates = {**dict.fromkeys(GCS_RATES, 0.0), "ODOMETRY": GCS_RATE}
    ep = MavlinkEndpoint(EndpointConfig(role="gcs", rates=rates), RuntimeMetrics())
    ep.reset_counter = 0  # random per process; the relay sends 0
    sink = BufferSink()
    ep.tr = sink  # type: ignore[assignment]
    return ep, sink


def _state(t: float) -> NavState:
    """A state at the home, level, at rest, covariance unknown, not aligned: what the relay's message says."""
    z = np.zeros(3)
    return NavState(t=t, q_nb=np.array([1.0, 0.0, 0.0, 0.0]), vel_ned=z, lat=0.8, lon=0.5, h=180.0, std_pos=z,
                    std_vel=z, std_att=z, omega_b=z, aligned=False)  # fmt: skip


def test_relay_odometry_is_the_gateways_message() -> None:
    """time_usec and every other field as the gateway's own ODOMETRY of a state at home, level, at rest
    (the gateway's home-relative down is -0.0 there, the relay's 0.0: equal values, same length)."""
    ep, sink = _odometry_endpoint()
    mav = mavlink2.MAVLink(None, srcSystem=ep.cfg.sysid, srcComponent=ep.cfg.compid)
    times = [0.001, 0.0213, 1.234567, 3599.999, 4294.967297]  # the last is past the 32-bit µs wrap
    mine = [odometry_message(mav, t) for t in times]
    for t in times:
        ep._send_odometry(_state(t))
    assert [len(b) for b in mine] == [len(b) for b in sink.bufs]
    got = [m for b in mine for m in mavlink2.MAVLink(None).parse_buffer(b) or []]
    ref = [m for b in sink.bufs for m in mavlink2.MAVLink(None).parse_buffer(b) or []]
    assert len(got) == len(ref) == len(times)
    for a, b in zip(got, ref):
        assert (a.get_srcSystem(), a.get_srcComponent(), a.get_seq()) == (b.get_srcSystem(), b.get_srcComponent(),
                                                                          b.get_seq())  # fmt: skip
        for f in a.get_fieldnames():
            np.testing.assert_array_equal(np.array(getattr(a, f), dtype=float), np.array(getattr(b, f), dtype=float))
    assert [m.time_usec for m in got] == [round(t * 1e6) for t in times]


def test_relay_sends_the_states_the_gateway_sends(monkeypatch: pytest.MonkeyPatch) -> None:
    """The due rule: for the same state-ready times (1 kHz with jitter and stalls) the relay's schedule picks
    exactly the states the gateway's endpoint sends."""
    rng = np.random.default_rng(5)
    ready = np.cumsum(1_000_000 + rng.integers(-200_000, 200_000, 5000))
    ready[rng.choice(len(ready), 30, replace=False)] += rng.integers(1_000_000, 20_000_000, 30)
    ready = np.maximum.accumulate(ready) + 10**12
    clock = [0]
    monkeypatch.setattr(mavlink_out.time, "monotonic_ns", lambda: clock[0])
    ep, sink = _odometry_endpoint()
    sched = Schedule(GCS_RATE)
    sent_gw, sent_relay = [], []
    for k, r in enumerate(ready.tolist()):
        clock[0] = r
        n = len(sink.bufs)
        ep.offer(_state(k * 1e-3), r, r)
        if len(sink.bufs) > n:
            sent_gw.append(k)
        if sched.due(r):
            sent_relay.append(k)
    assert sent_relay == sent_gw
    assert len(sent_gw) == pytest.approx((ready[-1] - ready[0]) * 1e-9 * GCS_RATE, abs=2)


def _imu(t: float, unit: int) -> ImuSample:
    return ImuSample(t, 1e-3, np.zeros(3), np.zeros(3), unit, 0)


def test_epochs_complete_when_every_unit_has_delivered() -> None:
    e = Epochs(2)
    assert not e.complete(_imu(0.001, 0)) and e.complete(_imu(0.001, 1))
    assert not e.complete(_imu(0.002, 1)) and not e.complete(_imu(0.003, 0))
    assert e.complete(_imu(0.003, 1))  # epoch 2 lost unit 0's frame: given up
    assert e.incomplete == 1
    assert not e.complete(_imu(0.002, 0)) and e.late == 1  # too late
    assert Epochs(1).complete(_imu(0.5, 0))


@pytest.fixture(scope="module")
def relay_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("relay")
    with machine_alone():  # a 1 kHz real-time run: alone on the machine (its frame count is a real-time property)
        d = run_soak(SoakOptions(duration=DURATION, gateway="relay", faults="none", out=str(out)))
    m, _ = analyse(d)
    return d, m


def test_relay_soak_measures_end_to_end_latency(relay_run: tuple[Path, dict[str, Any]]) -> None:
    d, m = relay_run
    gw = json.loads((d / "gateway.json").read_text())
    assert gw["kind"] == "relay" and m["gateway"] == "relay" and m["label"] == RELAY_LABEL
    # every epoch written to the pty was read and decoded by the relay: nothing lost
    fr = m["frames"]
    n_epochs = round(DURATION * 1000.0)
    assert fr["scheduled"] == [n_epochs] and fr["received"] == [n_epochs] and fr["lost"] == 0
    assert gw["imu_epochs"] == n_epochs
    # ~47 ODOMETRY a second, from the first epoch on, each naming an emitted epoch, received after it
    odo = np.fromfile(d / "gcs_odometry.bin", dtype=np.int64).reshape(-1, 2)
    e2e = m["latency"]["end_to_end"]
    assert m["latency"]["end_to_end_unmatched"] == 0
    assert e2e["count"] == len(odo) == gw["odometry_sent"]
    assert 0.9 * DURATION * GCS_RATE <= e2e["count"] <= DURATION * GCS_RATE + 2
    assert 19_000 <= np.median(np.diff(odo[:, 0])) <= 23_000  # sensor µs between messages: ~1/47 s
    em = np.fromfile(d / "emission.bin", dtype=np.int64).reshape(-1, 2)
    lat = odo[:, 1] - em[np.searchsorted(em[:, 0], odo[:, 0]), 1]
    assert np.all(lat > 0)
    assert e2e["p50_us"] > 0 and e2e["max_us"] >= e2e["p999_us"] >= e2e["p99_us"] >= e2e["p50_us"]
    assert m["latency"]["state_to_sent"]["count"] == e2e["count"]
    # the GNSS input was drained: the simulator's datagrams all went somewhere
    sim = json.loads((d / "sim.json").read_text())
    assert sim["udp_send_errors"] == 0 and gw["gnss_udp"]["datagrams"] >= 5 * (DURATION - 1)
    assert json.loads((d / "gcs.json").read_text())["messages"] == {"ODOMETRY": len(odo)}


def test_relay_report_says_not_applicable_and_compares_with_the_gateway(
    relay_run: tuple[Path, dict[str, Any]],
) -> None:
    _, m = relay_run
    c = m["checks"]
    assert c["nav_sigma_coverage"]["ok"] is None and c["nav_rms"]["ok"] is None and c["rss_growth"]["ok"] is None
    assert c["nav_sigma_coverage"]["note"].startswith("not applicable")
    assert c["loop_p999_steal_free"]["ok"] is None and c["lost_frames"]["ok"] is True
    assert c["e2e_p99"]["ok"] is None  # the tail is judged against the floor in an interleaved run
    md = run_section(m, [], RELAY_TITLE)
    assert "## Platform floor: null relay" in md and RELAY_LABEL.capitalize() in md
    assert "not applicable: null relay (no navigation)" in md
    assert "navigation error (after" not in md
    # a campaign's comparison: the gateway's run beside the floor (here the same run: differences 0)
    gw = {**m, "gateway": "ins-hil"}
    assert "| gateway − floor | | 0 | 0 | 0 | 0 |" in floor_comparison(gw, m)
    # and over the seconds without host steal, when the analysis found any (a real run's steal figures)
    q = m["steal"]["e2e_in_intervals_without_steal"]
    md = floor_comparison(gw, m)
    if q.get("n"):
        assert f"| null relay (platform floor) | {q['n']} |" in md and "without steal (µs)" in md
    calm = {"n": 10, "p50_us": 1.0, "p99_us": 2.0, "p999_us": 3.0}
    st = {
        "seconds_per_cpu": [0.5, 0.25],
        "intervals_with_steal": 3,
        "intervals": 60,
        "e2e_in_intervals_without_steal": calm,
    }
    md = floor_comparison({**gw, "steal": st}, {**m, "steal": st})
    assert "| gateway (main run) | 10 | 1 | 2 | 3 |" in md and "0.50 / 0.25 s of steal" in md and "3 of 60 s" in md
    s = relay_summary([("main", "Main run", gw, []), ("relay", RELAY_TITLE, m, [])])
    assert s is not None and s["end_to_end"] == m["latency"]["end_to_end"]
    assert s["gateway_minus_floor_us"]["p99_us"] == 0


def test_campaign_command_line_names_the_relay_run(capsys: pytest.CaptureFixture[str]) -> None:
    cmd = note_command(SoakOptions(duration=1800, out="soak-out"), [], [], 60.0, 0.0, None, 30.0, 600.0)
    assert "--relay-duration 600" in cmd and "--gateway" not in cmd
    assert "--gateway relay" in note_command(SoakOptions(gateway="relay"), [], [], 60.0, 0.0, None)
    assert cli_main(["soak", "--gateway", "relay", "--relay-duration", "5"]) == 2  # the main run is the relay
    assert "already" in capsys.readouterr().err
