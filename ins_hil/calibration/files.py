"""The calibration file (TOML or JSON, by suffix): read, validate and write.

Format: :mod:`ins_hil.nav.calibration` (module doc) and docs/calibration.md; the tables are
validated and built by :meth:`~ins_hil.nav.calibration.SensorCalibration.from_dict`.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ins_hil.nav.calibration import CalibrationError, SensorCalibration


def save_calibration(c: SensorCalibration, path: str | Path) -> None:
    """Write ``c`` as TOML (``.toml``) or JSON (``.json``)."""
    path = Path(path)
    if path.suffix == ".json":
        path.write_text(json.dumps(c.to_dict(), indent=2) + "\n")
    elif path.suffix == ".toml":
        path.write_text(_to_toml(c.to_dict()))
    else:
        raise CalibrationError(f"{path}: calibration files end in .toml or .json")


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def _to_toml(d: Mapping[str, Any]) -> str:
    """The calibration tables as TOML text (nested tables one level deep)."""
    lines = ["# ins_hil sensor calibration; format: docs/calibration.md", ""]
    tables = []
    for k, v in d.items():
        if isinstance(v, Mapping):
            tables.append((k, v))
        else:
            lines.append(f"{k} = {_toml_value(v)}")
    for k, v in tables:
        sub = [(kk, vv) for kk, vv in v.items() if isinstance(vv, Mapping)]
        flat = [(kk, vv) for kk, vv in v.items() if not isinstance(vv, Mapping)]
        if flat:
            lines += ["", f"[{k}]"] + [f"{kk} = {_toml_value(vv)}" for kk, vv in flat]
        for kk, vv in sub:
            lines += ["", f"[{k}.{kk}]"] + [f"{k3} = {_toml_value(v3)}" for k3, v3 in vv.items()]
    return "\n".join(lines) + "\n"


def load_calibration(path: str | Path) -> SensorCalibration:
    """Read and validate a calibration file (.toml or .json); CalibrationError names the problem."""
    import tomllib

    path = Path(path)
    if path.suffix not in (".toml", ".json"):
        raise CalibrationError(f"{path}: calibration files end in .toml or .json")
    try:
        text = path.read_text()
    except OSError as e:
        raise CalibrationError(f"{path}: cannot read calibration file ({e.strerror})") from e
    try:
        d = json.loads(text) if path.suffix == ".json" else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as e:
        raise CalibrationError(f"{path}: not valid {path.suffix[1:].upper()}: {e}") from e
    if not isinstance(d, Mapping):
        raise CalibrationError(f"{path}: the top level must be a table")
    return SensorCalibration.from_dict(d, str(path))
