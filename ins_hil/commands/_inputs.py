"""What kind of TOML config a file is, for a hint when one kind is given where the other is expected: a dataset
config (``configs/datasets/*.toml``, ``ins-hil replay --dataset``) or a gateway config (``configs/*.toml``,
``ins-hil run --config``, ``config --check``, ``replay sim --config``)."""

from __future__ import annotations

import tomllib
from pathlib import Path

#: the top-level tables only a gateway config has
GATEWAY_TABLES = ("gateway", "inputs", "outputs", "mqtt", "recorder", "core", "sim")

#: a hint (one clause) per kind
HINTS = {
    "dataset": "a dataset config: ins-hil replay LOG --dataset FILE",
    "gateway": "a gateway config: ins-hil run --config FILE, or ins-hil replay sim --config FILE",
}


def config_kind(path: str | Path) -> str | None:
    """The kind of the config at ``path``: "dataset" (a ``[dataset]`` table), "gateway" (one of
    :data:`GATEWAY_TABLES` and no ``[dataset]``), or None (unreadable, not TOML, neither)."""
    try:
        d = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if isinstance(d.get("dataset"), dict):
        return "dataset"
    return "gateway" if any(k in d for k in GATEWAY_TABLES) else None
