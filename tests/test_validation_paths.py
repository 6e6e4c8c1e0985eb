"""Every live path goes through the validation boundary (ins_hil.validation), provably.

- Behaviour: an IMU sample beyond the configured sensor range, made by each real driver from its wire format
  (serial frame, DroneCAN RawIMU, DBC frames, MAVLink HIGHRES_IMU), goes through the gateway's sink and queue
  into the pipeline: it is refused and counted (``reject_imu_*``), it never reaches the core, and nothing of it
  is kept (the host↔sensor clock that maps the aiding times is fed only samples past the boundary).
- Structure: the pipeline's only entries for samples (``imu``, ``aid``) call the validator before anything
  else; the core is stepped and fused only from code those entries reach; the gateway hands every sample to
  one of them; no runtime module steps or fuses a core itself.
"""

from __future__ import annotations

import ast
import asyncio
import inspect
import math
import textwrap
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
from ins_hil.drivers import dronecan_codec as dc
from ins_hil.drivers import serial_frame as sf
from ins_hil.drivers.can_imu import CanImuDriver
from ins_hil.drivers.dbc_codec import DbcProfile, encode_imu_frames
from ins_hil.drivers.mavlink_in import MavlinkDriver
from ins_hil.drivers.serial_imu import SerialImuDriver
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from runtime_helpers import sim_config

from ins_hil.runtime import pipeline as pipeline_mod
from ins_hil.runtime.loop import Gateway
from ins_hil.types import FixType, GnssFix, ImuSample

G = 9.80665
ROOT = Path(__file__).resolve().parent.parent
W_BAD = 10.0  # rad/s: beyond the configured 250 °/s × 1.5 = 6.5 rad/s, within every decoder's own bounds


def _gateway(**core: Any) -> Gateway:
    cfg = sim_config(
        sim={"enabled": False},
        inputs=[{"name": "imu0", "type": "serial_imu", "port": "/dev/ins-hil-no-such-tty"}],
        recorder={"enabled": False},
        core={"init": "config", "init_lat_deg": 50.0, "init_lon_deg": 30.0, "init_h": 100.0, **core},
    )
    return Gateway(cfg)


class CoreSpy:
    """Records every IMU sample that reaches the core (wraps ``step_begin`` of the pipeline's core)."""

    def __init__(self, gw: Gateway) -> None:
        self.seen: list[ImuSample] = []
        core = gw.pipeline.core
        assert core is not None
        inner = core.step_begin

        def step_begin(s: ImuSample) -> Any:
            self.seen.append(s)
            return inner(s)

        core.step_begin = step_begin  # type: ignore[method-assign]


def _serial(gw: Gateway, sink: Any) -> None:
    drv = SerialImuDriver("/dev/ins-hil-no-such-tty")
    for k in range(1, 41):
        w = W_BAD if k == 30 else 0.01
        s = ImuSample(t=1.0 + k * 0.005, dt=0.005, dtheta=np.array((w * 0.005, 0.0, 0.0)),
                      dvel=np.array((0.0, 0.0, -G * 0.005)), seq=k)  # fmt: skip
        drv.feed(sf.encode(s), sink, 10**9 + k * 5_000_000)


def _dronecan(gw: Gateway, sink: Any, dvel: float = 0.0, w: float = W_BAD) -> None:
    drv = CanImuDriver({"interface": "virtual"}, protocol="dronecan", node_id=None)
    for k in range(1, 41):
        bad = k == 30
        s = ImuSample(t=1.0 + k * 0.005, dt=0.005, dtheta=np.array(((w if bad else 0.01) * 0.005, 0.0, 0.0)),
                      dvel=np.array((dvel if bad else 0.0, 0.0, -G * 0.005)))  # fmt: skip
        cid = dc.message_can_id(dc.DTID_RAW_IMU, 10)
        for d in dc.split_transfer(dc.DTID_RAW_IMU, dc.raw_imu_payload(s), k):
            drv.handle(can.Message(arbitration_id=cid, data=d, is_extended_id=True), sink, 10**9 + k * 5_000_000)


def _dbc(gw: Gateway, sink: Any) -> None:
    drv = CanImuDriver({"interface": "virtual"}, protocol="dbc", node_id=None, dbc=DbcProfile())
    assert drv.dbc is not None
    for k in range(1, 41):
        gyro = (W_BAD if k == 30 else 0.01, 0.0, 0.0)
        for cid, d in encode_imu_frames(drv.dbc.db, gyro, (0.0, 0.0, -G), k):
            drv.handle(can.Message(arbitration_id=cid, data=d, is_extended_id=False), sink, 10**9 + k * 5_000_000)


def _mavlink(gw: Gateway, sink: Any) -> None:
    drv = MavlinkDriver("udpin:127.0.0.1:0", emit={"imu"}, imu_dt=0.005)
    drv._sink = sink
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    for k in range(1, 41):
        w = W_BAD if k == 30 else 0.01
        m = mav.highres_imu_encode(1_000_000 + k * 5000, 0.0, 0.0, -G, w, 0.0, 0.0, 0, 0, 0, 0, 0, 0, 20.0, 0x3F)
        drv.feed(m.pack(mav), now_ns=10**9 + k * 5_000_000)
        mav.seq = (mav.seq + 1) % 256


DRIVERS = {"serial": _serial, "dronecan": _dronecan, "dbc": _dbc, "mavlink": _mavlink}


@pytest.mark.parametrize("kind", list(DRIVERS))
def test_an_out_of_range_sample_from_each_driver_is_refused_counted_and_never_reaches_the_core(kind: str) -> None:
    async def run() -> None:
        gw = _gateway(gyro_range_dps=250.0)
        spy = CoreSpy(gw)
        sink = gw._sink_for("imu0")
        DRIVERS[kind](gw, sink)
        gw._process_queue()
        p = gw.pipeline
        assert p.counts.get("reject_imu_rate") == 1, p.counts
        assert len(spy.seen) >= 35  # the others navigate
        assert all(abs(float(s.dtheta[0])) / s.dt < 1.0 for s in spy.seen)  # the 10 rad/s sample never did

    asyncio.run(run())


def test_a_physically_impossible_dronecan_rawimu_is_refused_by_the_validation_boundary() -> None:
    """dvel 50 m/s in 5 ms (1,000 g: the DroneCAN decoder's per-interval bound lets it through) is refused
    by the default validation ranges at the pipeline's entry and counted; it never reaches the core."""

    async def run() -> None:
        gw = _gateway()
        spy = CoreSpy(gw)
        _dronecan(gw, gw._sink_for("imu0"), dvel=50.0, w=0.01)
        gw._process_queue()
        assert gw.pipeline.counts.get("reject_imu_accel") == 1, gw.pipeline.counts
        assert len(spy.seen) >= 35 and all(abs(float(s.dvel[0])) < 1.0 for s in spy.seen)

    asyncio.run(run())


def test_a_refused_sample_leaves_no_trace_in_the_aiding_time_map() -> None:
    """A sample refused at the boundary (here non-finite, with a time 10^6 s ahead, as a third-party driver
    could deliver it) must not move the host↔sensor offset that maps the aiding times: before, it did, and
    every later GNSS fix was held for a time the IMU would not reach (never fused)."""

    async def run() -> None:
        gw = _gateway()
        sink = gw._sink_for("imu0")
        arrival = 10**9
        for k in range(1, 201):
            t = 1.0 + k * 0.005
            if k == 100:
                sink(ImuSample(t=t + 1e6, dt=0.005, dtheta=np.array((math.nan, 0.0, 0.0)), dvel=np.zeros(3),
                               t_arrival_ns=arrival + k * 5_000_000))  # fmt: skip
            sink(ImuSample(t=t, dt=0.005, dtheta=np.zeros(3), dvel=np.array((0.0, 0.0, -G * 0.005)),
                           t_arrival_ns=arrival + k * 5_000_000))  # fmt: skip
            if k % 20 == 0 and k > 100:  # GNSS on the host clock, as the MAVLink driver delivers it
                sink(GnssFix(t=(arrival + k * 5_000_000) * 1e-9, lat=math.radians(50.0), lon=math.radians(30.0),
                             h=100.0, vel_ned=np.zeros(3), fix_type=FixType.FIX_3D))  # fmt: skip
            gw._process_queue()
        gw.pipeline.flush()
        c = gw.pipeline.counts
        assert c.get("reject_imu_nonfinite") == 1
        assert c.get("fused_GnssFix", 0) == 5, c

    asyncio.run(run())


def test_decode_refuses_what_the_stream_parser_refuses() -> None:
    """``serial_frame.decode`` returned dθ = 3.4e38 (the stream parser dropped the same frame as ``range``)."""
    bad = sf.encode(ImuSample(t=1.0, dt=0.001, dtheta=np.array((3.4e38, 0.0, 0.0)), dvel=np.zeros(3)))
    with pytest.raises(sf.FrameError) as e:
        sf.decode(bad)
    assert e.value.reason == "range"
    p = sf.FrameParser()
    assert p.feed(bad, 10**9) == [] and p.counts["range"] == 1
    good = ImuSample(t=1.0, dt=0.001, dtheta=np.array((0.9, 0.0, 0.0)), dvel=np.array((0.0, 0.0, 49.0)))
    assert sf.decode(sf.encode(good)).dtheta[0] == pytest.approx(0.9)


# ---------------------------------------------------------------- structure
def _method(cls: type, name: str) -> ast.FunctionDef:
    node = ast.parse(textwrap.dedent(inspect.getsource(getattr(cls, name)))).body[0]
    assert isinstance(node, ast.FunctionDef)
    return node


def _calls(fn: ast.AST) -> set[str]:
    """Names of the attributes called in ``fn`` (``self.x(...)``, ``core.y(...)`` → x, y)."""
    return {n.func.attr for n in ast.walk(fn) if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)}


def test_the_pipeline_entries_validate_first_and_only_they_reach_the_core() -> None:
    P = pipeline_mod.Pipeline
    # imu/aid: the validator runs before any other statement that uses the sample (imu: in _admit, first)
    admit = _method(P, "_admit")
    first_use = [st for st in admit.body if not isinstance(st, ast.Expr)]  # skip the docstring
    val = next(i for i, st in enumerate(first_use) if "_val_imu" in ast.unparse(st))
    assert all("core" not in ast.unparse(st) and "_epoch" not in ast.unparse(st) for st in first_use[:val])
    assert not _calls(admit) & {"_take", "_group", "_epoch"}
    imu = [st for st in _method(P, "imu").body if not isinstance(st, ast.Expr)]
    assert ast.unparse(imu[0]) == "a = self._admit(s)"
    # imu_pair (two samples of one read): each through _admit before anything else takes it; only what
    # _admit returned (a2, b2) goes on
    pair = _method(P, "imu_pair")
    body = [st for st in pair.body if not isinstance(st, ast.Expr)]
    assert ast.unparse(body[0]) == "a2 = self._admit(a)"
    src = ast.unparse(pair)
    assert src.index("b2 = self._admit(b)") < min(src.index("self._epoch("), src.index("self._take(a2)"))
    for bad in ("_take(a)", "_take(b)", "_epoch([a,", "_epoch([b,", "_group("):
        assert bad not in src, bad
    aid = _method(P, "aid")
    body = [st for st in aid.body if not isinstance(st, ast.Expr)]
    assert "self.validator.check(m)" in ast.unparse(body[0])
    assert ast.unparse(body[1]).startswith("if why is not None:") and "return" in ast.unparse(body[1])
    # the core is stepped / fused only in methods reachable from imu/aid (and work/flush, which take no sample)
    feeders = {"step", "step_begin", "fuse", "fuse_steps", "fuse_now"}
    methods = {n: _method(P, n) for n, f in vars(P).items() if inspect.isfunction(f)}
    graph = {n: _calls(m) & set(methods) for n, m in methods.items()}
    touching = {n for n, m in methods.items() if _calls(m) & feeders}
    assert touching == {"_epoch", "_fuse"}, touching
    reach: dict[str, set[str]] = {}
    for root in methods:
        seen, todo = set(), [root]
        while todo:
            for c in graph[todo.pop()] - seen:
                seen.add(c)
                todo.append(c)
        reach[root] = seen
    public = {n for n in methods if not n.startswith("_")}
    entries = {n for n in public if reach[n] & touching or n in touching}
    assert entries <= {"imu", "imu_pair", "aid", "imu_run", "baro_runs", "work", "flush"}, entries
    # baro_runs (an offline replay's screened stretch of baro samples on C): the screen was the boundary; the
    # pipeline's validator confirms the first IMU sample is after its last checked time before the C call
    br = ast.unparse(_method(P, "baro_runs"))
    assert "self.validator.imu_screened(iid, imu[k0].t)" in br
    assert br.index("self.validator.imu_screened(iid, imu[k0].t)") < br.index("core.run_baro(")
    # imu_run (an offline replay's IMU samples up to the next aid): each sample through the validator before the
    # batched C path takes it; every other sample through imu()
    run = ast.unparse(_method(P, "imu_run"))
    assert "val(s) is not None" in run and run.index("val(s) is not None") < run.index("self._epochs_c(")
    assert "val, t_prev = (self._val_imu, self._t_imu)" in run
    for n in ("work", "flush"):  # they run queued work only: no sample comes in
        assert [a.arg for a in methods[n].args.args] == ["self"]


def test_the_gateway_hands_every_sample_to_a_pipeline_entry_and_nothing_else_feeds_a_core() -> None:
    src = inspect.getsource(Gateway._process_queue)
    assert "pipe.imu(s)" in src and "pipe.aid(s)" in src
    tree = ast.parse(textwrap.dedent(src))
    branch = next(n for n in ast.walk(tree) if isinstance(n, ast.If) and ast.unparse(n.test) == "s.kind == 'imu'")
    body = ast.unparse(ast.Module(branch.body, []))
    assert "pipe.imu(s)" in body and "pipe.imu_pair(first, s)" in body  # an IMU sample: the pipeline's IMU entries
    assert "pipe.aid(s)" in ast.unparse(ast.Module(branch.orelse, []))  # anything else: its aiding entry
    # no runtime module but the pipeline steps or fuses a core, or reaches into the pipeline's core
    for f in sorted((ROOT / "ins_hil" / "runtime").glob("*.py")):
        if f.name == "pipeline.py":
            continue
        text = f.read_text()
        for bad in (".step_begin(", ".fuse_steps(", "core.step(", "core.fuse(", "pipeline.core.", "pipe.core."):
            assert bad not in text, f"{f.name}: {bad}"
