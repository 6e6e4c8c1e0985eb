"""Typed settings: a configuration key is a dataclass field whose metadata holds its unit, range and help.

``setting(default, unit, range, help, **more)`` declares one (a ``dataclasses.field``); the TOML loader
(:mod:`ins_hil.config_schema`, which also writes docs/configuration.md from the same metadata) and the
dataclass itself (``__post_init__`` → :func:`check_fields`) check a value against it, so a key has one
description and one range. The key's type comes from its default (bool, int, float, str, 3-vector, list, table)
or its annotation; a number must be finite unless the key says ``nonfinite``.

Metadata: ``unit``, ``range`` (an interval, ``"(0, 1e4]"``: open/closed ends, ``inf`` for none; ``"0 | [a, b]"``
when 0 is also allowed, e.g. 0 = off), or ``min``/``max`` (inclusive), ``gt``/``lt`` (exclusive); ``choices``,
``help``, ``nonfinite``, ``nonempty``, ``file``, ``length``, ``unique``, ``nonzero``, ``optional``, ``required``,
``type``, ``doc_default``, ``hex_bytes``.

The lowest layer of the package (no ins_hil import): every settings dataclass can use it.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
from collections.abc import Iterable
from dataclasses import MISSING, dataclass
from pathlib import Path
from typing import Any

import numpy as np


class ConfigError(ValueError):
    """A configuration problem; a single line naming the file, the dotted key, the value and what is allowed
    (raised by ``ins_hil.config`` and by the runtime for its parameter override file)."""

    def __init__(self, msg: object = "") -> None:
        super().__init__(re.sub(r"\s*[\r\n]+\s*", " ", str(msg)).strip())


#: a list of known names longer than this is not spelt out in an error (the error stays one line)
KNOWN_LIST_MAX = 80


def setting(default: Any = MISSING, unit: str = "", range: str = "", help: str = "", *, factory: Any = MISSING,
            **more: Any) -> Any:  # fmt: skip
    """A settings dataclass field (``dataclasses.field``) with its key's metadata: ``unit``, ``range``, ``help``
    and any of the module's other metadata names; ``factory`` for a mutable default (a list, a vector)."""
    md = {k: v for k, v in (("unit", unit), ("range", range), ("help", help)) if v}
    md.update(more)
    if factory is not MISSING:
        return dataclasses.field(default_factory=factory, metadata=md)
    return dataclasses.field(default=default, metadata=md)


REQUIRED = "(required)"


def _scalar(x: Any) -> bool:
    """A string, boolean, integer or finite float."""
    return isinstance(x, str | bool | int) or (isinstance(x, float) and math.isfinite(x))


def show(v: Any) -> str:
    """The value as in the file, shortened to one short line."""
    try:
        s = repr(v)
    except ValueError:  # an integer of more than 4300 digits
        s = f"<an integer of {v.bit_length()} bits>" if isinstance(v, int) else f"<a {type(v).__name__}>"
    return s if len(s) <= 60 else s[:57] + "..."


_RANGE = re.compile(r"^\s*(?:(0)\s*\|\s*)?([\[(])\s*([^,\s]+)\s*,\s*([^,\s\])]+)\s*([\])])\s*$")


@dataclass(frozen=True)
class Interval:
    """A range ``(lo, hi]`` etc.; ``zero``: 0 is allowed as well (e.g. 0 = off)."""

    lo: float
    hi: float
    lo_closed: bool
    hi_closed: bool
    zero: bool = False

    @classmethod
    def parse(cls, s: str) -> Interval:
        m = _RANGE.match(s)
        if not m:
            raise ValueError(f"bad range {s!r} (e.g. '(0, 1e4]', '0 | [0.01, 1000]')")
        return cls(float(m[3]), float(m[4]), m[2] == "[", m[5] == "]", m[1] is not None)

    def __contains__(self, v: float) -> bool:
        if self.zero and v == 0:
            return True
        lo_ok = v >= self.lo if self.lo_closed else v > self.lo
        hi_ok = v <= self.hi if self.hi_closed else v < self.hi
        return lo_ok and hi_ok

    def text(self, integer: bool = False) -> str:
        def num(x: float) -> str:
            if math.isinf(x):
                return "inf" if x > 0 else "-inf"
            return str(int(x)) if integer or (x == int(x) and abs(x) < 1e15) else f"{x:g}"

        if math.isinf(self.hi) and math.isinf(self.lo):
            core = "any"
        elif math.isinf(self.hi):
            core = f"{'≥' if self.lo_closed else '>'} {num(self.lo)}"
        elif math.isinf(self.lo):
            core = f"{'≤' if self.hi_closed else '<'} {num(self.hi)}"
        elif integer and self.lo_closed and self.hi_closed:
            core = f"{num(self.lo)}..{num(self.hi)}"
        else:
            lb, rb = "[" if self.lo_closed else "(", "]" if self.hi_closed else ")"
            core = f"in {lb}{num(self.lo)}, {num(self.hi)}{rb}"
        return f"0 or {core}" if self.zero else core


ANY = Interval(-math.inf, math.inf, False, False)

#: key types: what TOML value each takes
TYPES = {
    "bool": "true or false",
    "int": "an integer",
    "float": "a number",
    "str": "a string",
    "str|int": "a string or an integer",
    "vec3": "3 numbers",
    "list[int]": "a list of integers",
    "list[float]": "a list of numbers",
    "list[str]": "a list of strings",
    "table": "a table",
    "any": "a string, finite number, boolean, or a list of them or of tables of them",
}


@dataclass(frozen=True)
class Key:
    """One configuration key."""

    name: str
    type: str
    default: Any = None
    unit: str = ""
    range: str = ""
    choices: tuple[Any, ...] = ()
    help: str = ""
    attr: str | None = None  # the dataclass field it sets (None: handled by the loader)
    nonfinite: bool = False  # NaN / ±inf allowed (documented per key)
    optional: bool = False  # no default value: absent = not set
    required: bool = False
    nonempty: bool = False  # strings, lists
    file: bool = False  # a path to an existing file ("" = none unless nonempty)
    length: int = 0  # lists: exactly this many entries
    unique: bool = False  # lists: no entry twice
    nonzero: bool = False  # vectors: not all zero
    doc_default: str = ""  # the default as shown in the docs (when the value is machine-specific)
    hex_bytes: int = 0  # a string of 2 × this many hex digits, or ''

    @property
    def interval(self) -> Interval:
        return Interval.parse(self.range) if self.range else ANY

    def allowed(self) -> str:
        """What the key accepts, in words (used in the error messages and the docs)."""
        if self.choices:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        t = self.type
        iv = self.interval
        what = TYPES[t]
        if t in ("float", "int", "vec3", "list[int]", "list[float]"):
            integer = t in ("int", "list[int]")
            rng = iv.text(integer)
            if t == "vec3":
                what = "3 finite numbers" if not self.nonfinite else what
                what += f" each {rng}" if rng != "any" else ""
                what += " (not all 0)" if self.nonzero else ""
            elif t in ("list[int]", "list[float]"):
                n = f"{self.length} " if self.length else ""
                what = (
                    ("a non-empty " if self.nonempty else "a ")
                    + f"list of {n}"
                    + ("integers" if integer else "finite numbers")
                )
                what += f" {rng}" if rng != "any" else ""
                what += " (no duplicates)" if self.unique else ""
            else:
                if t == "float" and not self.nonfinite:
                    what = "a finite number"
                what += f" {rng}" if rng != "any" else ""
        elif t in ("str", "list[str]"):
            if self.hex_bytes:
                what = f"'' or {2 * self.hex_bytes} hex digits"
            elif self.length:
                what = f"a list of {self.length} strings"
            elif self.file:
                what = "the path of an existing file" + ("" if self.nonempty else " ('' = none)")
            elif self.nonempty:
                what = "a non-empty " + what[2:]
        if self.unit and t in ("float", "int", "vec3", "list[int]", "list[float]"):
            what += f" {self.unit}"
        return what

    def check(self, v: Any, where: str) -> Any:
        """The value converted to its Python type (int → float for a float key), or ConfigError."""
        t = self.type

        def bad() -> ConfigError:
            what = self.allowed()
            if self.choices and len(what) > KNOWN_LIST_MAX:  # one line: the close matches, not every choice
                near = difflib.get_close_matches(v, [str(c) for c in self.choices], n=2) if isinstance(v, str) else []
                alt = f" (did you mean {' or '.join(repr(n) for n in near)}?)" if near else ""
                what = f"one of {len(self.choices)} names{alt}, listed in docs/configuration.md"
            return ConfigError(f"{where} = {show(v)}: expected {what}")

        if t == "bool":
            if not isinstance(v, bool):
                raise bad()
            return v
        if t == "int":
            if isinstance(v, bool) or not isinstance(v, int) or v not in self.interval:
                raise bad()
            return v
        if t == "float":
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise bad()
            try:
                x = float(v)
            except OverflowError:
                raise bad() from None
            if math.isnan(x) or math.isinf(x):
                if not self.nonfinite:
                    raise bad()
                return x
            if x not in self.interval:
                raise bad()
            return x
        if t in ("str", "str|int"):
            if t == "str|int" and isinstance(v, int) and not isinstance(v, bool):
                return v
            if not isinstance(v, str) or "\0" in v or (self.nonempty and not v):
                raise bad()
            if self.choices and v not in self.choices:
                raise bad()
            if self.hex_bytes and v:
                try:
                    ok = len(bytes.fromhex(v)) == self.hex_bytes and len(v) == 2 * self.hex_bytes
                except ValueError:
                    ok = False
                if not ok:
                    raise bad()
            if self.file and v:
                try:
                    found = Path(v).is_file()
                except (OSError, ValueError) as e:  # e.g. a name too long, a NUL byte
                    why = getattr(e, "strerror", None) or e
                    raise ConfigError(f"{where} = {show(v)}: not a usable path ({why})") from None
                if not found:
                    raise ConfigError(f"{where} = {show(v)}: file not found (or not a regular file)")
            return v
        if t == "vec3":
            ok = isinstance(v, list) and len(v) == 3
            ok = ok and all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
            if not ok or not all(abs(x) < 1e300 for x in v if isinstance(x, int)):
                raise bad()
            xs = [float(x) for x in v]
            if not self.nonfinite and not all(math.isfinite(x) and x in self.interval for x in xs):
                raise bad()
            if self.nonzero and not any(xs):
                raise bad()
            return xs
        if t == "list[int]":
            ok = isinstance(v, list) and (bool(v) or not self.nonempty)
            ok = ok and all(isinstance(x, int) and not isinstance(x, bool) and x in self.interval for x in v)
            if not ok or (self.unique and len(set(v)) != len(v)):
                raise bad()
            return list(v)
        if t == "list[float]":
            ok = isinstance(v, list) and (bool(v) or not self.nonempty) and (not self.length or len(v) == self.length)
            ok = ok and all(isinstance(x, int | float) and not isinstance(x, bool) and abs(x) < 1e300 for x in v)
            if not ok or not all(math.isfinite(float(x)) and float(x) in self.interval for x in v):
                raise bad()
            return [float(x) for x in v]
        if t == "list[str]":
            ok = isinstance(v, list) and all(isinstance(x, str) and x for x in v)
            if not ok or (self.length and len(v) != self.length) or (self.nonempty and not v):
                raise bad()
            return list(v)
        if t == "table":
            if not isinstance(v, dict):
                raise bad()
            return v
        if t == "any":
            if (isinstance(v, float) and not math.isfinite(v)) or isinstance(v, dict):
                raise bad()
            if isinstance(v, list) and not all(_scalar(x) or (isinstance(x, dict) and all(map(_scalar, x.values())))
                                               for x in v):  # fmt: skip
                raise bad()
            return v
        raise AssertionError(f"schema: unknown type {t!r} of {where}")

    def shown_default(self) -> str:
        if self.doc_default:
            return self.doc_default
        if self.required:
            return REQUIRED
        if self.optional and self.default is None:
            return "not set"
        if self.type == "table":
            return ""
        d = self.default
        if isinstance(d, bool):
            return "true" if d else "false"
        if isinstance(d, str):
            return f'"{d}"'
        if isinstance(d, float):
            return f"{d:.6g}"
        if isinstance(d, list | tuple):
            return "[" + ", ".join(f"{x:.6g}" if isinstance(x, float) else repr(x) for x in d) + "]"
        return str(d)


# --------------------------------------------------------------------------------------------------
# the keys of a settings dataclass


def _plain(v: Any) -> Any:
    """A default as a TOML-like value (numpy vectors → lists of floats, tuples → lists)."""
    if hasattr(v, "tolist"):
        return v.tolist()
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    return v


def _infer(default: Any, annotation: str) -> tuple[str, bool]:
    """(key type, optional) from a field's default value or, when it has none, its annotation."""
    if isinstance(default, bool):
        return "bool", False
    if isinstance(default, int):
        return "int", False
    if isinstance(default, float):
        return "float", False
    if isinstance(default, str):
        return "str", False
    if isinstance(default, dict):
        return "table", False
    if hasattr(default, "shape") or (isinstance(default, tuple | list) and len(default) == 3 and
                                     all(isinstance(x, float) for x in default)):  # fmt: skip
        return "vec3", False
    if isinstance(default, list | tuple):
        if default and isinstance(default[0], str):
            return "list[str]", False
        return ("list[float]" if any(isinstance(x, float) for x in default) else "list[int]"), False
    a = str(annotation).replace(" ", "")
    optional = default is None
    if "tuple[float" in a or a.startswith("Vec") or "ndarray" in a:
        return "vec3", optional
    for name in ("bool", "int", "float", "str"):
        if a.split("|")[0] == name:
            return name, optional
    if "dict" in a:
        return "table", optional
    return "any", optional


_META = {"unit", "range", "choices", "help", "nonfinite", "nonempty", "file", "length", "unique", "nonzero",
         "optional", "required", "type", "doc_default", "hex_bytes"}  # fmt: skip


def _from_metadata(md: Any) -> dict[str, Any]:
    """The :class:`Key` attributes a dataclass field's metadata gives (min/max/gt/lt → range)."""
    out = {k: md[k] for k in _META if k in md}
    if "range" not in out and any(k in md for k in ("min", "max", "gt", "lt")):
        lo = md.get("min", md.get("gt", -math.inf))
        hi = md.get("max", md.get("lt", math.inf))
        out["range"] = f"{'(' if 'min' not in md else '['}{lo}, {hi}{')' if 'max' not in md else ']'}"
    if "choices" in out:
        out["choices"] = tuple(out["choices"])
    if isinstance(out.get("range"), tuple | list):
        lo, hi = out["range"]
        out["range"] = f"[{lo}, {hi}]"
    return out


def dataclass_keys(cls: type, rename: dict[str, str] | None = None, skip: tuple[str, ...] = ()) -> dict[str, Key]:
    """The keys of a section from the fields of dataclass ``cls``: type from the default (or annotation), unit,
    range, help, ... from the field's metadata (:func:`setting`). A field holding a dataclass is a section of its
    own and left out. The keys of a class are made once (they are fixed; a replay builds its settings many times):
    each call returns a new dict of the same (frozen) keys."""
    memo = (cls, tuple(sorted((rename or {}).items())), skip)
    got = _KEYS.get(memo)
    if got is None:
        got = _KEYS[memo] = _dataclass_keys(cls, rename or {}, skip)
    return dict(got)


_KEYS: dict[tuple[type, tuple[tuple[str, str], ...], tuple[str, ...]], dict[str, Key]] = {}


def _dataclass_keys(cls: type, rename: dict[str, str], skip: tuple[str, ...]) -> dict[str, Key]:
    out: dict[str, Key] = {}
    for f in dataclasses.fields(cls):
        if f.name in skip or not f.init or f.name.startswith("_") or f.metadata.get("sections"):
            continue
        name = rename.get(f.name, f.name)
        attrs: dict[str, Any] = _from_metadata(f.metadata)
        if f.default is not dataclasses.MISSING:
            default: Any = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = None
            attrs.setdefault("required", True)
        if dataclasses.is_dataclass(default):  # a nested settings object is its own section (e.g. core.nav.filter)
            continue
        typ, optional = _infer(default, str(f.type))
        attrs.setdefault("type", typ)
        if optional:
            attrs.setdefault("optional", True)
        out[name] = Key(name=name, default=_plain(default), attr=f.name, **attrs)
    return out


_FIELD_KEYS: dict[type, dict[str, Key]] = {}


def check_fields(obj: Any, prefix: str) -> None:
    """Check every field of the settings dataclass ``obj`` against its metadata (the same :meth:`Key.check` the
    TOML loader runs; a file's existence is left to the loader): ConfigError (a ValueError) in one line,
    ``<prefix>.<field>=<value>: expected <what is allowed>``. Called by the dataclasses' ``__post_init__``, so a
    setting built in code obeys the ranges a configuration file does."""
    cls = type(obj)
    keys = _FIELD_KEYS.get(cls)
    if keys is None:
        keys = _FIELD_KEYS[cls] = {
            k.attr or n: dataclasses.replace(k, file=False) for n, k in dataclass_keys(cls).items()
        }
    for attr, key in keys.items():
        v = getattr(obj, attr)
        if (v is None and (key.optional or key.required)) or key.type == "any":  # "any": an object, not a value
            continue
        try:
            key.check(_plain(v), f"{prefix}.{attr}")
        except ConfigError:
            raise ConfigError(f"{prefix}.{attr}={show(_plain(v))}: expected {key.allowed()}") from None


def known_hint(k: str, known: Iterable[str], section: str = "") -> str:
    """What to say about an unknown name ``k`` in one line: the close matches (``did you mean``), else the
    known names when they fit in :data:`KNOWN_LIST_MAX` characters, else how many there are and where
    they are documented (``section``: its name in docs/configuration.md, e.g. ``core.nav.filter``)."""
    names = sorted(known)
    near = difflib.get_close_matches(k, names, n=2)
    if near:
        return f"did you mean {' or '.join(repr(n) for n in near)}?"
    listed = ", ".join(names)
    if len(listed) <= KNOWN_LIST_MAX:
        return f"known: {listed}"
    sec = section.replace("[]", "")
    table = f"[[{sec}]]" if section.endswith("[]") and "." not in sec else f"[{sec}]"
    return f"{len(names)} known keys: docs/configuration.md, {table}" if section else f"{len(names)} known"


def build(cls: type, table: Any, where: str, **fixed: Any) -> Any:
    """The settings dataclass ``cls`` from its TOML table, each key checked once against its metadata
    (:meth:`Key.check`): ConfigError in one line naming ``<where>.<key>``. A field holding a settings dataclass
    is a sub-table built the same way; a 3-vector field annotated ``Vec`` becomes a numpy array, a tuple field a
    tuple. ``fixed``: constructor arguments the table does not hold (e.g. an object built from a name)."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where} = {show(table)}: expected a table")
    keys = {n: k for n, k in dataclass_keys(cls).items() if k.attr not in fixed}
    nested = {f.name: f for f in dataclasses.fields(cls) if f.name not in keys and f.name not in fixed}
    ann = {f.name: str(f.type).replace(" ", "") for f in dataclasses.fields(cls)}
    kw: dict[str, Any] = dict(fixed)
    for k, v in table.items():
        key = keys.get(k)
        if key is None:
            f = nested.get(k)
            sub = f.default_factory if f is not None else MISSING
            if sub is MISSING or not dataclasses.is_dataclass(sub):
                raise ConfigError(f"unknown key {show(f'{where}.{k}')} ({known_hint(str(k), [*keys, *nested], where)})")
            kw[k] = build(sub, v, f"{where}.{k}")
            continue
        if v is None and key.optional:  # not set (a table written from the dataclass; TOML has no None)
            kw[key.attr or k] = None
            continue
        x = key.check(_plain(v), f"{where}.{k}")  # a vector built in code (tuple, array) as in a file
        a = ann[key.attr or k]
        if isinstance(x, list) and ("Vec" in a or "ndarray" in a):
            x = np.array(x, dtype=np.float64)
        elif isinstance(x, list) and a.startswith("tuple"):
            x = tuple(x)
        kw[key.attr or k] = x
    for k, key in keys.items():
        if key.required and k not in table:
            raise ConfigError(f"{where}: missing key {k!r} ({key.allowed()})")
    try:
        return cls(**kw)
    except (TypeError, ValueError) as e:  # a check across keys (ConfigError is a ValueError)
        msg = str(e)
        raise ConfigError(msg if msg.startswith(where) else f"{where}: {msg}") from None


def table(obj: Any) -> dict[str, Any]:
    """The TOML table of a settings dataclass: the fields that differ from their defaults (a settings field as a
    sub-table of its own differences, left out when there are none; vectors as lists of floats), so that
    :func:`build` of it gives ``obj`` back. What a recording's header and a configuration document hold."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(obj):
        if not f.init or f.name.startswith("_"):
            continue
        v = getattr(obj, f.name)
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            sub = table(v)
            if sub:
                out[f.name] = sub
            continue
        if f.metadata.get("sections"):  # sections by name (NavConfig.sources): each a sub-table of its own
            for name, sec in v.items():
                sub = table(sec) if dataclasses.is_dataclass(sec) else dict(sec)
                if sub:
                    out[name] = sub
            continue
        if f.default is not MISSING:
            d: Any = f.default
        elif f.default_factory is not MISSING:
            d = f.default_factory()
        else:
            d = MISSING
        pv, pd = _plain(v), _plain(d)
        if d is MISSING or pv != pd:
            out[f.name] = pv
    return out
