"""The delayed-fusion history: per-step snapshots and the log of IMU samples and measurements, and the
roll-back that fuses a late measurement at its step and replays the log up to now (forward propagation)."""

from __future__ import annotations

from collections import deque
from collections.abc import Generator, Iterator
from typing import Any, Protocol

from ins_hil.types import AidSample as Aid
from ins_hil.types import ImuSample

_DONE = object()

#: a log entry: (step number, "imu" or "meas", the sample)
Entry = tuple[int, str, Any]


class Replayable(Protocol):
    """What the history needs of the core (:class:`ins_hil.core.NavCore`): its snapshot, its step counter and
    replay flag, the propagation and the fusion at the current step."""

    step_n: int
    replaying: bool
    pending_end: ImuSample | None

    def snapshot(self) -> Any: ...

    def restore(self, d: Any) -> None: ...

    def step_end(self) -> None: ...

    def propagate(self, imu: ImuSample) -> None: ...

    def fuse_now(self, meas: Aid, assume_now: bool = False) -> None: ...

    def fuse_now_steps(self, meas: Aid, assume_now: bool = False) -> Iterator[None]: ...


class DelayedHistory:
    """Snapshots of the last ``max_delay`` s of steps (step number, state time s, core snapshot) and the log
    of the IMU samples and measurements since the oldest of them."""

    #: IMU steps a roll-back replays per segment of ``NavCore.fuse_steps`` (about 0.3 ms in Python)
    REPLAY_SEGMENT = 8

    def __init__(self, core: Replayable, max_delay: float) -> None:
        self.core = core
        self.max_delay = max_delay
        self.snaps: deque[tuple[int, float, Any]] = deque()
        self.log: deque[Entry] = deque()
        self.log_sorted = 0  # the log's first entries already in replay order (see sort_log)
        self.rb_gen: Generator[None, None, bool] | None = None  # a roll-back, maybe suspended between segments
        self.rb_new: list[Entry] | None = None  # while one runs: IMU steps logged meanwhile

    def log_imu(self, step_n: int, imu: ImuSample) -> None:
        e = (step_n, "imu", imu)
        self.log.append(e)
        if self.rb_new is not None:
            self.rb_new.append(e)  # a suspended roll-back replays this step too

    def after_step(self, step_n: int, t: float, dt: float) -> None:
        """Keep the snapshot of the step just finished; drop what is older than the horizon."""
        snaps = self.snaps
        snaps.append((step_n, t, self.core.snapshot()))
        horizon = t - self.max_delay - 2 * dt
        while snaps and snaps[0][1] < horizon:
            snaps.popleft()
        if self.rb_new is None:  # a suspended roll-back still needs the log from its target on
            first = snaps[0][0] if snaps else step_n
            log = self.log
            while log and log[0][0] < first:
                log.popleft()
                self.log_sorted -= 1
            if self.log_sorted < 0:
                self.log_sorted = 0

    def fuse_delayed_steps(self, meas: Aid, dt: float) -> Generator[None, None, bool]:
        """Roll back to the step nearest meas.t (``dt``: the IMU interval, s), fuse, replay; returns False if
        the history is too short. In segments: the roll-back and the fusion, then the replay of the logged IMU
        steps and measurements up to now, ``REPLAY_SEGMENT`` steps per segment.

        Between two segments the core is live again: the state at the roll-back's start is put back, so a
        real-time caller can run IMU steps (logged, and replayed by the next segments) and publish their
        state; the roll-back's state is kept aside. When the replay has caught up with the last step, its
        state replaces the live one. Exhausted with no step in between, the operations and their order are
        those of a roll-back in one piece: the same numbers, bit for bit."""
        core = self.core
        target = None
        for sn in reversed(self.snaps):
            if sn[1] <= meas.t + 0.5 * dt:
                target = sn
                break
        if target is None:
            return False
        t_step, t_t, t_data = target
        replay = [e for e in self.log if e[0] >= t_step]
        live = (core.snapshot(), core.step_n)
        core.restore(t_data)
        core.step_n = t_step
        self.rb_new = []
        try:
            it = core.fuse_now_steps(meas)  # counted and gated like any measurement
            while next(it, _DONE) is not _DONE:
                live = yield from self._pause(live, False)
            core.replaying = True
            kept = deque(self.snaps)
            while kept and kept[-1][0] > t_step:
                kept.pop()
            kept[-1] = (t_step, t_t, core.snapshot())
            k = 0
            pos = 0
            while True:
                if replay:
                    entries, replay = replay, []
                else:
                    entries = self.rb_new[pos:]
                    pos += len(entries)
                    if not entries:
                        break
                for _step, kind, obj in entries:
                    if kind == "imu":
                        core.propagate(obj)
                        kept.append((core.step_n, obj.t, core.snapshot()))
                        k += 1
                        if k % self.REPLAY_SEGMENT == 0:
                            live = yield from self._pause(live, True)
                    else:
                        core.fuse_now(obj)
            self.snaps = kept
        finally:
            core.replaying = False
            self.rb_new = None
        self.log.append((t_step, "meas", meas))
        self.sort_log(t_step)
        return True

    def _pause(self, live: tuple[Any, int], replaying: bool) -> Generator[None, None, tuple[Any, int]]:
        """Suspend a roll-back between two segments: the live state back in, the roll-back's aside; on
        resume (after any IMU steps the caller ran) the other way round. Returns the live state."""
        core = self.core
        mine = (core.snapshot(), core.step_n)
        core.restore(live[0])
        core.step_n = live[1]
        core.replaying = False
        yield
        if core.pending_end is not None:
            core.step_end()
        live = (core.snapshot(), core.step_n)
        core.restore(mine[0])
        core.step_n = mine[1]
        core.replaying = replaying
        return live

    def finish_rollback(self) -> None:
        """Run a suspended roll-back to its end now (before anything else changes the core)."""
        gen, self.rb_gen = self.rb_gen, None
        if gen is not None:
            for _ in gen:
                pass

    def sort_log(self, floor: int) -> None:
        """Put the log in replay order: by step, the measurements fused at a step (state after IMU step−1)
        before that step's IMU sample, which takes the state to the next step (a stable sort). Only the tail
        from the first step ≥ min(``floor``, the first step logged since the last sort) is sorted: the entries
        before it are in order and all of smaller steps."""
        log = self.log
        n = len(log)
        u = min(self.log_sorted, n)
        b = floor if u >= n else min(floor, log[u][0])
        cut = u
        while cut > 0 and log[cut - 1][0] >= b:
            cut -= 1
        tail = [log.pop() for _ in range(n - cut)]
        tail.reverse()
        tail.sort(key=lambda e: (e[0], e[1] == "imu"))
        log.extend(tail)
        self.log_sorted = n
