"""The live per-sample path in C (firmware_ref/src/live.c): ODOMETRY bytes as the Python floats make them, the FDI
parity group's common epoch with the Python step's decisions, and the C core's published state across a roll-back."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from runtime_helpers import BufferSink

from ins_hil.fdi import monitor as fdi_monitor
from ins_hil.nav.rotation import quat_normalize
from ins_hil.runtime.mavlink_out import EndpointConfig, MavlinkEndpoint
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.types import NavState

live = pytest.importorskip("ins_hil._cref")


def _endpoint(role: str) -> tuple[MavlinkEndpoint, BufferSink]:
    ep = MavlinkEndpoint(EndpointConfig(role=role), RuntimeMetrics())
    ep.reset_counter = 0
    sink = BufferSink()
    ep.tr = sink  # type: ignore[assignment]
    return ep, sink


def _state(rng: np.random.Generator, t: float, k: int) -> NavState:
    q = quat_normalize(rng.normal(size=4))
    if k % 11 == 3:  # pitch at ±90° (the Euler covariance's singularity) and a level attitude
        q = np.array([math.sqrt(0.5), 0.0, math.copysign(math.sqrt(0.5), rng.normal()), 0.0])
    elif k % 11 == 4:
        q = np.array([1.0, 0.0, 0.0, 0.0])
    st = NavState(
        t=t, q_nb=q, vel_ned=rng.normal(0.0, 20.0, 3), lat=0.6 + rng.normal(0.0, 1e-4),
        lon=-1.2 + rng.normal(0.0, 1e-4), h=float(rng.uniform(-100.0, 3000.0)),
        std_pos=np.abs(rng.normal(0.0, 2.0, 3)), std_vel=np.abs(rng.normal(0.0, 0.2, 3)),
        std_att=np.abs(rng.normal(0.0, 0.02, 3)), omega_b=rng.normal(0.0, 1.0, 3), aligned=k % 7 != 0,
    )  # fmt: skip
    if k % 13 == 5:
        st.std_pos = np.array([0.0, 0.0, 0.0])  # unknown covariance
    elif k % 13 == 6:
        st.std_pos = np.array([1.0, math.nan, 1.0])
    elif k % 13 == 7:
        st.lat += 1e-4  # ~600 m: a position step beyond what the velocity explains (reset_counter + 1)
    return st


@pytest.mark.parametrize("role", ["gcs", "fc"])
def test_odometry_in_c_sends_the_bytes_of_the_python_floats(role: str) -> None:
    """live_odometry against the Python builder (the same endpoint without the C buffers): the same bytes, the
    same reset counter, the same refusals of a value the message cannot carry, over random and edge states."""
    rng = np.random.default_rng(42)
    fast, fsink = _endpoint(role)
    slow, ssink = _endpoint(role)
    assert fast._live is not None
    slow._live = None  # the Python floats and _Frame (the path before live.c)
    t = 5.0
    for k in range(600):
        t += float(rng.uniform(0.0, 0.05))
        st = _state(rng, round(t * 1e6) * 1e-6 + (5e-7 if k % 17 == 0 else 0.0), k)  # half-µs: rounding to even
        if k % 97 == 50:
            st.std_att = np.array([1e30, 0.0, 0.0])  # a covariance beyond the float range: refused by both
        if k % 89 == 40:
            st.std_pos = np.array([1e160, 1.0, 1.0])  # σ² beyond the double range: ** raises, C refuses
        if k % 83 == 30:  # NaNs of both signs meeting in sums and products: the Python path for both
            st.std_att = np.array([-math.nan, math.nan, 1.0])
        if k % 79 == 20:
            st.q_nb = np.array([-math.nan, math.nan, 0.0, 0.0])
            st.std_vel = np.array([-math.nan, 1.0, 2.0])
        outcome = []
        for ep in (fast, slow):
            try:
                outcome.append(ep._send_odometry(st))
            except Exception:  # OverflowError, struct.error: counted as encode_error by the endpoint
                outcome.append("raised")
        assert outcome[0] == outcome[1], k
        assert fast.reset_counter == slow.reset_counter, k
    assert len(fsink.bufs) > 300 and fsink.bufs == ssink.bufs
    assert fast.mav.seq == slow.mav.seq and fast.mav.total_bytes_sent == slow.mav.total_bytes_sent


def test_c_hypot_is_pythons() -> None:
    """The Euler covariance's normaliser: CPython's correctly rounded hypot, not sqrt(x² + y²)."""
    rng = np.random.default_rng(1)
    lib = live.lib
    for _ in range(20000):
        a, b = (rng.standard_normal(2) * 10.0 ** rng.uniform(-200, 200, 2)).tolist()
        assert lib.live_hypot(a, b) == math.hypot(a, b)
    for a, b in [(0.0, 0.0), (-0.0, 3.0), (5e-324, 5e-324), (1e-310, 3e-310), (1e308, 1e308), (math.inf, 1.0)]:
        assert lib.live_hypot(a, b) == math.hypot(a, b)
    assert math.isnan(lib.live_hypot(math.nan, 1.0))


def _series(n: int, seed: int) -> Any:
    from ins_hil.fdi.geometry import dual_imu
    from ins_hil.sim.redundant import simulate
    from ins_hil.sim.trajectory import generate, uav_profile

    truth = generate(uav_profile(), n * 0.005, 0.005, 0.87, 0.52, 100.0)
    return simulate(truth, dual_imu(), seed=seed)


def _config(geo: Any) -> Any:
    from ins_hil.fdi.monitor import FdiConfig
    from ins_hil.sim.sensors import mems_accel, mems_gyro

    g, a = mems_gyro(), mems_accel()
    return FdiConfig(geometry=geo, dt=0.005, gyro_noise=g.noise_density, accel_noise=a.noise_density,
                     gyro_bias=g.bias_instability, accel_bias=a.bias_instability, readmit_after=1.0)  # fmt: skip


def test_fdi_group_step_in_c_makes_the_python_decisions(monkeypatch: pytest.MonkeyPatch) -> None:
    """Two IMUs with a step, a ramp, a stuck output and a dropout: the monitor with the C step (its common
    epochs in live_fdi_step) and without it (every epoch in Python, the monitor before live.c) raise the same
    events and exclude the same sensors; the fused increments agree to rounding (summation order)."""
    s = _series(3000, 5)
    g = s.gyro
    g[600:, 1] += 0.05 * s.dt  # a gyro step bias (rad/s)
    s.accel[1500:, 4] += np.arange(len(s.t) - 1500) * 1e-3 * s.dt * s.dt  # an accelerometer ramp
    g[2200:2260, 5] = g[2200, 5]  # a stuck gyro for 0.3 s
    g[2500:2502, 3] = math.nan  # a frame lost on its link (bridged)
    with_c = fdi_monitor.FdiMonitor(_config(s.geometry))
    assert with_c.gyro._c_ok and with_c.accel._c_ok
    monkeypatch.setattr(fdi_monitor, "_lib", None)
    monkeypatch.setattr(fdi_monitor, "_ffi", None)
    py = fdi_monitor.FdiMonitor(_config(s.geometry))
    assert not py.gyro._c_ok
    monkeypatch.undo()
    calls = {"c": 0}
    step = fdi_monitor._Group.step

    def counted(self: Any, *a: Any) -> Any:
        if self is with_c.gyro or self is with_c.accel:
            calls["c"] += 1
        return step(self, *a)

    monkeypatch.setattr(fdi_monitor._Group, "step", counted)
    mark: dict[int, int] = {}
    for k in range(len(s.t)):
        if k in (600, 1000, 1500):
            mark[k] = calls["c"]
        a = with_c.process(s.epoch(k))[0]
        b = py.process(s.epoch(k))[0]
        for x, y in ((a.dtheta, b.dtheta), (a.dvel, b.dvel)):  # to rounding of the vector's size
            assert np.max(np.abs(x - y)) <= 1e-13 * np.max(np.abs(y)), k
    key = [(e.t, e.sensor, e.mode, e.isolated, e.cleared) for e in py.events]
    assert len(key) >= 3 and [(e.t, e.sensor, e.mode, e.isolated, e.cleared) for e in with_c.events] == key
    assert with_c.excluded == py.excluded
    assert with_c.events[0].t < 1000 * s.dt  # the gyro step isolated (its row excluded) before epoch 1000
    # in C: the healthy epochs, and those with the faulty gyro row excluded (its residual watched in Python);
    # the Python step around the faults only
    assert mark[600] == 0 and mark[1500] == mark[1000]


def test_c_core_keeps_publishing_across_a_roll_back_to_its_first_step() -> None:
    """CNavCore.step_begin (the live path) with delayed fusion: a measurement older than the first steps rolls the
    core back to the snapshot of its first step; the state it publishes after that is still written (before: the
    first step's snapshot had no publication buffer, the roll-back took it away and the next step_begin read
    through a NULL pointer)."""
    from ins_hil.core_parts.config import NavConfig
    from ins_hil.cref import CNavCore
    from ins_hil.nav.mechanization import StrapdownState
    from ins_hil.nav.rotation import quat_from_euler
    from ins_hil.types import BaroSample, ImuSample

    init = StrapdownState(quat_from_euler(0.0, 0.0, 0.3), np.array((5.0, 0.0, 0.0)), 0.87, 0.52, 100.0, 0.0)
    core = CNavCore(init, NavConfig())
    assert core._hist is not None  # delayed fusion by roll-back (the default)
    rng = np.random.default_rng(0)
    states = []
    for k in range(1, 40):
        imu = ImuSample(t=k * 1e-3, dt=1e-3, dtheta=rng.normal(0, 1e-5, 3),
                        dvel=np.array((0.0, 0.0, -9.81e-3)) + rng.normal(0, 1e-4, 3))  # fmt: skip
        states.append(core.step_begin(imu))
        assert core._core.pub == core._pub, k  # every step, the first included, publishes
        if k == 20:
            # valid before the second step: back to the first step's snapshot
            core.fuse(BaroSample(t=0.5e-3, pressure=math.nan, altitude=100.2))
    assert all(math.isfinite(st.lat) and abs(st.t - (k + 1) * 1e-3) < 1e-12 for k, st in enumerate(states))


def test_one_read_of_two_imus_runs_the_core_once_with_the_same_result() -> None:
    """The serial driver hands the samples of one read to the gateway in one call (its sink's ``many``): the
    soak's gateway (2 IMUs on one link, FDI, C core) sends the same bytes, makes the same states and counts as
    with one sink call per sample, also with a FIFO of one sample (nothing dropped: it is drained first)."""
    from ins_hil.soak import live_path

    ns = live_path._namespace("c", 1000.0, 2, 3.0, 7)
    ns.warmup, ns.chunk_s = 0.0, 3.0
    one = live_path.drive(ns, batch=False)
    many = live_path.drive(ns)
    assert one["digest"] == many["digest"] and one["counts"] == many["counts"]
    assert many["received"] == one["received"] == 2 * 3000 and many["dropped"] == one["dropped"] == 0
    assert many["sent"]["ODOMETRY"] > 100
    # the two samples of a read in one pipeline call (Pipeline.imu_pair) with the FDI isolating faults: the same
    ns.faults, ns.duration, ns.chunk_s = "auto", 12.0, 12.0
    one = live_path.drive(ns, batch=False)
    many = live_path.drive(ns)
    assert one["digest"] == many["digest"] and one["counts"] == many["counts"] and many["fdi_events"] >= 2

    from ins_hil.drivers.serial_frame import encode
    from ins_hil.drivers.serial_imu import SerialImuDriver

    from ins_hil.types import ImuSample

    gw, _, _ = live_path.build(ns)
    gw.queue_size = 1
    sink = gw._sink_for("imu0")
    assert hasattr(sink, "many")
    data = b"".join(encode(ImuSample(0.001, 0.001, np.zeros(3), np.zeros(3), imu_id=u)) for u in range(2))
    SerialImuDriver("/dev/null", name="imu0").feed(data, sink, 1_000_000)
    src = gw.metrics.source("imu0")
    assert src.received == 2 and gw.metrics.dropped_total() == 0 and not gw.queue


def test_live_path_counts_instructions_of_the_same_run(monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """``live_path --instructions`` counts the run of ``--mark`` (the simulator's samples made first, the counted
    window between two getppid calls): the same states and bytes as the timed run; without valgrind, one line."""
    import json as _json
    import os
    import shutil

    from ins_hil.soak import live_path

    ns = live_path._namespace("c", 1000.0, 2, 2.0, 7)
    ns.warmup = 1.0
    calls: list[int] = []
    marked = live_path.drive(ns, mark=lambda: calls.append(os.getppid()))
    assert len(calls) == 2 and marked["digest"] == live_path.drive(ns)["digest"] and marked["epochs"] == 1001
    import gc

    try:
        assert live_path.main(["--mark", "--seconds", "2", "--warmup", "1"]) == 0
        assert _json.loads(capsys.readouterr().out.strip().splitlines()[-1])["digest"] == marked["digest"]
        monkeypatch.setattr(shutil, "which", lambda _: None)
        assert live_path.main(["--instructions", "--seconds", "2", "--warmup", "1"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == ["live_path --instructions: valgrind not found (apt-get install valgrind)"]
        assert live_path.main(["--instructions", "--seconds", "2", "--warmup", "2"]) == 2  # no counted window
        err = capsys.readouterr().err.strip().splitlines()
        assert err == ["live_path: --warmup must be >= 0 and below --seconds (the counted window)"]
    finally:
        gc.unfreeze()  # main() froze what this process holds
