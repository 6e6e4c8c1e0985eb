"""Recorder robustness: CRC-framed records, damage reported with file/part/offset, parts checked, retention.

Property tests (hypothesis, seconds): any bytes read back as records or one ``RecordError``;
any single flipped byte of a recording is detected (never a silently wrong value).
"""

from __future__ import annotations

import json
import math
import os
import struct
import tomllib
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ins_hil.config import ConfigError, from_dict
from ins_hil.runtime.recorder import (
    MAGIC_V1,
    T_BARO,
    T_GNSS,
    T_IMU,
    LogReader,
    Recorder,
    RecordError,
    bytes_per_hour,
    part_path,
    parts_of,
    read_records,
)
from ins_hil.runtime.replay import replay_cli, replay_log
from ins_hil.types import BaroSample, FixType, GnssFix, ImuSample, MagSample

_FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _samples(n: int = 40) -> list:
    rng = np.random.default_rng(7)
    out: list = []
    for k in range(n):
        t = 0.01 * k
        out.append(ImuSample(t, 0.01, rng.normal(size=3) * 1e-3, rng.normal(size=3) * 0.1, 0, k, 20.0, 0, k))
        if k % 10 == 3:
            out.append(GnssFix(t, 0.88, 0.53, 181.0, rng.normal(size=3), 1.5, 2.5, 0.2, FixType.FIX_3D, 9, 0, k))
        if k % 10 == 6:
            out.append(BaroSample(t, 98765.0, 181.2, 21.0, 1, k))
        if k % 10 == 8:
            out.append(MagSample(t, rng.normal(size=3) * 1e-5, 4, k))
    return out


def _key(s: object) -> tuple:
    """Every field of a sample as a comparable tuple (NaN-safe, arrays as tuples)."""
    vals = []
    for f in s.__slots__:  # type: ignore[attr-defined]
        v = getattr(s, f)
        if isinstance(v, np.ndarray):
            v = tuple(float(x) for x in v)
        if isinstance(v, float) and math.isnan(v):
            v = "nan"
        vals.append(v)
    return (type(s).__name__, *vals)


def _record(path: Path, samples: list, **kw: object) -> Recorder:
    rec = Recorder(path, header={"pipeline": {}}, **kw)  # type: ignore[arg-type]
    for k, s in enumerate(samples):
        rec.write(s)
        if k % 7 == 0:
            rec.flush()
    rec.close()
    return rec


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[bytes, list]:
    d = tmp_path_factory.mktemp("rec")
    src = _samples()
    _record(d / "r.ihlog", src)
    return (d / "r.ihlog").read_bytes(), [_key(s) for s in src]


def _read_all(path: Path, skip: bool = False) -> tuple[list, str]:
    out: list = []
    try:
        for r in read_records(path, skip_damaged=skip):
            out.append(_key(r))
    except RecordError as e:
        return out, str(e)
    return out, ""


@_FAST
@given(pos=st.integers(min_value=0), mask=st.integers(min_value=1, max_value=255))
def test_any_flipped_byte_is_detected_never_silently_wrong(
    tmp_path: Path, recorded: tuple[bytes, list], pos: int, mask: int
) -> None:
    data, keys = recorded
    pos %= len(data)
    bad = bytearray(data)
    bad[pos] ^= mask
    p = tmp_path / "f.ihlog"
    p.write_bytes(bytes(bad))
    got, err = _read_all(p)
    assert err, f"flip at byte {pos} not detected"
    assert "\n" not in err and str(p) in err and "part 0" in err
    assert got == keys[: len(got)]  # the intact prefix, exact
    # skip mode: resync on the next valid frame; everything delivered is an original record
    got2, _ = _read_all(p, skip=True)
    assert set(got2) <= set(keys)
    assert len(got2) >= len(got)
    (n,) = struct.unpack_from("<I", data, 7)
    if 7 + 4 + n + 4 <= pos < len(data) - 25:
        # inside the records: the damaged one is lost, and the next one too when the flip hit the damaged
        # one's CRC (the seed of the next frame's chained CRC); the rest in order
        lost = [i for i, k in enumerate(keys) if k not in set(got2)]
        assert got2 == [k for k in keys if k in set(got2)]
        assert len(lost) == 1 or (len(lost) == 2 and lost[1] == lost[0] + 1), lost


def test_every_single_byte_flip_of_a_recording_is_detected(tmp_path: Path) -> None:
    src = _samples(8)
    p = tmp_path / "e.ihlog"
    _record(p, src)
    data = p.read_bytes()
    keys = [_key(s) for s in src]
    silent = 0
    for pos in range(len(data)):
        for mask in (0x01, 0x80):
            bad = bytearray(data)
            bad[pos] ^= mask
            p.write_bytes(bytes(bad))
            got, err = _read_all(p)
            silent += not err or got != keys[: len(got)]
    assert silent == 0


@_FAST
@given(blob=st.binary(max_size=400), prefix=st.sampled_from([b"", b"IHLOG2\n", b"IHLOG1\n", "valid"]))
def test_any_bytes_give_records_or_one_record_error(
    tmp_path: Path, recorded: tuple[bytes, list], blob: bytes, prefix: bytes | str
) -> None:
    data, _ = recorded
    head = data[: len(blob) % len(data)] if prefix == "valid" else prefix
    p = tmp_path / "x.ihlog"
    assert isinstance(head, bytes)
    p.write_bytes(head + blob)
    for skip in (False, True):
        try:
            for r in read_records(p, skip_damaged=skip):
                assert isinstance(r, ImuSample | GnssFix | BaroSample | MagSample)
        except RecordError as e:
            assert "\n" not in str(e) and str(e)


@pytest.mark.parametrize("n", [0, 3, 7, 8, 9, 10, 11, 20])
def test_file_cut_inside_the_header_is_one_record_error(tmp_path: Path, recorded: tuple[bytes, list], n: int) -> None:
    data, _ = recorded
    p = tmp_path / "c.ihlog"
    p.write_bytes(data[:n])
    with pytest.raises(RecordError, match=r"c\.ihlog"):
        list(read_records(p))
    res = replay_log_or_error(p)
    assert "c.ihlog" in res


def replay_log_or_error(p: Path) -> str:
    try:
        return replay_log(p).read_error
    except RecordError as e:
        return str(e)


@pytest.mark.parametrize("doc", [b"[1, 2]", b'"text"', b"3", b"null", b"\xff\xfe{"])
def test_header_json_not_an_object_is_one_record_error(tmp_path: Path, doc: bytes) -> None:
    for magic, crc in ((MAGIC_V1, b""), (b"IHLOG2\n", None)):
        n = struct.pack("<I", len(doc))
        tail = crc if crc is not None else struct.pack("<I", zlib.crc32(n + doc))
        p = tmp_path / "h.ihlog"
        p.write_bytes(magic + n + doc + tail)
        with pytest.raises(RecordError, match="header"):
            list(read_records(p))


def test_killed_recording_keeps_the_prefix(tmp_path: Path) -> None:
    src = _samples()
    rec = Recorder(tmp_path / "k.ihlog")
    for s in src:
        rec.write(s)
    rec.flush()  # killed: never closed
    data = (tmp_path / "k.ihlog").read_bytes()
    whole = [_key(s) for s in src]
    for cut in (1, 5, 40, 91):
        (tmp_path / "k.ihlog").write_bytes(data[:-cut])
        reader = LogReader(tmp_path / "k.ihlog")
        got = [_key(r) for r in reader]
        assert got == whole[: len(got)] and len(got) >= len(whole) - 2
        assert reader.message() == "" and reader.stats.notes  # a kill is a note, not damage


def _corrupt_type_of_record(path: Path, index: int) -> int:
    """Overwrite the type byte of the index-th record; returns its offset."""
    data = bytearray(path.read_bytes())
    (n,) = struct.unpack_from("<I", data, 7)
    off = 7 + 4 + n + 4
    sizes = {T_IMU: 92, T_GNSS: 100, T_BARO: 49, 4: 49}
    for _ in range(index):
        off += sizes[data[off + 2]]
    data[off + 2] = 0x77
    path.write_bytes(bytes(data))
    return off


def test_corrupt_record_type_replays_the_prefix_or_skips_and_counts(tmp_path: Path, capsys) -> None:
    src = _samples()
    p = tmp_path / "t.ihlog"
    _record(p, src)
    off = _corrupt_type_of_record(p, 20)
    res = replay_log(p)
    assert res.records == 20  # the intact prefix was replayed, not discarded
    assert f"part 0: damaged record at byte {off}" in res.read_error and "20 records used" in res.read_error
    assert replay_cli(p, None) == 2
    out = capsys.readouterr().err  # the one-line damage message goes to stderr
    line = next(x for x in out.splitlines() if "damaged" in x)
    assert str(p) in line and f"byte {off}" in line and "sensor time 0.000–" in line
    reader = LogReader(p, skip_damaged=True)
    got = [_key(r) for r in reader]
    whole = [_key(s) for s in src]
    assert got == whole[:20] + whole[21:]
    assert reader.stats.damaged == 1 and reader.stats.skipped_bytes > 0 and "1 damaged" in reader.message()


def _rotated(tmp_path: Path, name: str = "rot.ihlog", n: int = 400, **kw: object) -> tuple[Recorder, list]:
    src = _samples(n)
    rec = _record(tmp_path / name, src, max_bytes=4096, **kw)
    return rec, src


def test_damaged_header_of_part_1_keeps_part_0(tmp_path: Path) -> None:
    rec, src = _rotated(tmp_path)
    assert len(rec.paths) >= 4
    p1 = rec.paths[1]
    data = bytearray(p1.read_bytes())
    data[20] ^= 0x40
    p1.write_bytes(bytes(data))
    got, err = _read_all(rec.paths[0])
    n0 = len(list(LogReader(rec.paths[0], follow_parts=False)))
    assert len(got) == n0 > 0 and got == [_key(s) for s in src[:n0]]
    assert "rot.1.ihlog: part 1: damaged header" in err


def test_missing_middle_part_is_reported_not_silently_dropped(tmp_path: Path) -> None:
    rec, src = _rotated(tmp_path)
    per = [len(list(LogReader(q, follow_parts=False))) for q in rec.paths]
    rec.paths[2].unlink()
    got, err = _read_all(rec.paths[0])
    assert len(got) == per[0] + per[1]
    assert "rot.2.ihlog: part 2 missing" in err
    reader = LogReader(rec.paths[0], skip_damaged=True)
    got = [_key(r) for r in reader]
    assert len(got) == len(src) - per[2]
    assert "part 2 missing" in reader.message()


def test_missing_last_part_and_foreign_part_are_reported(tmp_path: Path) -> None:
    rec, _ = _rotated(tmp_path)
    last = rec.paths[-1]
    last.unlink()
    _, err = _read_all(rec.paths[0])
    assert "says a next part follows, none on disk" in err
    other, _ = _rotated(tmp_path / "other", n=400)
    os.replace(other.paths[1], last)  # a part of another run under this run's name
    _, err = _read_all(rec.paths[0])
    assert f"part {len(rec.paths) - 1} belongs to another run" in err


def test_headers_name_index_previous_part_and_run(tmp_path: Path) -> None:
    from ins_hil.runtime.recorder import read_header

    rec, _ = _rotated(tmp_path)
    hs = [read_header(q) for q in rec.paths]
    assert [h["part"] for h in hs] == list(range(len(hs)))
    assert [h["prev"] for h in hs] == [None] + [q.name for q in rec.paths[:-1]]
    assert len({h["session"] for h in hs}) == 1 and all(h["format"] == 2 for h in hs)
    assert hs[1]["prev_records"] > 0


def _v1_file(path: Path, samples: list) -> None:
    """A format-1 recording as the previous recorder wrote it (type byte + struct, no CRC)."""
    from ins_hil.runtime import recorder as r

    hdr = json.dumps({"pipeline": {}, "session": "old", "part": 0}).encode()
    body = b"".join(r.encode_record(s)[2:-4][:1] + r.encode_record(s)[4:-4] for s in samples)
    path.write_bytes(MAGIC_V1 + struct.pack("<I", len(hdr)) + hdr + body)


def test_format_1_recordings_still_read(tmp_path: Path) -> None:
    src = _samples()
    p = tmp_path / "old.ihlog"
    _v1_file(p, src)
    assert [_key(r) for r in read_records(p)] == [_key(s) for s in src]
    p.write_bytes(p.read_bytes()[:-5])  # cut by a kill
    assert len(list(read_records(p))) == len(src) - 1


def test_retention_deletes_this_runs_oldest_parts_only(tmp_path: Path) -> None:
    foreign = tmp_path / "other-run.ihlog"
    _record(foreign, _samples(5))
    msgs: list[str] = []
    rec, src = _rotated(tmp_path, max_total_bytes=4 * 4096, on_message=msgs.append)
    assert len(rec.paths) > 6 and rec.deleted == rec.paths[: len(rec.deleted)] and rec.deleted
    kept = [q for q in rec.paths if q.exists()]
    assert kept == rec.kept and sum(q.stat().st_size for q in kept) <= 4 * 4096
    assert foreign.exists()  # other runs' files are not touched without a directory limit
    assert (
        len(msgs) == len(rec.deleted) and "deleted this run's oldest part" in msgs[0] and str(rec.paths[0]) in msgs[0]
    )
    # the kept parts still read, from the first kept part, with a note instead of an error
    reader = LogReader(kept[-1])
    got = [_key(r) for r in reader]
    assert reader.message() == "" and "not on disk" in reader.stats.notes[0]
    res = replay_log(kept[0])
    assert res.read_error == "" and "not on disk" in res.read_notes[0] and res.records == len(got)
    assert got == [_key(s) for s in src[len(src) - len(got) :]]
    rec2, _ = _rotated(tmp_path, name="counted.ihlog", max_parts=3)
    assert [q for q in rec2.paths if q.exists()] == rec2.paths[-3:]


def test_directory_limit_deletes_other_runs_oldest_first(tmp_path: Path) -> None:
    old, new = tmp_path / "a-old.ihlog", tmp_path / "b-new.ihlog"
    _record(old, _samples(100))
    _record(new, _samples(100))
    os.utime(old, (1e9, 1e9))
    msgs: list[str] = []
    size = old.stat().st_size
    _rotated(tmp_path, name="z-now.ihlog", n=100, dir_max_bytes=3 * 4096 + size, on_message=msgs.append)
    assert not old.exists() and new.exists()
    assert any("another run's oldest file" in m and "a-old.ihlog" in m for m in msgs)
    # a limit already exceeded when a run starts is applied at its start
    msgs.clear()
    Recorder(tmp_path / "later.ihlog", dir_max_bytes=1, on_message=msgs.append).close()
    assert not new.exists() and (tmp_path / "later.ihlog").exists() and len(msgs) >= 1


def test_retention_config_default_holds_a_day_at_1_khz(tmp_path: Path) -> None:
    doc = tomllib.loads((Path(__file__).parent.parent / "configs" / "default.toml").read_text())
    cfg = from_dict(doc)
    rate = bytes_per_hour(1000.0, 5.0, 25.0)  # the default run: 1 kHz IMU, 5 Hz GNSS, 25 Hz baro
    assert 300e6 < rate < 360e6
    assert cfg.recorder.total_mb * 1048576 / rate >= 24.0
    assert cfg.recorder.dir_total_mb == 0.0
    for bad in ({"total_mb": 0}, {"total_mb": -5.0}, {"dir_total_mb": -1.0}):
        with pytest.raises(ConfigError, match="recorder"):
            from_dict({**doc, "recorder": {**doc["recorder"], **bad}})


def test_rotation_writes_whole_frames_and_replays_across_parts(tmp_path: Path) -> None:
    rec, src = _rotated(tmp_path)
    assert all(q.stat().st_size <= 4096 for q in rec.paths)
    assert parts_of(rec.paths[1]) == rec.paths
    reader = LogReader(rec.paths[2])
    assert [_key(r) for r in reader] == [_key(s) for s in src]
    assert reader.message() == "" and reader.stats.closed and reader.stats.parts == rec.paths
    assert part_path(tmp_path / "rot.ihlog", 3) == rec.paths[3]


def test_a_valid_record_copied_elsewhere_is_detected(tmp_path: Path) -> None:
    """A whole, CRC-valid record duplicated or moved (a block copied by a faulty medium, a splice) is not a
    silently extra record: each frame's CRC is chained to the four bytes before it, so the copy fails at its
    new place and the read stops there with the intact prefix."""
    src = _samples(20)
    p = tmp_path / "c.ihlog"
    _record(p, src)
    data = p.read_bytes()
    (n,) = struct.unpack_from("<I", data, 7)
    start = 7 + 4 + n + 4  # the first frame
    frames = []
    i = start
    while i < len(data) and data[i : i + 2] == b"\xa9\x1e":
        size = 4 + data[i + 3] + 4
        frames.append((i, size))
        i += size
    a, sa = frames[3]
    b, _ = frames[10]
    bad = data[:b] + data[a : a + sa] + data[b:]  # record 3 again before record 10
    q = tmp_path / "spliced.ihlog"
    q.write_bytes(bad)
    got, err = _read_all(q)
    keys = [_key(s) for s in src]
    assert err and f"byte {b}" in err, err
    assert got == keys[:10]


def test_an_empty_recording_is_one_line_naming_the_file_once(tmp_path: Path, capsys) -> None:
    p = tmp_path / "empty.ihlog"
    p.write_bytes(b"")
    assert replay_cli(p, None) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.count(str(p)) == 1, err  # was "…: empty.ihlog: empty.ihlog: …"
    assert "cut off" in err
