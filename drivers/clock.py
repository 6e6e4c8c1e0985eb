"""One clock model for every sensor counter: raw counter → continuous output time (s).

A sensor stamps its samples with a free-running counter: the serial frame's 32-bit µs
``t_us``, DroneCAN's 56-bit ``timestamp.usec``, the DBC profile's 8-bit sample counter.
:class:`SourceClock` (one per source: per serial ``imu_id``, per DroneCAN node, per DBC IMU)
turns that counter into an output time that

- never goes backwards (every accepted sample is strictly after the previous one: the
  pipeline drops any sample whose time is not),
- equals the sensor's own unwrapped time as long as nothing happens (so the output is as
  regular as the sensor's crystal, and a replay gives the same times),
- and recovers from every ordinary accident of the field, counted as a clock event.

Rules, per sample (raw counter ``raw``, optional sequence number ``seq``, interval
``dt`` in ticks, host arrival time ``host_ns``; 0 = not known):

1. **Consistent** with the last accepted sample (``el`` = counter step, ``d`` = sequence step,
   ``hs`` = host time elapsed): ``el > 0``, ``d > 0`` and either
   ``|el − d·dt| ≤ max(jump_tol_s, 10·dt, 5 %·d·dt)`` or ``el > d·dt`` and ``|el − hs| ≤
   max(jump_tol_s, 5 %·hs)`` (a long stall with the sensor clock running); and, when the host time is known,
   ``el ≤ hs + jump_tol_s`` (a sensor cannot advance further than the host saw time pass:
   this rejects a lone frame with its sequence and time far ahead). Accepted; the output
   is the unwrapped counter plus the current anchor offset.
2. **Wrap**: the counter step is taken modulo ``2^bits``; when the host says more than half
   a counter period passed, the number of wraps is taken from the host time
   (``k = round((hs/tick − el)/2^bits)``): after a 10 s stall an 8-bit 200 Hz counter
   advances 2000 ticks, not 208. Every wrap counts ``clock_wrap`` (not an error).
3. **Inconsistent** (time or sequence back, a forward jump, a sequence far ahead): the sample
   is dropped and counted once (``seq_backwards``, ``time_backwards`` or ``time_jump``; a
   same sequence number is ``duplicate``) and kept as a *candidate*. If the next inconsistent
   sample is consistent with the candidate (rule 1 between the two), the sensor's clock really
   changed: **re-anchor** there. A lone bad sample therefore costs that sample only, and a
   reboot, re-plug, forward jump or stall costs one sample.
4. **Re-anchoring** maps the new sensor time so the output continues at
   ``last output + host time elapsed since the last accepted sample`` (at least one interval;
   without host times: the intervals the sensor itself counted): downstream never sees a
   step back, and the wrap count of the old time base is kept in the output. Counted as
   ``clock_reanchor_reboot`` (time or sequence went back), ``clock_reanchor_stall`` (forward,
   after more than ``stall_s`` of host silence) or ``clock_reanchor_jump`` (forward).
   :meth:`hint_reset` (a DroneCAN NodeStatus whose uptime went back, a transport re-open) lets
   the next inconsistent sample re-anchor without waiting for a second one.
5. A sample without a sensor time (DroneCAN ``usec = 0``, "unknown") gets host time for that
   sample only (:meth:`host_sample`, ``clock_host_time``), continuing the output; the
   sensor's own time base is kept for the next sample.

Samples rejected for other reasons (values out of range, an unpaired DBC frame) are reported
with :meth:`rejected` so the sequence gap they leave is not counted a second time as
``seq_gap``: every received sample is accepted or counted exactly once; ``seq_gap`` counts
only samples that never arrived. :meth:`reopen` after a transport re-open keeps the time base
(the output continues across a re-plug: 0 samples lost when the device restarted its clock).
"""

from __future__ import annotations

import math

_NO_HOST = -1.0


class SourceClock:
    """Clock model of one sensor time source (see the module doc).

    ``bits``: counter width (32 serial µs, 56 DroneCAN µs, 8 DBC counter); ``tick_s``: seconds per
    count; ``counts``: the owner's counter dict (drop reasons and ``clock_*`` events);
    ``seq_bits``: width of a separate sequence number (16 serial; 0 = none); ``gaps_from_time``:
    count ``seq_gap`` from the counter step (DBC, whose counter is its sequence);
    ``anchor_host``: start the output at the host time of the first sample (DBC) instead of the
    sensor time; ``same_key``/``back_key``: counter keys for a counter that did not advance / went
    back when there is no sequence number.
    """

    __slots__ = (
        "anchor_host",
        "anchor_out",
        "back_key",
        "base",
        "cand",
        "counts",
        "gaps_from_time",
        "half",
        "half_s",
        "hint",
        "jt",
        "jump_tol",
        "last_host",
        "last_raw",
        "last_seq",
        "mask",
        "mod",
        "ns_tick",
        "off",
        "out",
        "rej",
        "same_key",
        "seq_half",
        "seq_mask",
        "seq_mod",
        "stall_s",
        "started",
        "tick",
    )

    def __init__(
        self,
        bits: int,
        tick_s: float,
        counts: dict[str, int] | None = None,
        *,
        seq_bits: int = 0,
        gaps_from_time: bool = False,
        jump_tol_s: float = 0.1,
        stall_s: float = 1.0,
        anchor_host: bool = False,
        same_key: str = "time_backwards",
        back_key: str = "time_backwards",
    ) -> None:
        if not 2 <= bits <= 64 or not (tick_s > 0 and math.isfinite(tick_s)):
            raise ValueError(f"clock model: bits 2..64 and a positive tick, got {bits}, {tick_s}")
        self.tick = tick_s
        self.mod = 1 << bits
        self.mask = self.mod - 1
        self.half = self.mod >> 1
        self.half_s = self.half * tick_s
        self.seq_mod = 1 << seq_bits if seq_bits else 0
        self.seq_mask = self.seq_mod - 1 if seq_bits else 0
        self.seq_half = self.seq_mod >> 1
        self.jump_tol = jump_tol_s
        self.jt = jump_tol_s / tick_s  # the same, in ticks
        self.ns_tick = 1e-9 / tick_s  # ticks per host ns
        self.stall_s = stall_s
        self.gaps_from_time = gaps_from_time
        self.anchor_host = anchor_host
        self.same_key, self.back_key = same_key, back_key
        self.counts: dict[str, int] = {} if counts is None else counts
        self.started = False
        self.last_raw = self.last_seq = self.last_host = 0
        self.base = 0  # unwrapped counter of the last accepted sample − its raw value (wraps × 2^bits)
        self.off = 0.0  # output − unwrapped counter × tick (s): 0 until the first re-anchor
        self.out = -math.inf  # output time of the last sample (s)
        self.anchor_out = -math.inf  # output time of the last sample stamped by the sensor
        self.cand: tuple[int, int, int] | None = None  # (raw, seq, host_ns) of the last inconsistent sample
        self.hint = False
        self.rej: list[int] = []  # sequence/counter steps of samples rejected since the last accepted one

    def _count(self, key: str, n: int = 1) -> None:
        c = self.counts
        c[key] = c.get(key, 0) + n

    # ------------------------------------------------------------------ the per-sample path
    def accept(self, raw: int, seq: int, dt: int, host_ns: int) -> float | None:
        """One sample: its output time (s), or None (dropped; the reason is counted).

        ``raw``: counter value; ``seq``: sequence number (ignored without ``seq_bits``);
        ``dt``: the sample's interval in ticks (≥ 1); ``host_ns``: arrival, host monotonic ns (0 = unknown).
        """
        # fast path: the next sample, one interval on (no allocation, no call)
        el = (raw - self.last_raw) & self.mask
        if (
            self.started
            and (not self.seq_mod or ((seq - self.last_seq) & self.seq_mask) == 1)
            and 0 < el < self.half
            and (el == 1 or not self.gaps_from_time)
            and abs(el - dt) <= (self.jt if 10 * dt < self.jt else 10 * dt)
        ):
            lh = self.last_host
            if host_ns and lh:
                h = (host_ns - lh) * self.ns_tick
                if h >= self.half or el > h + self.jt:
                    return self._slow(raw, seq, dt, host_ns)
            if raw < self.last_raw:
                self.base += self.mod
                self._count("clock_wrap")
            if self.rej:
                self.rej.clear()
            if self.cand is not None or self.hint:
                self.cand = None
                self.hint = False
            self.last_raw = raw
            self.last_seq = seq
            if host_ns:
                self.last_host = host_ns
            out = (raw + self.base) * self.tick + self.off
            if out <= self.out:  # only after a host-timed sample (rule 5): keep the output strictly increasing
                out = self.out + 1e-6
            self.out = self.anchor_out = out
            return out
        return self._slow(raw, seq, dt, host_ns)

    def _slow(self, raw: int, seq: int, dt: int, host_ns: int) -> float | None:
        if not self.started:
            return self._start(raw, seq, dt, host_ns)
        el = (raw - self.last_raw) & self.mask
        if self.seq_mod:
            d = (seq - self.last_seq) & self.seq_mask
            if d == 0 and el == 0:  # the same frame again
                self._count("duplicate")
                return None
            if d >= self.seq_half:
                d = -1
        else:
            d = 1
        hs = (host_ns - self.last_host) * 1e-9 if host_ns and self.last_host else _NO_HOST
        tick = self.tick
        if hs > self.half_s:  # more than half a counter period passed: the host counts the wraps
            k = round((hs / tick - el) / self.mod)
            if k > 0:
                el += k * self.mod
        elif el >= self.half:
            el -= self.mod
        if d > 0 and el > 0:
            e_s = d * dt * tick
            el_s = el * tick
            ok = abs(el_s - e_s) <= self._tol(e_s, dt)
            if hs >= 0.0:
                if el_s > hs + self.jump_tol:
                    ok = False
                elif not ok and el_s > e_s and abs(el_s - hs) <= max(self.jump_tol, 0.05 * hs):
                    ok = True  # a stall: the sensor's clock ran on while it sent nothing
            if ok:
                return self._advance(raw, seq, el, d, host_ns)
        return self._inconsistent(raw, seq, dt, host_ns, d, el, hs)

    def _advance(self, raw: int, seq: int, el: int, d: int, host_ns: int) -> float:
        """Accept a consistent sample ``el`` ticks after the last one."""
        base = self.last_raw + self.base + el - raw
        if base != self.base:
            self._count("clock_wrap", (base - self.base) // self.mod)
            self.base = base
        if self.seq_mod or self.gaps_from_time:
            steps = d if self.seq_mod else el
            if self.rej:
                lost = steps - 1 - len({r for r in self.rej if 0 < r < steps})
                self.rej.clear()
            else:
                lost = steps - 1
            if lost > 0:
                self._count("seq_gap", lost)
        elif self.rej:
            self.rej.clear()
        self.cand = None
        self.hint = False
        self.last_raw, self.last_seq = raw, seq
        if host_ns:
            self.last_host = host_ns
        out = (raw + base) * self.tick + self.off
        if out <= self.out:  # only after a host-timed sample (rule 5): keep the output strictly increasing
            out = self.out + 1e-6
        self.out = self.anchor_out = out
        return out

    def _inconsistent(self, raw: int, seq: int, dt: int, host_ns: int, d: int, el: int, hs: float) -> float | None:
        cand = self.cand
        if cand is not None:
            craw, cseq, chost = cand
            dc = ((seq - cseq) & self.seq_mask) if self.seq_mod else 1
            elc = (raw - craw) & self.mask
            if 0 < dc < (self.seq_half or 2) and 0 < elc < self.half:
                e = dc * dt * self.tick
                elc_s = elc * self.tick
                ok = abs(elc_s - e) <= self._tol(e, dt)
                if host_ns and chost and elc_s > (host_ns - chost) * 1e-9 + self.jump_tol:
                    ok = False
                if ok:
                    kind = "reboot" if self._went_back(craw, cseq) else "jump"
                    return self._reanchor(raw, seq, dt, host_ns, hs, kind, elc + dt)
        if self.hint:
            return self._reanchor(raw, seq, dt, host_ns, hs, "reboot", dt)
        if d == 0:
            self._count("duplicate")  # the same sequence number with another time: kept as a candidate
        elif d < 0:
            self._count("seq_backwards" if self.seq_mod else self.back_key)
        elif el == 0:
            self._count(self.same_key)
        elif el < 0:
            self._count(self.back_key)
        else:
            self._count("time_jump")
        self.cand = (raw, seq, host_ns)
        if d > 0 and (self.seq_mod or self.gaps_from_time):
            self._reject_at(d if self.seq_mod else el)
        return None

    def _tol(self, e_s: float, dt: int) -> float:
        """How far a counter step may differ from the step the sequence expects (``e_s``, s):
        max(jump_tol_s, 10 intervals, 5 % of the step)."""
        return max(self.jump_tol, 10 * dt * self.tick, 0.05 * e_s)

    def _went_back(self, raw: int, seq: int) -> bool:
        if self.seq_mod and ((seq - self.last_seq) & self.seq_mask) >= self.seq_half:
            return True
        el = (raw - self.last_raw) & self.mask
        return el == 0 or el >= self.half

    def _reanchor(self, raw: int, seq: int, dt: int, host_ns: int, hs: float, kind: str, own: int) -> float:
        """Start a new time base at this sample: output = last output + host time elapsed."""
        if kind != "reboot" and hs > self.stall_s:
            kind = "stall"
        self._count("clock_reanchor_" + kind)
        step = dt * self.tick
        elapsed = hs if hs >= 0.0 else own * self.tick  # without host times: the intervals the sensor counted
        out = self.out + (elapsed if elapsed > step else step)
        self.base = 0
        self.off = out - raw * self.tick
        self.last_raw, self.last_seq = raw, seq
        if host_ns:
            self.last_host = host_ns
        self.cand = None
        self.hint = False
        self.rej.clear()
        self.out = self.anchor_out = out
        return out

    def _start(self, raw: int, seq: int, dt: int, host_ns: int) -> float:
        self.started = True
        self.last_raw, self.last_seq, self.last_host = raw, seq, host_ns
        self.base = 0
        if self.out > -math.inf:  # host-timed samples came first: continue after them
            t = host_ns * 1e-9 if host_ns else -math.inf
            out = max(t, self.out + dt * self.tick)
            self.off = out - raw * self.tick
        elif self.anchor_host and host_ns:
            self.off = host_ns * 1e-9 - raw * self.tick
        out = raw * self.tick + self.off
        self.out = self.anchor_out = out
        return out

    # ------------------------------------------------------------------ other inputs
    def host_sample(self, dt_s: float, host_ns: int) -> float:
        """Output time of a sample that carries no sensor time (rule 5): host time, continuing the
        output (strictly after the previous one); the sensor's time base is left as it was."""
        self._count("clock_host_time")
        if not self.started:
            t = host_ns * 1e-9 if host_ns else -math.inf
            out = t if t > self.out else self.out + dt_s
        elif host_ns and self.last_host:
            out = self.anchor_out + (host_ns - self.last_host) * 1e-9
            if out < self.out + dt_s:
                out = self.out + dt_s
        else:
            out = self.out + dt_s
        self.out = out
        return out

    def rejected(self, seq: int) -> None:
        """A sample with this sequence number (or counter, without ``seq_bits``) was dropped for
        its values: not a gap (see the module doc)."""
        if not self.started or not (self.seq_mod or self.gaps_from_time):
            return
        if self.seq_mod:
            r = (seq - self.last_seq) & self.seq_mask
            if r >= self.seq_half:
                return
        else:
            r = (seq - self.last_raw) & self.mask
        self._reject_at(r)

    def _reject_at(self, r: int) -> None:
        if len(self.rej) < 64:
            self.rej.append(r)

    def hint_reset(self) -> None:
        """The sensor restarted (e.g. its uptime went back): the next inconsistent sample
        re-anchors at once instead of waiting for a second one to agree."""
        if self.started:
            self.hint = True

    def reopen(self) -> None:
        """The transport was re-opened (re-plug): keep the time base so the output continues, forget the
        candidate, and let the first inconsistent sample re-anchor at once (the device may have restarted)."""
        self.cand = None
        self.rej.clear()
        self.hint_reset()


class HostTimeMap:
    """A node's clock (s) mapped onto the host monotonic clock (s).

    ``offset = min(arrival − node time)`` over the samples of the current and the previous
    window (``window_s``): the smallest transport latency, following a slow drift. A node time
    that falls behind the estimate by more than ``reset_s`` (a node reboot) restarts the estimate.
    Used for DroneCAN node timestamps of aiding samples: the runtime treats every aiding time as
    host-monotonic.
    """

    __slots__ = ("_cur", "_prev", "_win_end", "reset_s", "window_s")

    def __init__(self, window_s: float = 10.0, reset_s: float = 0.5) -> None:
        self.window_s, self.reset_s = window_s, reset_s
        self.reset()

    def reset(self) -> None:
        self._cur = self._prev = math.inf
        self._win_end = -math.inf

    def update(self, node_s: float, host_ns: int) -> None:
        """One node-stamped sample and its host arrival (ns)."""
        a = host_ns * 1e-9
        d = a - node_s
        o = min(self._cur, self._prev)
        if o < math.inf and d > o + self.reset_s:
            self.reset()
        if a > self._win_end:
            self._prev, self._cur = self._cur, math.inf
            self._win_end = a + self.window_s
        if d < self._cur:
            self._cur = d

    def to_host(self, node_s: float, host_ns: int) -> float:
        """Host monotonic time (s) of a node time, never after its arrival ``host_ns``."""
        self.update(node_s, host_ns)
        t = node_s + min(self._cur, self._prev)
        a = host_ns * 1e-9
        return t if t < a else a
