"""Every gateway config error is one line: no line break, at most LINE characters after the file name, and a
ConfigError (never another exception). Before: an unknown key listed every key of its table (435 characters
for [core], 561 for [core.nav.filter]), a bad mav_type every name, a MAVLink url its value twice, and a
file name too long escaped as OSError."""

from __future__ import annotations

import copy
import random
import tomllib
from pathlib import Path
from typing import Any

import pytest

from ins_hil.config import ConfigError, from_dict, load

ROOT = Path(__file__).resolve().parent.parent
LINE = 160  # characters of the message after "<file>: "
DEFAULT = tomllib.loads((ROOT / "configs" / "default.toml").read_text())


def _with(path: str, value: Any) -> dict[str, Any]:
    """The default config with ``value`` set at the dotted ``path`` (list indices as numbers)."""
    d = copy.deepcopy(DEFAULT)
    *head, last = [int(p) if p.isdigit() else p for p in path.split(".")]
    t: Any = d
    for p in head:
        t = t.setdefault(p, {}) if isinstance(p, str) else t[p]
    t[last] = value
    return d


BAD = {
    "unknown core key": _with("core.nope", 1),
    "unknown core.nav.filter key": _with("core.nav.filter.nope", 1),
    "unknown core.nav.aids key": _with("core.nav.aids.nope", 1),
    "unknown fdi.aiding key": _with("fdi.aiding.nope", 1),
    "unknown fdi.options key": _with("fdi.options.nope", 1),
    "unknown sim key": _with("sim.nope", 1),
    "unknown mqtt key": _with("mqtt.nope", 1),
    "unknown outputs key": _with("outputs.0.nope", 1),
    "unknown outputs.rates key": _with("outputs.0.rates.NOPE", 1),
    "misspelt outputs key": _with("outputs.0.rool", "gcs"),
    "unknown core.nav.alignment key": _with("core.nav.alignment.nope", 1),
    "key with a line break": _with("core.a\nb", 1),
    "key with CRLF": _with("gateway.a\r\nb", 1),
    "a long key": _with("core." + "k" * 300, 1),
    "mav_type": _with("outputs.0.mav_type", "QUADROTR"),
    "mav_type number": _with("outputs.0.mav_type", 5),
    "mav_type huge integer": _with("outputs.0.mav_type", 10**5000),
    "output url empty": _with("outputs.0.url", ""),
    "output url scheme": _with("outputs.0.url", "udp:1.2.3.4:5"),
    "output url long": _with("outputs.0.url", "x" * 500),
    "input url": _with("inputs.1.url", "x\ny"),
    "calibration name too long": _with("core.calibration", "c" * 500),
    "calibration NUL": _with("core.calibration", "a\0b"),
    "string value with line breaks": _with("gateway.name", ["a\nb"]),
    "long string value": _with("outputs.0.rates.ATTITUDE", "y" * 500),
}


def _one_line(msg: str) -> None:
    assert "\n" not in msg and "\r" not in msg, msg
    assert len(msg) <= LINE, f"{len(msg)} characters: {msg}"


@pytest.mark.parametrize("case", list(BAD))
def test_each_config_error_is_one_line(case: str) -> None:
    with pytest.raises(ConfigError) as e:
        from_dict(BAD[case], source="<test>")
    _one_line(str(e.value))


def test_errors_of_a_file_are_one_line(tmp_path: Path) -> None:
    """Through ``load`` (what ``ins-hil run --config`` does): the message after the file name."""
    p = tmp_path / "bad.toml"
    for text in (b"[core]\nnope = 1\n", b"[core.nav.filter]\nzz = 1\n", b'[[outputs]]\nmav_type = "X"\n',
                 b"[gateway\n", b"a = \xff\n"):  # fmt: skip
        p.write_bytes(text)
        with pytest.raises(ConfigError) as e:
            load(p)
        msg = str(e.value)
        assert msg.startswith(f"{p}: "), msg
        _one_line(msg[len(f"{p}: ") :])


def test_mutated_seed_configs_give_one_line_errors() -> None:
    """The fuzz campaign's config mutator (ins_hil.fuzz.targets) on the shipped configs, 400 inputs, fixed seed."""
    from ins_hil.fuzz.targets import _mutate_tree

    seeds = [tomllib.loads(p.read_text()) for p in sorted((ROOT / "configs").glob("*.toml"))]
    rng = random.Random(39)
    errors = 0
    for _ in range(400):
        d = copy.deepcopy(rng.choice(seeds))
        for _ in range(rng.choice((1, 1, 2, 3))):
            _mutate_tree(rng, d)
        try:
            from_dict(d, source="<fuzz>")
        except ConfigError as e:
            errors += 1
            _one_line(str(e))
    assert errors > 100  # the mutations do reach the checks
