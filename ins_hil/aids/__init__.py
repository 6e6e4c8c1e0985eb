"""Aid sources: one module per aiding sensor, behind one registry keyed by sample type.

In the shape of PX4's ``ekf2/EKF/aid_sources/*`` (one folder per source with its update and reset) and of
pyins' ``Measurement`` (``compute_matrices → (z, H, R)``: a new aid is one class). An aid module defines

* ``SOURCE``: an :class:`AidSource` naming the sample type it reads (its own dataclass or a shared one of
  :mod:`ins_hil.types`), its ``.ihlog`` record (type byte, ``struct`` format, fields ↔ sample), its
  validation check (the reasons it may reject a sample for, counted ``reject_<reason>``), the core's input
  contract (:meth:`AidSource.check`), its config section (``[core.nav.<name>]``, new aids only: the sections
  of the first aids stay in :mod:`ins_hil.core_parts.config`), the error-state blocks it adds, and
* its per-core part (:meth:`AidSource.bind` → :class:`Aid`): the model returning
  :class:`~ins_hil.core_parts.contract.Measurement` (z, H, R, gate) — built with
  :mod:`ins_hil.fusion.measurements` where the model exists there —, the alignment hook before navigation,
  the feedback of its own error states and its snapshot/restore for delayed fusion.

:class:`ins_hil.core.NavCore` keeps the mechanization, the time update, the gating/update (``_apply``) and the
feedback of the navigation states, and dispatches ``fuse`` through :func:`by_sample`; the validation boundary,
the recorder, the pipeline and the schema read the same registry.

Adding an aid: one module here and its name in :data:`AID_MODULES` (the registry line). Modules are imported
lazily by name, the first time the registry is read (python-can's ``BACKENDS`` style).
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import fields
from typing import Any, ClassVar

from ins_hil.types import Vec

#: the aid modules of this package, in registry order (the one line a new aid adds)
AID_MODULES = ("gnss", "baro", "mag", "vehicle", "odometer", "airspeed")

_INF = math.inf


class Aid:
    """One aid source bound to one core (:meth:`AidSource.bind`): what the core calls.

    ``fuse(meas, assume_now)`` yields between its updates (a real-time caller runs IMU steps there);
    ``after_step(imu)`` runs after every IMU time update (the vehicle aids: no sample of their own);
    ``arrive(meas)`` sees every sample as it comes; ``align(meas)`` takes a sample before navigation;
    ``feedback(x)`` applies the aid's own error states of the error estimate ``x``; ``snapshot``/``restore``
    keep the aid's state for delayed fusion (references
    only, nothing mutated in place). Every hook defaults to nothing."""

    #: the aid keeps state across steps (snapshot/restore are called)
    stateful = False
    #: the aid runs after every IMU step (``after_step``)
    per_step = False

    def parts(self, meas: Any) -> tuple[Any, ...]:
        """The measurements ``meas`` is fused as, each at its own time of validity (default: itself)."""
        return (meas,)

    def arrive(self, meas: Any) -> None:
        """Every sample as the core receives it, before alignment or fusion (in arrival order)."""
        return None

    def fuse(self, meas: Any, assume_now: bool = False) -> Iterator[None]:
        yield from ()

    def after_step(self, imu: Any) -> None:
        return None

    def align(self, meas: Any) -> None:
        return None

    def feedback(self, x: Vec) -> None:
        return None

    def snapshot(self) -> Any:
        return None

    def restore(self, d: Any) -> None:
        return None


class AidSource:
    """The static description of one aid source (one per module, ``SOURCE``); see the module doc."""

    #: the source's name (its ``[core.nav.<name>]`` section, its record, its counters)
    name: str = ""
    #: the sample type it reads (None: an aid fed by the IMU, e.g. the vehicle aids)
    sample: type | None = None
    #: its ``.ihlog`` record type (0: not recorded) and the payload's struct format (little endian, no prefix)
    record: int = 0
    record_fmt: str = ""
    #: the reasons :meth:`validate` may return (``reject_<reason>``)
    reasons: tuple[str, ...] = ()
    #: the gate-statistics kinds of its measurements (``Measurement.kind``)
    kinds: tuple[str, ...] = ()
    #: its config section (a dataclass; ``NavConfig.sources[name]``), None: in core_parts.config
    section: type | None = None
    #: the aiding drift monitor (:mod:`ins_hil.fdi.aiding`) checks its samples before they are fused
    drift_monitor: bool = False
    #: the pipeline's drift-monitor check of a sample and its update run in separate gaps
    split_check: bool = False
    #: its generic-CSV record (:mod:`ins_hil.datasets.generic_csv`): the kind, the columns after ``t`` (the first
    #: ``csv_required`` of them required); "" = none
    csv_kind: str = ""
    csv_columns: tuple[str, ...] = ()
    csv_required: int = 0
    #: the PX4 ULog topics it reads (the ULog and ulog2csv readers load them for :meth:`from_ulog`)
    ulog_topics: tuple[str, ...] = ()
    #: the DataFlash messages it reads, each with the fields it needs (the reader refuses a log whose rows lack
    #: them, and keeps the first instance of each), for :meth:`from_dataflash`
    dataflash_messages: ClassVar[Mapping[str, tuple[str, ...]]] = {}

    def check(self, s: Any) -> None:
        """The core's input contract: ValueError (one line) for a sample the core cannot fuse. Default: a
        finite time."""
        if not abs(s.t) < _INF:
            raise ValueError(f"NavCore.fuse: {type(s).__name__}.t = {s.t!r}: must be a finite time (s)")

    def validate(self, v: Any, s: Any) -> str | None:
        """The validation boundary's check (``v``: the :class:`ins_hil.validation.SampleValidator`, its limits
        and per-source state): None for a sample that may be fused, else one of :attr:`reasons`."""
        return None

    def starts_core(self, s: Any) -> bool:
        """Whether the runtime may start a core at this sample (its position and velocity: a 3-D GNSS fix)."""
        return False

    def fields(self, s: Any) -> tuple[Any, ...]:
        """The record payload's values of a sample, in :attr:`record_fmt` order."""
        raise NotImplementedError

    def build(self, vals: tuple[Any, ...]) -> Any:
        """The sample of a record payload's values (:meth:`fields` reversed)."""
        raise NotImplementedError

    def from_csv(self, row: list[float]) -> Any:
        """The sample of a generic-CSV record's values ``[t, *csv_columns]`` (NaN: an empty optional field)."""
        raise NotImplementedError

    def to_csv(self, s: Any) -> tuple[float, ...]:
        """A sample's generic-CSV values ``(t, *csv_columns)`` (:meth:`from_csv` reversed; NaN: left empty)."""
        raise NotImplementedError

    def from_ulog(self, topics: Mapping[str, Mapping[str, Vec]], time: Callable[[Any], Vec]) -> tuple[list[Any], str]:
        """Its samples from a PX4 log's topics (:attr:`ulog_topics`; a topic: field name → column) and a note for
        the dataset's notes ("" none); ``time(topic)``: the topic's time of validity (s)."""
        return [], ""

    def from_dataflash(self, rows: Mapping[str, list[dict[str, Any]]]) -> tuple[list[Any], str]:
        """Its samples from a DataFlash log's rows (:attr:`dataflash_messages` and the reader's own messages, the
        first instance of each; a row: field → value, ``TimeUS`` in µs) and a note ("" none)."""
        return [], ""

    def blocks(self, nav: Any) -> tuple[tuple[str, int, float, float], ...]:
        """The error-state blocks this aid adds under config ``nav`` (``NavConfig``): (name, size, initial
        1-σ, random-walk σ per √s), appended after the filter's own states."""
        return ()

    def config(self, nav: Any) -> Any:
        """This aid's own section of ``nav`` (``NavConfig.sources[name]``, built by
        :func:`ins_hil.runtime.pipeline.nav_config`): its default when absent; None for an aid whose section is in
        :mod:`ins_hil.core_parts.config`. TypeError (one line) for anything but its class (a table is built once,
        by the config loader, not here)."""
        if self.section is None:
            return None
        v = nav.sources.get(self.name)
        if v is None:
            return self.section()
        if not isinstance(v, self.section):
            raise TypeError(
                f"NavConfig.sources[{self.name!r}]: expected a {self.section.__name__}, got {type(v).__name__}"
            )
        return v

    def enabled(self, nav: Any) -> bool:
        """Whether ``nav`` (``NavConfig``) turns this aid on (the C core's "not supported" list)."""
        return bool(getattr(self.config(nav), "enabled", False))

    def stat_kinds(self, nav: Any) -> tuple[str, ...]:
        """The gate-statistics kinds a core under ``nav`` keeps (``NavCore.stats``): :attr:`kinds` when
        enabled."""
        return self.kinds if self.enabled(nav) else ()

    def bind(self, core: Any) -> Aid:
        """This source's part of one core (:class:`ins_hil.core.NavCore`)."""
        return Aid()

    def decoders(self, protocol: str, cfg: Any) -> dict[Any, Decoder]:
        """The decoders of this source's samples from a driver's messages, for one driver (a decoder may keep
        state, e.g. the air density): ``protocol`` ``"mavlink"`` (message type → ``fn(msg, t, arrival_ns)``,
        ``msg`` a pymavlink message, ``t`` its time on our clock, s) or ``"dronecan"`` (data type id →
        ``fn(payload, t, arrival_ns)``, ``payload`` the transfer's bytes); ``cfg``: the source's config section.
        A decoder returns the sample, None (nothing to deliver) or a reason (str) the driver counts."""
        return {}


#: a driver-message decoder (:meth:`AidSource.decoders`): (message, t (s), arrival (ns)) → sample | None | reason
Decoder = Callable[[Any, float, int], Any]

_SOURCES: tuple[AidSource, ...] | None = None
_BY_SAMPLE: dict[type, AidSource] = {}
_BY_RECORD: dict[int, AidSource] = {}


def sources() -> tuple[AidSource, ...]:
    """Every registered aid source, in :data:`AID_MODULES` order (imported on first use)."""
    global _SOURCES
    if _SOURCES is None:
        out = tuple(importlib.import_module(f"{__name__}.{m}").SOURCE for m in AID_MODULES)
        for s in out:
            if s.sample is not None:
                if getattr(s.sample, "kind", None) != s.name:
                    raise RuntimeError(f"aid source {s.name!r}: its sample {s.sample.__name__} needs kind = {s.name!r}")
                if s.sample in _BY_SAMPLE:
                    raise RuntimeError(f"aid sources {_BY_SAMPLE[s.sample].name!r} and {s.name!r} read one sample")
                _BY_SAMPLE[s.sample] = s
            if s.record:
                if s.record in _BY_RECORD:
                    raise RuntimeError(f"aid sources {_BY_RECORD[s.record].name!r} and {s.name!r}: one record type")
                _BY_RECORD[s.record] = s
        _SOURCES = out
    return _SOURCES


def by_sample() -> dict[type, AidSource]:
    """The aid sources by the sample type they read."""
    sources()
    return _BY_SAMPLE


def by_record() -> dict[int, AidSource]:
    """The aid sources by their ``.ihlog`` record type."""
    sources()
    return _BY_RECORD


def by_name() -> dict[str, AidSource]:
    """The aid sources by name."""
    return {s.name: s for s in sources()}


def sample_types() -> tuple[type, ...]:
    """The aiding sample types (the aid half of :data:`ins_hil.types.Sample`)."""
    return tuple(by_sample())


def source_of(s: Any) -> AidSource:
    """The aid source of sample ``s``; TypeError (one line) for a sample no aid reads."""
    src = by_sample().get(type(s))
    if src is None:
        raise TypeError(f"no aid source reads {type(s).__name__} (known: {', '.join(t.__name__ for t in _BY_SAMPLE)})")
    return src


def sections() -> dict[str, type]:
    """The config sections of the aid modules (``[core.nav.<name>]`` → dataclass)."""
    return {s.name: s.section for s in sources() if s.section is not None}


def check_sources(nav: Any) -> None:
    """ValueError (one line) for a name in ``nav.sources`` (``NavConfig``) that no aid module has a section for."""
    known = sections()
    bad = set(nav.sources) - set(known)
    if bad:
        raise ValueError(f"NavConfig.sources: unknown aid section(s) {sorted(bad)} (known: {', '.join(known)})")
    for name in nav.sources:
        by_name()[name].config(nav)  # of its class


def section_keys(cls: type) -> set[str]:
    """The keys of a config section."""
    return {f.name for f in fields(cls)}


def ulog_topics() -> tuple[str, ...]:
    """The PX4 ULog topics the aid sources read (:attr:`AidSource.ulog_topics`)."""
    return tuple(t for s in sources() for t in s.ulog_topics)


def dataflash_messages() -> dict[str, tuple[str, ...]]:
    """The DataFlash messages the aid sources read, with the fields they need (:attr:`AidSource.dataflash_messages`;
    a message two aids read: the union of their fields)."""
    out: dict[str, tuple[str, ...]] = {}
    for s in sources():
        for name, cols in s.dataflash_messages.items():
            out[name] = (*out.get(name, ()), *(c for c in cols if c not in out.get(name, ())))
    return out


def from_ulog(topics: Mapping[str, Mapping[str, Vec]], time: Callable[[Any], Vec]) -> tuple[list[Any], list[str]]:
    """Every aid source's samples of a PX4 log (:meth:`AidSource.from_ulog`), time-ordered, and their notes."""
    return _read(lambda s: s.from_ulog(topics, time))


def from_dataflash(rows: Mapping[str, list[dict[str, Any]]]) -> tuple[list[Any], list[str]]:
    """Every aid source's samples of a DataFlash log (:meth:`AidSource.from_dataflash`), time-ordered, and their
    notes."""
    return _read(lambda s: s.from_dataflash(rows))


def _read(one: Callable[[AidSource], tuple[list[Any], str]]) -> tuple[list[Any], list[str]]:
    out: list[Any] = []
    notes: list[str] = []
    for s in sources():
        got, note = one(s)
        out += got
        if note:
            notes.append(note)
    return sorted(out, key=lambda m: m.t), notes


def reasons() -> tuple[str, ...]:
    """Every validation reason of the aid sources."""
    return tuple(r for s in sources() for r in s.reasons)


def decoders(protocol: str, nav: Any) -> dict[Any, tuple[Decoder, ...]]:
    """The decoders of the aids enabled in ``nav`` (``NavConfig``; None: none enabled) for one driver of
    ``protocol`` (:meth:`AidSource.decoders`), by message key. The runtime hands these to the drivers as plain
    callables (the drivers sit below the aids and never import them)."""
    out: dict[Any, tuple[Decoder, ...]] = {}
    if nav is None:
        return out
    for src in sources():
        if src.section is None or not src.enabled(nav):
            continue
        for key, fn in src.decoders(protocol, src.config(nav)).items():
            out[key] = (*out.get(key, ()), fn)
    return out
