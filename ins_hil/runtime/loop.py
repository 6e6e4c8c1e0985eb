"""The real-time gateway: driver tasks → bounded queue → pipeline (one task) → publishers.

Drivers call a per-source ``sink`` (non-blocking): the sample goes into one
bounded FIFO (arrival order); when it is full the sample is dropped and
counted (``queue_full``) — never silently. The core (run by the sink that put a
sample into the empty FIFO, in the driver's callback: no extra turn of the event
loop between the bytes read and the state) drains the FIFO and
calls the synchronous :class:`~ins_hil.runtime.pipeline.Pipeline` on every
sample (nothing on this path awaits I/O), hands the state to every publisher
(the MAVLink messages that are due go out right there; each publisher measures
state ready → sent) and measures arrival → state ready. In the slack, a callback
after the samples at hand: the samples go to the recorder (in-memory buffer,
flushed by a 50 ms task) in the order the pipeline got them, the rest of the step
and the aiding fusion's segments run.

A sample is *late* when its arrival → state latency exceeds
``gateway.late_threshold_ms``; the loop warns (at most once a second) with
the late count and the queue depth. Memory is bounded by the queue size.

Stop: :meth:`Gateway.request_stop` (SIGINT/SIGTERM) ends the run cleanly,
flushing the recorder and closing every transport; a second SIGINT exits at
once (``os._exit(130)``).
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import os
import signal
import socket
import time
from collections import deque
from collections.abc import Callable, Iterable
from functools import partial
from pathlib import Path
from typing import Any, Protocol

from ins_hil.aids import decoders as aid_decoders
from ins_hil.drivers.base import Sample
from ins_hil.drivers.factory import make_driver
from ins_hil.runtime.clock import SensorClock
from ins_hil.runtime.mavlink_out import EndpointConfig, MavlinkEndpoint, fault_text
from ins_hil.runtime.mavlink_params import ParamStore
from ins_hil.runtime.metrics import RuntimeMetrics
from ins_hil.runtime.mqtt_out import MqttPublisher
from ins_hil.runtime.pipeline import Pipeline
from ins_hil.runtime.recorder import Recorder
from ins_hil.runtime.rt import enter_realtime, policy
from ins_hil.types import FaultEvent, NavState


class Devices(Protocol):
    """Sensor devices the gateway hosts for one run (``[sim] enabled``: the simulator,
    :class:`ins_hil.sim.devices.SimDevices`). Started once the MAVLink input listens, before the
    serial inputs open ``imu_path`` (the device behind ``port = "sim"``); stopped first at shutdown."""

    imu_path: str

    def start(self) -> object: ...

    def stop(self) -> None: ...


DevicesFactory = Callable[[tuple[str, int]], Devices]
"""Builds the devices for the address (host, UDP port) the gateway's MAVLink input listens on."""


class Gateway:
    """One gateway run built from a validated :class:`~ins_hil.config.Config`.

    ``metrics`` is the live :class:`RuntimeMetrics` (status view, MQTT health,
    soak test); ``on_state`` callbacks get every state (tests, tools). ``devices`` builds the
    sensor devices of a ``[sim] enabled`` config, which needs it (every caller passes the simulator's,
    ``functools.partial(SimDevices, cfg.sim)``): the runtime never imports the simulator. Every input's
    driver comes from the one registry, ``ins_hil.drivers.factory.make_driver``. ``outputs``: the MAVLink
    outputs already open and sending HEARTBEAT (:func:`open_outputs`), taken over instead of opened here.
    """

    def __init__(
        self,
        cfg: Any,  # an ins_hil.config.Config (the layer above: the runtime does not import it)
        record_path: str | Path | None = None,
        devices: DevicesFactory | None = None,
        outputs: OpenOutputs | None = None,
    ) -> None:
        self.params = ParamStore(cfg)  # MAVLink parameters; the override file (<config>.params.toml) applied
        self.cfg = cfg = self.params.cfg
        self.metrics = outputs.metrics if outputs is not None else RuntimeMetrics()
        self.metrics.late_threshold_ns = int(cfg.gateway.late_threshold_ms * 1e-3 * 1e9)
        self.metrics.expect_inputs([(i.name, i.type) for i in cfg.inputs])  # SYS_STATUS sensor bits
        self.pipeline = Pipeline(cfg.pipeline)  # may raise: before anything starts
        self.on_state: list[Callable[[NavState], None]] = []
        self.on_fault: list[Callable[[FaultEvent], None]] = []
        self.queue: deque[tuple[Sample, str]] = deque()
        self.queue_size = cfg.gateway.queue_size
        self._scheduled = False  # _run_queue is running (a sink called meanwhile only appends to the FIFO)
        self._slack_scheduled = False  # _slack (the aiding segment of the gap) is scheduled on the event loop
        self._unrecorded: list[Sample] = []  # processed samples not handed to the recorder yet (_record, in the slack)
        self._stop = asyncio.Event()
        self.drivers: list[Any] = []
        self._opened: list[MavlinkEndpoint] = outputs.take(cfg.outputs) if outputs is not None else []
        self.mav_outputs = self._opened or [MavlinkEndpoint(e, self.metrics) for e in cfg.outputs]
        self.params.attach(self.mav_outputs, self.pipeline)
        self.mqtt = MqttPublisher(cfg.mqtt, self.metrics) if cfg.mqtt.enabled else None
        self.publishers: list[Any] = [*self.mav_outputs, *([self.mqtt] if self.mqtt else [])]
        self.sim: Devices | None = None
        self._devices = devices
        self.recorder: Recorder | None = None
        self.record_path = Path(record_path) if record_path else None
        self._tasks: list[asyncio.Task[Any]] = []
        self._sigints = 0
        self._was_aligned = False
        self.imu_clock = SensorClock()
        self.stopped_reason = ""
        self.error: BaseException | None = None
        self._current = ""  # source of the sample being processed (pipeline_error counts)
        self._err_warned = -1e9  # monotonic time (s) of the last pipeline-error warning

    # -- sinks (called by drivers, never block) ------------------------------------
    def _sink_for(self, name: str) -> Callable[[Sample], None]:
        stats = self.metrics.source(name)
        q = self.queue
        cap = self.queue_size
        run = self._run_queue

        def sink(s: Sample) -> None:
            stats.received += 1
            if len(q) >= cap:
                stats.drop("queue_full")
                return
            q.append((s, name))
            if not self._scheduled:  # not inside the core already (it drains the FIFO): run it now
                run()

        def many(samples: Iterable[Sample]) -> None:
            """Several samples of one read (e.g. redundant IMUs' frames on one link), in order, taken one at a
            time (a driver's iterator: what is not taken yet when this raises is still the driver's): the core
            runs once for all of them (the pipeline gets them in the same order as one sink call each)."""
            for s in samples:
                stats.received += 1
                if len(q) >= cap and not self._scheduled:
                    run()  # the FIFO full with this read's samples: drained first, as one sink call each would
                if len(q) >= cap:
                    stats.drop("queue_full")
                    continue
                q.append((s, name))
            if q and not self._scheduled:
                run()

        sink.many = many  # type: ignore[attr-defined]
        return sink

    # -- the core callback ---------------------------------------------------------
    def _run_queue(self) -> None:
        """The core, run by the sink of the sample put into an empty FIFO, in the driver's callback (on the
        event loop's thread: every driver delivers there), so a sample reaches the pipeline and its state the
        publishers without waiting for another turn of the event loop. An exception (the pipeline catches the
        core's own) does not stop the gateway: the sample is counted as ``pipeline_error`` under its source, a
        warning is given at most once a second, and the rest of the FIFO is processed. The aiding segment of
        the gap (:meth:`Pipeline.work`) runs in the slack, a callback scheduled once the FIFO is empty."""
        if self.error is not None:
            return
        self._scheduled = True
        try:
            while True:
                try:
                    self._process_queue()
                    break
                except Exception as e:
                    self._pipeline_error(e)
                    if not self.queue:
                        break
        finally:
            self._scheduled = False
        if not self._slack_scheduled and (self._unrecorded or self.pipeline.has_work()):
            try:
                call_soon = asyncio.get_running_loop().call_soon
            except RuntimeError:  # no event loop (a tool driving the gateway's core directly): in the slack now
                self._slack()
                return
            self._slack_scheduled = True
            call_soon(self._slack)

    def _pipeline_error(self, e: Exception) -> None:
        self.metrics.source(self._current).drop("pipeline_error")
        now = time.monotonic()
        if now - self._err_warned >= 1.0:
            self._err_warned = now
            self.metrics.warn(f"pipeline error on a {self._current} sample: {type(e).__name__}: {e}")

    def _record(self) -> None:
        """Hand the samples processed since the last call to the recorder (its in-memory buffer), in order."""
        unrec = self._unrecorded
        if unrec and self.recorder is not None:
            w = self.recorder.write
            for s in unrec:
                w(s)
        unrec.clear()

    def _slack(self) -> None:
        """One aiding segment in the slack after the samples at hand (:meth:`Pipeline.work`: at most one per gap
        between IMU epochs), after the driver callbacks of this turn of the event loop, so that the other unit's
        sample of an epoch delivered in the same read is not kept waiting behind it."""
        self._slack_scheduled = False
        if self._scheduled:
            return
        self._record()
        if self.error is not None:
            return
        pipe = self.pipeline
        try:
            if pipe.work() and pipe.events:
                for ev in pipe.drain_events():
                    self._fault(ev)
        except Exception as e:
            self._pipeline_error(e)

    def _process_queue(self) -> None:
        """Run the pipeline on everything in the FIFO (synchronous: never awaits).

        Aiding measurements (GNSS, baro, magnetometer) are handed to the pipeline when dequeued (and
        queued for the recorder, which writes them in the slack in that order); the pipeline splits
        their fusion into segments, one per gap between IMU epochs (:meth:`Pipeline.work`; a GNSS
        update costs about a millisecond in the Python core). The segment of a gap runs in the slack
        (:meth:`_slack`) once the FIFO is empty after an IMU state has been published, so its cost
        falls before the next IMU sample instead of delaying it. The recorder writes every input in
        the order it is handed to the pipeline, so replay
        reproduces the same states."""
        q = self.queue
        pipe = self.pipeline
        rec = self.recorder
        unrec = self._unrecorded
        m = self.metrics
        pubs = self.publishers
        mono = time.monotonic_ns
        clock = self.imu_clock
        depth = len(q)
        if depth > m.queue_depth_max:
            m.queue_depth_max = depth
        pair = pipe.pair_ready
        while q:
            s, name = q.popleft()
            self._current = name
            if s.kind == "imu":
                t0 = mono()
                first = None
                if q and pair(s, q[0][0]):
                    # the two units' samples of one epoch (one read of a serial link) in one call, as one each
                    first = s
                    s, name = q.popleft()
                    self._current = name
                    t_first, st = pipe.imu_pair(first, s)
                else:
                    st = pipe.imu(s)
                ready = mono()
                if st is not None:
                    for p in pubs:  # first: the bookkeeping below is not on the latency path
                        p.offer(st, s.t_arrival_ns, ready)
                if first is not None:  # the first sample's, as after its own call
                    if t_first is not None:
                        clock.update(t_first, first.t_arrival_ns)
                    if rec is not None:
                        unrec.append(first)
                if pipe.imu_t is not None:  # only a sample past the validation boundary, at its (re-anchored) time
                    clock.update(pipe.imu_t, s.t_arrival_ns)
                if rec is not None:
                    unrec.append(s)  # recorded in the slack, in the order handed to the pipeline: replay order kept
                if st is None:
                    continue
                m.record_state(s.t_arrival_ns, ready, ready - t0)
                for cb in self.on_state:
                    cb(st)
                if st.aligned != self._was_aligned:
                    self._was_aligned = st.aligned
                    m.aligned = st.aligned
                    self._text(6 if st.aligned else 4, "INS aligned" if st.aligned else "INS alignment lost")
                if st.test_ratios:
                    m.test_ratios = st.test_ratios
            else:
                m.aid_seen(s)  # sensor health (SYS_STATUS), before any drop
                # aiding times arrive on the host monotonic clock (MAVLink driver, TIMESYNC): to the IMU clock
                t = clock.to_sensor(s.t)
                if t is None:
                    m.source(name).drop("before_imu_clock")
                    continue
                s.t = t
                if s.kind == "gnss":  # the MAVLink outputs forward the fixes (GPS_INPUT, GPS_RAW_INT)
                    for e in self.mav_outputs:
                        e.offer_gnss(s)
                if rec is not None:
                    unrec.append(s)
                pipe.aid(s)  # fused / excluded counts: the pipeline's, copied by the housekeeping task
            if pipe.events:
                for ev in pipe.drain_events():
                    self._fault(ev)

    def _text(self, severity: int, text: str) -> None:
        for e in self.mav_outputs:
            if e.cfg.role == "gcs":
                e.statustext(severity, text)

    def _fault(self, ev: FaultEvent) -> None:
        m = self.metrics
        m.faults += 1
        m.last_fault = f"{ev.sensor} {ev.mode.name}{' cleared' if ev.cleared else ''} at {ev.t:.2f} s"
        m.fdi_state = "ok" if ev.cleared else f"fault {ev.sensor}"
        sev, text = fault_text(ev)
        self._text(sev, text)
        if self.mqtt is not None:
            self.mqtt.offer_fault(ev)
        for cb in self.on_fault:
            cb(ev)

    # -- housekeeping ---------------------------------------------------------------
    async def _housekeeping(self) -> None:
        rec = self.recorder
        period = self.cfg.recorder.flush_period
        m = self.metrics
        last_roll = last_warn = time.monotonic()
        late_seen = 0
        while True:
            await asyncio.sleep(period)
            if rec is not None:
                self._record()
                rec.flush()
            now = time.monotonic()
            m.tick()
            # a source lost or back → STATUSTEXT, once per loss and once when back: SensorHealth's hysteresis
            # (an IMU gap is "IMU lost: no data" then "IMU back"; the core's alignment is kept, so no INS text)
            for sev, text in m.drain_sensor_events():
                self._text(sev, text)
            imu = m.sensors["imu"]
            m.aligned = self._was_aligned and not (imu.count and not imu.healthy)  # no IMU: no solution
            for d in self.drivers:
                m.source(d.name).driver_drops(d.health.errors)
            self._watch_errors()
            for k, v in self.pipeline.counts.items():
                m.fused[k] = v
            if now - last_roll >= 5.0:
                last_roll = now
                m.roll_window()
            if now - last_warn >= 1.0:
                last_warn = now
                self._core_warnings()
                if m.late > late_seen:
                    n_late = m.late - late_seen
                    m.warn(f"core behind: {n_late} late samples in the last second, queue {len(self.queue)}")
                    late_seen = m.late

    def _core_warnings(self) -> None:
        """The core's start-up check of the IMU (a wrong mounting, a noise preset far below the IMU:
        ``NavCore.sensor_warnings``) said once each: a warning (log, status view, MQTT health) and a STATUSTEXT."""
        core = getattr(self.pipeline, "core", None)
        for w in getattr(core, "sensor_warnings", None) or ():
            if w in self._core_said:
                continue
            self._core_said.add(w)
            self.metrics.warn(w)
            what = "mounting looks wrong" if w.startswith("mounting") else "noise above preset"
            self._text(4, f"IMU check: {what}")

    def _watch_errors(self) -> None:
        """Each input's and output's error text (a port that does not open, a lost link) reported once
        as a warning (log, status view, MQTT health) under its config path, e.g. ``inputs[0] (imu0): open
        /dev/ttyUSB0: ...``; ``problems`` holds those not yet resolved (the input delivered a sample since,
        the output's link is open), and a resolved one is logged as up."""
        m = self.metrics
        for d in self.drivers:
            path = self.input_paths.get(d.name, d.name)
            n = m.source(d.name).received
            self._watch(path, d.health.last_error, not d.health.connected, n > self._marks.get(path, n), n)
        for i, e in enumerate(self.mav_outputs):
            tr = e.tr
            text = getattr(tr, "last_error", "") or ("cannot open" if tr.errors.get("connect_failed") else "")
            self._watch(f"outputs[{i}] ({e.name})", text, not tr.connected, tr.connected, 0)

    def _input_warning(self, path: str, text: str) -> None:
        """A driver's one-time notice (e.g. the MAVLink input refusing a source) as a warning under its path."""
        self.metrics.warn(f"{path}: {text}")

    def _watch(self, path: str, text: str, down: bool, ok: bool, mark: int) -> None:
        """One source: its last error ``text``, ``down`` (not open now), ``ok`` (working since the report);
        ``mark``: what ``ok`` is measured from (an input's received count)."""
        if path in self.problems and ok:
            del self.problems[path]
            self._reported[path] = ""
            self.log.info("%s: up", path)
        elif text and down and text != self._reported.get(path):  # a new error, or the same one again after up
            self._reported[path] = self.problems[path] = text
            self._marks[path] = mark
            self.metrics.warn(f"{path}: {text}")

    # -- start / stop ------------------------------------------------------------------
    def request_stop(self, reason: str = "stop") -> None:
        self.stopped_reason = self.stopped_reason or reason
        self._stop.set()

    def _on_sigint(self) -> None:
        self._sigints += 1
        if self._sigints >= 2:
            os._exit(130)
        self.request_stop("SIGINT")

    async def _start(self) -> None:
        cfg = self.cfg
        self.input_paths = {ic.name: f"inputs[{i}] ({ic.name})" for i, ic in enumerate(cfg.inputs)}
        self.problems: dict[str, str] = {}  # config path → error text not yet resolved (status view)
        self._reported: dict[str, str] = {}
        self._marks: dict[str, int] = {}  # an input's received count when its error was reported
        self._core_said: set[str] = set()  # the core's start-up check warnings already said (_core_warnings)
        import logging

        self.log = logging.getLogger("ins_hil")
        if cfg.recorder.enabled:
            path = self.record_path
            if path is None:
                stamp = time.strftime("%Y%m%d-%H%M%S")
                path = Path(cfg.recorder.dir) / f"ins-hil-{stamp}.ihlog"
            self.recorder = Recorder(
                path,
                header={
                    "config": _redact(cfg.to_dict()),
                    "pipeline": cfg.to_dict()["pipeline"],
                    "started": time.time(),
                },
                max_bytes=int(cfg.recorder.max_mb * 1024 * 1024),
                flush_period=cfg.recorder.flush_period,
                max_total_bytes=int(cfg.recorder.total_mb * 1024 * 1024),
                dir_max_bytes=int(cfg.recorder.dir_total_mb * 1024 * 1024),
                on_message=self.metrics.warn,
            )
        for i, p in enumerate(self.publishers):
            if p not in self._opened:  # (those opened by open_outputs send already)
                await _start_output(i, p)
        sim_gnss_port = 0
        later = []
        for ic in cfg.inputs:  # MAVLink inputs first: the simulator sends to the port the first one listens on
            if ic.type != "mavlink":
                later.append(ic)
                continue
            table = {**ic.driver_table(cfg), "url": _pin_port(ic.url),
                     "request": {} if cfg.sim_enabled else None}  # fmt: skip
            drv: Any = make_driver(table)  # a MavlinkDriver: local_address
            drv.on_warn = partial(self._input_warning, self.input_paths[ic.name])  # refused sources, said once
            self._add_driver(drv, ic.name)
            for _ in range(100):  # until the socket is bound (port 0 = any free port)
                if drv.local_address is not None:
                    break
                await asyncio.sleep(0.01)
            if drv.local_address is None:
                raise RuntimeError(f"{self.input_paths[ic.name]}: cannot open {ic.url}: {drv.health.last_error}")
            if not sim_gnss_port:
                sim_gnss_port = int(drv.local_address[1])
        if cfg.sim_enabled:
            if not sim_gnss_port:
                raise RuntimeError("[sim] needs a mavlink input for its GNSS/baro")
            if self._devices is None:
                raise RuntimeError("[sim] enabled: the gateway needs the simulator, Gateway(cfg, devices=...)")
            self.sim = self._devices(("127.0.0.1", sim_gnss_port))
            await asyncio.get_running_loop().run_in_executor(None, self.sim.start)
        for ic in later:
            table = ic.driver_table()
            if ic.type == "serial_imu" and ic.port == "sim" and self.sim is not None:
                table["port"] = self.sim.imu_path
            self._add_driver(make_driver(table), ic.name)
        if cfg.gateway.rt_priority:
            why = enter_realtime(cfg.gateway.rt_priority)
            if why:
                self.metrics.warn(f"gateway.rt_priority: {why}")
        self.metrics.scheduling = policy()
        self._announce()
        # everything allocated so far (modules, pymavlink tables, the core) lives for the whole run:
        # move it out of the collector's generations so a full collection does not scan it on the IMU path
        gc.collect()
        gc.freeze()
        t = asyncio.create_task(self._housekeeping(), name="housekeeping")
        t.add_done_callback(self._task_done)
        self._tasks.append(t)

    def _add_driver(self, drv: Any, name: str) -> None:
        proto = getattr(drv, "decoder_protocol", None)  # the aids' decoders of this driver's messages
        if proto:
            drv.set_decoders(aid_decoders(proto, self.cfg.pipeline.nav))
        self.drivers.append(drv)
        self._tasks.append(asyncio.create_task(drv.run(self._sink_for(name)), name=name))

    def _announce(self) -> None:
        """Log where everything goes: inputs, each MAVLink output's URL and role, MQTT, the recording."""
        log = self.log
        drivers = {d.name: d for d in self.drivers}
        for ic in self.cfg.inputs:
            url = getattr(drivers.get(ic.name), "url", ic.url)  # udpin:HOST:0 pinned to the port it listens on
            where = {"mavlink": url, "can_imu": str(ic.options.get("channel", ""))}.get(ic.type, ic.port)
            if where == "sim" and self.sim is not None:
                where = f"the simulator's pty {self.sim.imu_path}"
            log.info("%s: %s %s", self.input_paths[ic.name], ic.type, where)
        for i, e in enumerate(self.mav_outputs):
            c = e.cfg
            signed = ", signed" if c.signing_key or c.signing_key_file else ""
            log.info("MAVLink outputs[%d] (%s): %s, role %s, sysid %d%s", i, c.name, c.url, c.role, c.sysid, signed)
            if c.exposed():  # docs/flight_controller.md, "Securing the gateway"
                log.warning("MAVLink outputs[%d] (%s) listens on %s for the whole network, unsigned: sign it "
                            "(ins-hil keygen, signing_key_file) or listen on 127.0.0.1", i, c.name, c.url)  # fmt: skip
        if not self.mav_outputs:
            log.info("MAVLink: no outputs")
        if self.params.loaded:  # values a MAV_CMD_PREFLIGHT_STORAGE saved: never in force silently
            log.warning("%s", self.params.announcement())
        mq = self.cfg.mqtt
        if self.mqtt is not None:
            tls = " (TLS)" if mq.tls else ""
            link = "connected" if self.mqtt.connected else "offline, retrying" if self.mqtt.last_error else "connecting"
            log.info("mqtt: broker %s:%d%s, topics %s/...: %s", mq.host, mq.port, tls, mq.topic_prefix, link)
        else:
            log.info("mqtt: off")
        rec = self.recorder
        log.info("recording to %s", rec.paths[0] if rec is not None and rec.paths else "nowhere (recorder off)")

    def _task_done(self, t: asyncio.Task[Any]) -> None:
        if t.cancelled():
            return
        exc = t.exception()
        if exc is not None:
            self.error = exc
            self.request_stop(f"{t.get_name()} task failed: {type(exc).__name__}: {exc}")

    async def _shutdown(self) -> None:
        if self.sim is not None:
            self.sim.stop()
        # inputs first, then what they already delivered goes through the pipeline (and the recorder)
        for t in self._tasks:
            if t.get_name() in {d.name for d in self.drivers}:
                t.cancel()
        for t in self._tasks:
            if t.get_name() in {d.name for d in self.drivers}:
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await t
        if self.error is None and self.queue:
            self._run_queue()
        if self.error is None:
            self.pipeline.flush()  # what was handed over is fused (replay flushes at its end too)
            for ev in self.pipeline.drain_events():
                self._fault(ev)
        for t in self._tasks:
            t.cancel()
        for t in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await t
        self._tasks.clear()
        for p in self.publishers:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(p.close(), 10.0)
        if self.recorder is not None:
            self._record()
            self.recorder.close()
        gc.unfreeze()  # a process that runs several gateways (tests) gets its objects collectable again

    async def run(
        self,
        duration: float | None = None,
        signals: bool = True,
        status: Callable[[Gateway], Any] | None = None,
    ) -> RuntimeMetrics:
        """Run until ``duration`` (s), a stop request or a signal; returns the metrics."""
        loop = asyncio.get_running_loop()
        if signals:
            loop.add_signal_handler(signal.SIGINT, self._on_sigint)
            loop.add_signal_handler(signal.SIGTERM, self.request_stop, "SIGTERM")
        try:
            await self._start()
            if status is not None:
                self._tasks.append(asyncio.create_task(status(self), name="status"))
            try:
                await asyncio.wait_for(self._stop.wait(), duration)
            except TimeoutError:
                self.stopped_reason = self.stopped_reason or "duration"
        finally:
            await self._shutdown()
            if signals:
                loop.remove_signal_handler(signal.SIGINT)
                loop.remove_signal_handler(signal.SIGTERM)
        if self.error is not None:
            raise RuntimeError(self.stopped_reason) from self.error
        return self.metrics


async def _start_output(i: int, p: Any) -> None:
    """Start publisher ``i`` (a MAVLink endpoint, MQTT); RuntimeError naming its config path and URL."""
    try:
        await p.start()
    except OSError as e:  # e.g. a host that does not resolve: the config path and the URL
        raise RuntimeError(f"outputs[{i}] ({p.name}): cannot open {p.cfg.url}: {e}") from e


class OpenOutputs:
    """MAVLink outputs open and sending HEARTBEAT before the gateway is built (:func:`open_outputs`);
    :class:`Gateway` (``outputs=``) takes them over, :meth:`close` them when no gateway follows."""

    def __init__(self, metrics: RuntimeMetrics, endpoints: list[MavlinkEndpoint]) -> None:
        self.metrics = metrics
        self.endpoints = endpoints

    def take(self, cfgs: list[EndpointConfig]) -> list[MavlinkEndpoint]:
        """The endpoints, for the configuration's ``outputs`` (the same file's: same names and URLs) with
        its rates (a ``<config>.params.toml`` may have changed the SR_* of the file)."""
        eps = self.endpoints
        if [(e.cfg.name, e.cfg.url) for e in eps] != [(c.name, c.url) for c in cfgs]:
            raise RuntimeError("the MAVLink outputs opened at start are not those of the configuration")
        for ep, ec in zip(eps, cfgs, strict=True):
            ep.cfg = ec
            want = ec.effective_rates()
            for typ in sorted(set(ep.rates) | set(want)):
                if ep.rates.get(typ, 0.0) != want.get(typ, 0.0):
                    ep.set_rate(typ, want.get(typ, 0.0))
        return list(eps)

    async def close(self) -> None:
        for ep in self.endpoints:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(ep.close(), 10.0)


async def open_outputs(cfgs: list[EndpointConfig]) -> OpenOutputs:
    """Open the MAVLink outputs ``cfgs`` and return once each has sent its first HEARTBEAT (to the
    transport; a link not up yet retries on its own): the vehicle is on the ground station's list before
    the core is built, the simulator started or the rest of the config validated (``ins-hil run``). Their
    task keeps HEARTBEAT (SYS_STATUS, ESTIMATOR_STATUS) at its rate meanwhile. RuntimeError (config path,
    URL) when one cannot be opened."""
    out = OpenOutputs(RuntimeMetrics(), [])
    try:
        for i, ec in enumerate(cfgs):
            ep = MavlinkEndpoint(ec, out.metrics)
            await _start_output(i, ep)
            out.endpoints.append(ep)
        deadline = time.monotonic() + 1.0  # (the task's first beat is due at once: a few loop iterations)
        while any("HEARTBEAT" in e.rates and not e.sent.get("HEARTBEAT") for e in out.endpoints):
            if time.monotonic() > deadline:
                break
            await asyncio.sleep(0.001)
    except BaseException:
        await out.close()
        raise
    return out


def _pin_port(url: str) -> str:
    """``udpin:HOST:0`` → a concrete free port, so a re-opened socket keeps the address the sender uses."""
    parts = url.split(":")
    if len(parts) == 3 and parts[0] in ("udpin", "udp") and parts[2] == "0":
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind((parts[1], 0))
            return f"udpin:{parts[1]}:{s.getsockname()[1]}"
    return url


_SECRETS = ("signing_key", "sign_key", "password")


def _redact(d: Any) -> Any:
    """The config for the log header without secrets (signing keys, passwords)."""
    if isinstance(d, dict):
        return {k: ("<redacted>" if k in _SECRETS and v else _redact(v)) for k, v in d.items()}
    if isinstance(d, list):
        return [_redact(v) for v in d]
    return d
