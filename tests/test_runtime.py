"""The real-time loop: a live run on the simulated devices (pty + UDP), exact replay, metrics, stop."""

from __future__ import annotations

import asyncio
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from conftest import machine_alone
from runtime_helpers import free_port, sim_config, sim_gateway

from ins_hil.runtime.loop import Gateway
from ins_hil.runtime.metrics import LatencyHistogram
from ins_hil.runtime.recorder import read_records
from ins_hil.runtime.replay import replay_log
from ins_hil.sim.devices import SimConfig, truth_chunks
from ins_hil.types import BaroSample, GnssFix, ImuSample, NavState

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def live_run(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """One live run at 1 kHz with every state kept, until the counts the tests need (about 5 s on an idle machine;
    a count, not a time, so a busy machine runs longer instead of failing; 120 s guards a hang)."""
    tmp = tmp_path_factory.mktemp("live")
    port = free_port()  # nobody listens: the endpoint sends anyway and counts what the socket refuses
    cfg = sim_config(sim={"imu_errors": "none"}, outputs=[{"name": "gcs", "url": f"udpout:127.0.0.1:{port}"}])
    gw = sim_gateway(cfg, record_path=tmp / "live.ihlog")
    states: list[NavState] = []
    gw.on_state.append(states.append)

    async def run() -> None:
        task = asyncio.create_task(gw.run(duration=None, signals=False))
        for _ in range(1200):
            await asyncio.sleep(0.1)
            c = gw.pipeline.counts
            if (
                gw.metrics.source("imu0").received > 4000
                and gw.metrics.source("gnss").received > 20
                and c.get("fused_GnssFix", 0) > 15
                and c.get("fused_BaroSample", 0) > 80
            ) or task.done():
                break
        gw.request_stop("test")
        await task

    asyncio.run(run())
    return {"gw": gw, "states": states, "log": tmp / "live.ihlog", "cfg": cfg}


def test_live_run_consumes_every_input_and_counts(live_run: dict) -> None:
    gw, states = live_run["gw"], live_run["states"]
    snap = gw.metrics.snapshot()
    imu = snap["sources"]["imu0"]
    # at 1 kHz: every received sample was consumed (nothing dropped in the queue)
    assert imu["received"] > 4000
    assert "queue_full" not in imu["dropped"]
    n_imu_records = sum(isinstance(r, ImuSample) for r in read_records(live_run["log"]))
    assert n_imu_records == imu["received"]
    # one state per IMU epoch after initialisation, each latency measured
    assert len(states) == snap["imu_epochs"] == snap["latency"]["arrival_to_state"]["count"]
    assert len(states) == imu["received"] - gw.pipeline.counts["imu_before_init"]
    assert snap["sources"]["gnss"]["received"] > 20
    assert snap["fused"]["fused_GnssFix"] > 15 and snap["fused"]["fused_BaroSample"] > 80
    lat = snap["latency"]["arrival_to_state"]
    assert 0 < lat["min_us"] <= lat["p50_us"] <= lat["p99_us"] <= lat["max_us"]
    # sensor time strictly increasing at the IMU rate; a step of more than one period only where frames never
    # arrived (the simulator drops whole frames when its pty is not read for ~100 ms: a busy machine), counted
    t = np.array([s.t for s in states])
    steps = np.diff(t) / 1e-3
    assert np.all(steps > 0)
    assert np.allclose(steps, np.round(steps), atol=1e-6)
    (drv,) = [d for d in gw.drivers if d.name == "imu0"]
    lost = int(np.sum(np.round(steps) - 1))
    assert lost <= drv.health.errors.get("seq_gap", 0), (lost, drv.health.errors)


def test_replay_reproduces_online_states_bit_for_bit(live_run: dict) -> None:
    states = live_run["states"]
    res = replay_log(live_run["log"])
    assert len(res.states) == len(states)
    for a, b in zip(states, res.states):
        assert a.t == b.t and a.lat == b.lat and a.lon == b.lon and a.h == b.h
        assert np.array_equal(a.q_nb, b.q_nb) and np.array_equal(a.vel_ned, b.vel_ned)
        assert np.array_equal(a.std_pos, b.std_pos) and a.test_ratios == b.test_ratios


def test_live_states_follow_the_simulated_truth(live_run: dict) -> None:
    """Error-free IMU, GNSS 1 m / 0.1 m/s: attitude within 3 σ of the filter's own accuracy, position
    within the GNSS initialisation error (1 m N/E, 2 m D σ)."""
    states = live_run["states"]
    cfg: SimConfig = live_run["cfg"].sim
    truth = next(truth_chunks(cfg))[0]
    from ins_hil.nav import earth
    from ins_hil.nav.rotation import quat_angle_between

    for st in states[:: max(1, len(states) // 20)]:
        k = round(st.t * cfg.imu_rate)
        assert abs(truth.t[k] - st.t) < 1e-9
        err = math.degrees(quat_angle_between(st.q_nb, truth.q_nb[k]))
        assert err < 3.0 * math.degrees(float(np.linalg.norm(st.std_att))) + 0.5
        d = earth.ned_from_geodetic(st.lat, st.lon, st.h, truth.lat[k], truth.lon[k], truth.h[k])
        assert np.linalg.norm(d) < 10.0


def test_queue_overflow_is_counted_not_silent() -> None:
    cfg = sim_config()
    cfg.gateway.queue_size = 3

    async def go() -> tuple[Gateway, int]:
        gw = sim_gateway(cfg)
        sink = gw._sink_for("imu0")
        gw._scheduled = True  # the core is running: samples delivered meanwhile wait in the FIFO (bounded)
        for k in range(10):
            sink(ImuSample(t=k * 1e-3, dt=1e-3, dtheta=np.zeros(3), dvel=np.zeros(3)))
        return gw, len(gw.queue)

    gw, depth = asyncio.run(go())
    st = gw.metrics.snapshot()["sources"]["imu0"]
    assert st["received"] == 10 and st["dropped"] == {"queue_full": 7} and depth == 3


def test_sink_runs_the_core_at_once_and_the_rest_of_the_step_in_the_slack() -> None:
    """A sample reaches the pipeline and its state the publishers inside the driver's call of the sink (no turn
    of the event loop in between); the rest of the step (the Python core's time update) runs in the slack, a
    callback after the samples at hand."""
    cfg = sim_config(core={"init": "config", "init_lat_deg": 45.0, "init_lon_deg": 7.0, "init_h": 300.0})

    async def go() -> tuple[int, bool, bool]:
        gw = sim_gateway(cfg)
        states: list[NavState] = []
        gw.on_state.append(states.append)
        sink = gw._sink_for("imu0")
        g = np.array([0.0, 0.0, -9.80665e-3])
        sink(ImuSample(t=1e-3, dt=1e-3, dtheta=np.zeros(3), dvel=g))
        n, pending = len(states), gw.pipeline._step_pending
        await asyncio.sleep(0)  # one turn of the event loop: the slack
        return n, pending, gw.pipeline._step_pending

    n, pending, after = asyncio.run(go())
    assert n == 1 and pending and not after


def test_samples_are_recorded_in_the_slack_in_pipeline_order(tmp_path: Path) -> None:
    """The recorder's encoding is off the IMU path: a sample is handed to it in the slack after the samples at
    hand, every sample in the order the pipeline got it."""
    from ins_hil.runtime.recorder import Recorder

    cfg = sim_config(core={"init": "config", "init_lat_deg": 45.0, "init_lon_deg": 7.0, "init_h": 300.0})

    async def go() -> tuple[int, int]:
        gw = sim_gateway(cfg)
        gw.recorder = Recorder(tmp_path / "r.ihlog", header={})
        sink = gw._sink_for("imu0")
        g = np.array([0.0, 0.0, -9.80665e-3])
        for k in range(1, 4):
            sink(ImuSample(t=k * 1e-3, dt=1e-3, dtheta=np.zeros(3), dvel=g, seq=k))
        before = gw.recorder.records
        await asyncio.sleep(0)  # the slack
        gw.recorder.close()
        return before, gw.recorder.records

    before, after = asyncio.run(go())
    assert before == 0 and after == 3
    assert [s.seq for s in read_records(tmp_path / "r.ihlog")] == [1, 2, 3]


def test_pipeline_holds_aiding_until_its_time_of_validity() -> None:
    from ins_hil.runtime.pipeline import Pipeline, PipelineConfig

    p = Pipeline(PipelineConfig(init="config", init_lat_deg=50.0, init_lon_deg=30.0, init_h=100.0))
    fused: list[float] = []
    assert p.core is not None

    def fuse_steps(m: BaroSample | GnssFix) -> Iterator[None]:
        fused.append(m.t)
        yield from ()

    p.core.fuse_steps = fuse_steps  # type: ignore[attr-defined]
    g = 9.80665
    dv = np.array([0.0, 0.0, -g * 1e-3])
    for k in range(1, 4):
        p.imu(ImuSample(t=k * 1e-3, dt=1e-3, dtheta=np.zeros(3), dvel=dv))
    p.aid(BaroSample(t=0.0025, pressure=1e5))  # in the past: fused in the gap after the next epoch
    p.aid(GnssFix(t=0.0051, lat=0.87, lon=0.52, h=100.0))  # in the future: held
    p.aid(BaroSample(t=0.0045, pressure=1e5))
    assert not p.work() and fused == [] and p.pending_work() == 1  # handed over in this gap: not yet
    p.imu(ImuSample(t=0.004, dt=1e-3, dtheta=np.zeros(3), dvel=dv))
    assert fused == [] and p.work() and fused == [0.0025]
    assert not p.work()  # one segment per gap between IMU epochs
    p.imu(ImuSample(t=0.005, dt=1e-3, dtheta=np.zeros(3), dvel=dv))
    assert fused == [0.0025] and p.pending_work() == 1  # 0.0045 became due at 0.005: fused in this gap
    p.imu(ImuSample(t=0.006, dt=1e-3, dtheta=np.zeros(3), dvel=dv))  # no work() call: runs at this epoch's start
    assert fused == [0.0025, 0.0045] and p.pending_work() == 1  # 0.0051 became due at 0.006
    p.flush()
    assert fused == [0.0025, 0.0045, 0.0051] and p.pending_work() == 0


def test_histogram_percentiles() -> None:
    h = LatencyHistogram()
    rng = np.random.default_rng(0)
    x = rng.uniform(10_000, 1_000_000, 20000).astype(int)  # 10 µs .. 1 ms
    for v in x:
        h.record(int(v))
    for p in (50, 99, 99.9):
        ref = np.percentile(x, p)
        assert abs(h.percentile(p) - ref) / ref < 0.03  # 4 % buckets, centre → ≤ 2 %
    assert h.count == len(x) and h.min_ns == x.min() and h.max_ns == x.max()
    assert math.isnan(LatencyHistogram().percentile(50))


def _start_cli(tmp: Path, *extra: str) -> subprocess.Popen[str]:
    args = [sys.executable, "-m", "ins_hil", "run", "--no-status", "--no-mqtt", "--record", str(tmp / "r.ihlog")]
    return subprocess.Popen([*args, *extra], cwd=tmp, stderr=subprocess.PIPE, text=True)


def _wait_records(path: Path, n: int, timeout: float = 30.0) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if path.exists() and path.stat().st_size > n * 100:  # records are 43..94 bytes
            return
        time.sleep(0.1)
    raise AssertionError(f"{path} did not grow")


def test_sigint_stops_cleanly_and_flushes_the_recorder(tmp_path: Path) -> None:
    p = _start_cli(tmp_path)
    _wait_records(tmp_path / "r.ihlog", 500)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=20)
    assert p.returncode == 0, err
    assert "recorded" in err
    recs = list(read_records(tmp_path / "r.ihlog"))
    assert len(recs) > 500
    # the simulator was stopped with the gateway
    assert "Traceback" not in err


def test_second_sigint_exits_at_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """The first SIGINT asks for a clean stop; the second one calls os._exit(130) at once."""
    exits: list[int] = []
    monkeypatch.setattr(os, "_exit", exits.append)

    async def go() -> Gateway:
        gw = sim_gateway(sim_config())
        gw._on_sigint()
        assert gw._stop.is_set() and gw.stopped_reason == "SIGINT" and exits == []
        gw._on_sigint()
        return gw

    asyncio.run(go())
    assert exits == [130]


def test_sigkill_loses_at_most_100ms_of_inputs(tmp_path: Path) -> None:
    # the recorder's flush period is a real-time property (a gateway starved by another test's processes reads
    # its inputs late, not the recorder loses them): alone on the machine
    with machine_alone():
        p = _start_cli(tmp_path)
        log = tmp_path / "r.ihlog"
        _wait_records(log, 1000)
        time.sleep(0.5)
        os.kill(p.pid, signal.SIGSTOP)  # freeze it: nothing arrives or is written after this instant
        t_stop = time.monotonic_ns()
        os.kill(p.pid, signal.SIGKILL)
        p.communicate(timeout=10)
    # (the simulator process gets SIGTERM from the kernel when its parent dies: PR_SET_PDEATHSIG)
    recs = list(read_records(log))
    last_arrival = max(r.t_arrival_ns for r in recs)
    lost_s = (t_stop - last_arrival) * 1e-9
    assert 0 <= lost_s <= 0.1, lost_s


def test_status_view_renders_the_live_figures(live_run: dict) -> None:
    from rich.console import Console

    from ins_hil.commands.run import _summary_line, render

    with open(os.devnull, "w") as devnull:
        con = Console(width=160, record=True, file=devnull)
        con.print(render(live_run["gw"]))
    text = con.export_text()
    for word in ("imu0", "gnss", "arrival→state", "state→sent", "gcs", "align", "test ratios", "FDI"):
        assert word in text, word
    line = _summary_line(live_run["gw"])
    assert "imu0" in line and "arrival→sent" in line


def test_ins_hil_replay_command_on_an_ihlog(live_run: dict) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "ins_hil", "replay", str(live_run["log"]), "--quiet"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert f"IMU epochs processed {len(live_run['states'])}," in r.stdout
    last = live_run["states"][-1]
    assert f"final state t {last.t:.3f} s" in r.stdout


def test_a_failing_sample_does_not_stop_the_gateway() -> None:
    """A sample the loop cannot process (an IMU sample whose time is not a number at all) is counted as
    ``pipeline_error`` under its source with one warning; the samples queued behind it are processed."""
    cfg = sim_config()

    async def go() -> Gateway:
        gw = sim_gateway(cfg)
        sink = gw._sink_for("imu0")
        dv = np.array([0.0, 0.0, -9.80665e-3])
        for k in range(1, 6):
            sink(ImuSample(t=k * 1e-3, dt=1e-3, dtheta=np.zeros(3), dvel=dv, t_arrival_ns=k * 10**6))
        sink(ImuSample(t=None, dt=1e-3, dtheta=np.zeros(3), dvel=dv, t_arrival_ns=6 * 10**6))  # type: ignore[arg-type]
        for k in range(7, 12):
            sink(ImuSample(t=k * 1e-3, dt=1e-3, dtheta=np.zeros(3), dvel=dv, t_arrival_ns=k * 10**6))
        await asyncio.sleep(0.05)  # the core callback runs
        return gw

    gw = asyncio.run(go())
    assert gw.error is None and not gw._stop.is_set() and gw.stopped_reason == ""
    assert gw.metrics.snapshot()["sources"]["imu0"]["dropped"] == {"pipeline_error": 1}
    assert gw.pipeline.counts["imu_before_init"] == 10  # every other sample reached the pipeline
    assert len([w for w in gw.metrics.warnings if "pipeline error" in w]) == 1


def test_rejections_are_reproduced_by_the_replay_of_a_recording(tmp_path: Path) -> None:
    """The recorder writes every input, the rejected ones too; the replay's pipeline counts the same
    rejections (the live view and the MQTT health show the pipeline's counts)."""
    from ins_hil.runtime.pipeline import Pipeline, PipelineConfig
    from ins_hil.runtime.recorder import Recorder

    cfg = PipelineConfig(init="config", init_lat_deg=50.0, init_lon_deg=30.0, init_h=100.0)
    live = Pipeline(cfg)
    rec = Recorder(tmp_path / "r.ihlog", header={"pipeline": cfg.to_dict()})
    dv = np.array([0.0, 0.0, -9.80665e-3])
    inputs: list = [ImuSample(t=k * 1e-3, dt=1e-3, dtheta=np.zeros(3), dvel=dv) for k in range(1, 50)]
    inputs[20] = ImuSample(t=0.021, dt=0.0, dtheta=np.zeros(3), dvel=dv)
    inputs[30] = ImuSample(t=0.031, dt=1e-3, dtheta=np.array((1e30, 0.0, 0.0)), dvel=dv)
    inputs.insert(40, GnssFix(t=0.039, lat=0.87, lon=0.52, h=math.nan))
    inputs.insert(41, BaroSample(t=0.039, pressure=math.nan))
    for s in inputs:
        rec.write(s)
        if isinstance(s, ImuSample):
            live.imu(s)
        else:
            live.aid(s)
    rec.close()
    live.flush()
    res = replay_log(tmp_path / "r.ihlog")
    rej = {k: v for k, v in res.counts.items() if k.startswith("reject_")}
    assert rej == {"reject_imu_dt": 1, "reject_imu_rate": 1, "reject_gnss_nonfinite": 1, "reject_baro_nonfinite": 1}
    assert res.counts == live.counts
    assert all(math.isfinite(s.lat) and math.isfinite(s.h) for s in res.states)
